//! The `anerf` command-line tool.

use std::process::ExitCode;

use anerf_train::cli::{error_chain, interrupt_flag, Cli, Command};
use anerf_train::commands;
use anerf_train::run_start::RunStart;
use clap::Parser;

/// Large freed blocks are kept for reuse: Burn allocates every intermediate tensor anew (see
/// `anerf_core::alloc`; `anerf bench` measures the difference with `--system-allocator`).
#[global_allocator]
static ALLOCATOR: anerf_core::alloc::BlockCache = anerf_core::alloc::BlockCache::new();

fn main() -> ExitCode {
    // `commands::device` re-runs this binary to check a GPU backend in a child process.
    anerf_core::device::probe::exit_if_probe_child();
    let cli = Cli::parse();
    if let Err(e) = anerf_core::device::threads::init_pool() {
        eprintln!("warning: compute threads keep rayon's defaults: {e}");
    }
    // Every command runs on a compute thread, so that the backend's parallel ops fork in place.
    match anerf_core::device::threads::on_pool(|| run(cli)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Synth(a) => commands::synth(&a.out, a.preset, a.seed)?,
        Command::Info(a) => {
            if !commands::info(&a.path)? {
                return Ok(ExitCode::FAILURE);
            }
        }
        Command::Prepare(a) => {
            commands::prepare(commands::load_config(&a.config, &a.common)?, &a.common)?
        }
        Command::Train(a) => {
            let config = commands::train_config(&a)?;
            let run = a
                .out
                .clone()
                .unwrap_or_else(|| std::path::Path::new("runs").join(&config.name));
            let outcome = commands::train(
                config,
                &run,
                &a.common,
                RunStart::from_flags(a.resume, a.overwrite),
                a.steps,
                &interrupt_flag(),
            )?;
            if outcome.interrupted {
                return Ok(ExitCode::from(130));
            }
        }
        Command::Animate(a) => {
            let start = RunStart::from_flags(a.resume, a.overwrite);
            if commands::animate(&a.run, &a.common, start, a.steps, &interrupt_flag())?.interrupted
            {
                return Ok(ExitCode::from(130));
            }
        }
        Command::Eval(a) => {
            commands::eval(&a.run, a.split, &a.common)?;
        }
        Command::Compare(a) => {
            commands::compare(&a.prediction, &a.ground_truth, a.mask.as_deref())?
        }
        Command::Render(a) => {
            let job = match (a.poses, a.novel_poses_from_view) {
                (Some(path), _) => commands::RenderJob::PoseFiles { path, view: a.view },
                (None, Some(view)) => commands::RenderJob::NovelPoses { view },
                (None, None) => commands::RenderJob::Orbit {
                    frame: a.frame,
                    views: a.views,
                    size: a.size,
                },
            };
            commands::render(&a.run, job, &a.common)?;
        }
        Command::Mesh(a) => {
            let job = anerf_train::mesh::MeshJob {
                voxel: a.voxel,
                level: a.level,
                smooth: a.smooth,
                frames: a.frames,
                posed_frames: a.posed_frames,
                carve: !a.no_carve,
            };
            commands::mesh(&a.run, &job, &a.common)?;
        }
        Command::Bench(a) => {
            if a.system_allocator {
                ALLOCATOR.disable();
            }
            anerf_train::bench::run(&a)?;
        }
        Command::Demo(a) => commands::demo(&a.out, a.preset, &a.common, &interrupt_flag())?,
    }
    Ok(ExitCode::SUCCESS)
}
