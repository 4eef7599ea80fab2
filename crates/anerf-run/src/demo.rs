//! `anerf demo`: the whole pipeline on the built-in synthetic subject (synthesise once, both stages,
//! novel views and novel poses evaluated, a turntable of a novel pose), continuing where it stopped.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anerf_core::model::ModelPreset;
use anerf_data::synthetic::{write_subject, SynthPreset, SyntheticSpec, SyntheticSummary};
use anerf_eval::report::EvalSplit;
use anerf_train::config::{self, Settings};
use anerf_train::run_dir::RunDir;
use anerf_train::run_start::RunStart;
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::Checkpoint;
use anerf_train::training::StageOutcome;
use anyhow::{Context, Result};

use crate::{
    animate, eval, open_device, render, train, Evaluated, JobOptions, RenderJob, Rendered,
};

/// What the demo does, as it happens, for the caller to show.
pub enum DemoEvent<'a> {
    /// The subject of this spec was synthesised into this folder.
    Synthesised(&'a Path, &'a SyntheticSpec, &'a SyntheticSummary),
    /// A stage of the run in this folder ended (finished, interrupted, or already complete).
    Stage(Stage, &'a StageOutcome, &'a Path),
    Evaluated(EvalSplit, &'a Evaluated),
    Rendered(&'a Rendered),
}

/// What the demo did: its run, and when it was not interrupted, the two splits' results, the turntable
/// and the time each part took.
pub struct DemoOutcome {
    pub run: PathBuf,
    /// `None` when a stage was interrupted (the next demo continues it).
    pub finished: Option<DemoResults>,
}

pub struct DemoResults {
    pub novel_view: Evaluated,
    pub novel_pose: Evaluated,
    pub turntable: Rendered,
    /// Each part's wall time, in order; the last entry is the total.
    pub times: Vec<(&'static str, Duration)>,
}

/// Runs the demo in `out` (`subject/`, `cache/`, `run/`) with `preset` (default: `configs/demo.toml`'s),
/// reporting each part to `report`. The demo owns its run folder: each stage continues from its latest
/// checkpoint, or starts again where there is none.
pub fn demo(
    out: &Path,
    preset: Option<ModelPreset>,
    options: &JobOptions,
    stop: &AtomicBool,
    mut report: impl FnMut(DemoEvent<'_>),
) -> Result<DemoOutcome> {
    let started = Instant::now();
    let subject = out.join("subject");
    if let Some(choice) = options.device {
        // A GPU backend that cannot run fails here, not after the subject has been generated.
        open_device(choice, options)?;
    }
    if !subject.join("annots.npy").is_file() {
        let spec = SynthPreset::Demo.spec();
        let summary = write_subject(&spec, &subject)
            .with_context(|| format!("writing the synthetic subject to {}", subject.display()))?;
        report(DemoEvent::Synthesised(&subject, &spec, &summary));
    }
    let settings = Settings {
        root: Some(subject),
        cache: Some(out.join("cache")),
        preset,
        ..Settings::default()
    };
    let config = config::assemble(config::demo_table(), &settings, &options.set)?;
    let run = out.join("run");
    let unfinished = DemoOutcome {
        run: run.clone(),
        finished: None,
    };
    let checkpoints = RunDir { root: run.clone() }.checkpoints();
    let start = |stage| -> Result<RunStart> {
        Ok(match Checkpoint::latest(&checkpoints, stage)? {
            Some(_) => RunStart::Resume,
            None => RunStart::Overwrite,
        })
    };
    let mut times = Vec::new();
    let mut timed = |what, since: Instant| times.push((what, since.elapsed()));

    let t = Instant::now();
    let outcome = train(config, &run, options, start(Stage::Train)?, None, stop)?;
    report(DemoEvent::Stage(Stage::Train, &outcome, &run));
    if outcome.interrupted {
        return Ok(unfinished);
    }
    timed("stage 1 (train)", t);
    let t = Instant::now();
    let outcome = animate(&run, options, start(Stage::Animate)?, None, stop)?;
    report(DemoEvent::Stage(Stage::Animate, &outcome, &run));
    if outcome.interrupted {
        return Ok(unfinished);
    }
    timed("stage 2 (animate)", t);

    let t = Instant::now();
    let mut evaluate = |split| -> Result<Evaluated> {
        let e = eval(&run, split, crate::Avatar::Nerf, options)?;
        report(DemoEvent::Evaluated(split, &e));
        Ok(e)
    };
    let (novel_view, novel_pose) = (
        evaluate(EvalSplit::NovelView)?,
        evaluate(EvalSplit::NovelPose)?,
    );
    timed("evaluation", t);

    let t = Instant::now();
    let novel = RunDir::open(&run)?
        .read_config()?
        .dataset
        .split()
        .novel_pose_frames;
    let job = RenderJob::Orbit {
        frame: Some((novel.start + novel.end) / 2),
        views: 24,
        size: None,
    };
    let turntable = render(&run, job, crate::Avatar::Nerf, options)?;
    report(DemoEvent::Rendered(&turntable));
    timed("turntable render", t);
    times.push(("total", started.elapsed()));
    Ok(DemoOutcome {
        run,
        finished: Some(DemoResults {
            novel_view,
            novel_pose,
            turntable,
            times,
        }),
    })
}
