//! What a stage does with what its run folder already holds: start afresh, resume, or replace the earlier
//! work. Checked before any work, so that a refused or failed start leaves the folder as it was.

use std::fs;
use std::path::Path;

use anerf_data::paths::{self, Overlap};
use anyhow::{bail, Context, Result};

use crate::run_dir::RunDir;
use crate::stage::Stage;
use crate::training::checkpoint::Checkpoint;

/// `--resume`, `--overwrite` or neither.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RunStart {
    /// Start the stage; refuse when the folder already holds its work.
    #[default]
    Fresh,
    /// Continue the stage from its newest intact checkpoint; refuse when it has none.
    Resume,
    /// Replace the stage's earlier work (stage 1: the whole run folder) once the new start has passed its
    /// checks.
    Overwrite,
}

impl RunStart {
    /// From the command-line flags (which clap keeps from being given together).
    pub fn from_flags(resume: bool, overwrite: bool) -> Self {
        match (resume, overwrite) {
            (true, _) => RunStart::Resume,
            (false, true) => RunStart::Overwrite,
            (false, false) => RunStart::Fresh,
        }
    }
}

/// Checks that stage 1 may start in `root` as `start` asks, `inputs` being what the run reads (the dataset
/// folder, the body model): `--overwrite` never deletes a folder that holds one of them. Touches nothing.
pub fn check_stage1(root: &Path, start: RunStart, inputs: &[&Path]) -> Result<()> {
    if start == RunStart::Overwrite {
        for input in inputs {
            let overlap = paths::overlap(root, input)
                .with_context(|| format!("resolving {}", root.display()))?;
            if overlap == Some(Overlap::Holds) {
                bail!(
                    "--overwrite: {} holds the input {}, which replacing the run would delete; choose \
                     another --out",
                    root.display(),
                    input.display()
                );
            }
        }
    }
    let holds = contents(root)?;
    match start {
        RunStart::Fresh => {
            if let Some(what) = holds {
                bail!(
                    "{} already holds {what}; pass --resume to continue the run or --overwrite to replace it",
                    root.display()
                );
            }
        }
        RunStart::Resume => {
            if !root.exists() {
                bail!(
                    "--resume: {} does not exist (nothing to resume; start without --resume)",
                    root.display()
                );
            }
            let run = RunDir::open(root).context("--resume")?;
            if Checkpoint::latest(&run.checkpoints(), Stage::Train)?.is_none() {
                bail!(
                    "--resume: {} has no stage-1 checkpoint (start without --resume, adding --overwrite to \
                     replace the folder)",
                    root.display()
                );
            }
        }
        RunStart::Overwrite => {
            if holds.is_some() && !RunDir::looks_like_run(root) {
                bail!(
                    "--overwrite: {} is not a run folder (it has no config.toml); refusing to delete it",
                    root.display()
                );
            }
        }
    }
    Ok(())
}

/// The run folder for stage 1, once the start has been checked and the experiment opened: `Overwrite`
/// deletes the old run whole first.
pub fn begin_stage1(root: &Path, start: RunStart) -> Result<RunDir> {
    match start {
        RunStart::Resume => RunDir::open(root),
        RunStart::Overwrite if root.exists() => {
            fs::remove_dir_all(root)
                .with_context(|| format!("--overwrite: removing the old run {}", root.display()))?;
            RunDir::create(root)
        }
        _ => RunDir::create(root),
    }
}

/// Checks that stage 2 may start in `run` as `start` asks. Touches nothing.
pub fn check_stage2(run: &RunDir, start: RunStart) -> Result<()> {
    let existing = Checkpoint::latest(&run.checkpoints(), Stage::Animate)?;
    match (start, existing) {
        (RunStart::Fresh, Some(ck)) => bail!(
            "{} already has stage 2 ({}); pass --resume to continue it or --overwrite to fit it again",
            run.root.display(),
            ck.dir.display()
        ),
        (RunStart::Resume, None) => bail!(
            "--resume: {} has no stage-2 checkpoint (start stage 2 without --resume)",
            run.root.display()
        ),
        _ => Ok(()),
    }
}

/// Clears stage 2's earlier work from `run` when `start` is `Overwrite` (its checkpoints; its log lines
/// go when the stage's log opens at step 0).
pub fn begin_stage2(run: &RunDir, start: RunStart) -> Result<()> {
    if start == RunStart::Overwrite {
        Checkpoint::remove_stage(&run.checkpoints(), Stage::Animate)?;
    }
    Ok(())
}

/// What `root` holds, in words, if anything (a file, or a folder with entries).
fn contents(root: &Path) -> Result<Option<String>> {
    if root.is_file() {
        return Ok(Some("a file of that name".into()));
    }
    if !root.is_dir() {
        return Ok(None);
    }
    let entries = fs::read_dir(root)
        .with_context(|| format!("listing {}", root.display()))?
        .count();
    Ok(match (entries, RunDir::looks_like_run(root)) {
        (0, _) => None,
        (_, true) => Some("a run".into()),
        (n, false) => Some(format!("{n} other file(s) or folder(s)")),
    })
}
