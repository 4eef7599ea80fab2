//! The `anerf` command-line tool: parses a command line and runs the command's module in `commands/`.

mod alloc;
mod args;
mod cli;
mod commands;

use std::process::ExitCode;

use clap::Parser;
use cli::{error_chain, Cli, Command};

/// Large freed blocks are kept for reuse: Burn allocates every intermediate tensor anew (see
/// [`alloc`]; `anerf bench` measures the difference with `--system-allocator`).
#[global_allocator]
static ALLOCATOR: alloc::BlockCache = alloc::BlockCache::new();

fn main() -> ExitCode {
    // `anerf_run::open_device` re-runs this binary to check a GPU backend in a child process.
    anerf_device::probe::exit_if_probe_child();
    end_quietly_on_closed_pipe();
    let cli = Cli::parse();
    if let Err(e) = anerf_device::threads::init_pool() {
        eprintln!("warning: compute threads keep rayon's defaults: {e}");
    }
    // Every command runs on a compute thread, so that the backend's parallel ops fork in place.
    match anerf_device::threads::on_pool(|| run(cli)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

/// Output to a closed pipe (`anerf info DIR | head -1`) ends the process quietly by SIGPIPE, as Unix tools
/// do, instead of panicking in `println!` (Rust ignores the signal by default). Sockets are unaffected: the
/// standard library sends on them with MSG_NOSIGNAL, so a viewer client that goes away stays an error.
fn end_quietly_on_closed_pipe() {
    #[cfg(unix)]
    // SAFETY: restoring a signal's default disposition at start-up, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Exit status 130 after Ctrl-C stopped a stage (with a checkpoint), 1 when `info` found a fatal problem.
fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    let interrupted = match cli.command {
        Command::Demo(a) => {
            commands::demo::run(&a)?;
            false
        }
        Command::Synth(a) => {
            commands::synth::run(&a)?;
            false
        }
        Command::Info(a) => {
            if !commands::info::run(&a)? {
                return Ok(ExitCode::FAILURE);
            }
            false
        }
        Command::Import(a) => {
            commands::import::run(&a)?;
            false
        }
        Command::Prepare(a) => {
            commands::prepare::run(&a)?;
            false
        }
        Command::Train(a) => commands::train::run(&a)?.interrupted,
        Command::Animate(a) => commands::animate::run(&a)?,
        Command::Eval(a) => {
            commands::eval::run(&a)?;
            false
        }
        Command::Render(a) => {
            commands::render::run(&a)?;
            false
        }
        Command::Plot(a) => {
            commands::plot::run(&a)?;
            false
        }
        Command::Export(a) => {
            commands::export::run(&a)?;
            false
        }
        Command::Bake(a) => {
            commands::bake::run(&a)?;
            false
        }
        Command::View(a) => {
            commands::view::run(&a)?;
            false
        }
        Command::Mesh(a) => {
            commands::mesh::run(&a)?;
            false
        }
        Command::Compare(a) => {
            commands::compare::run(&a)?;
            false
        }
        Command::Bench(a) => {
            if a.system_allocator {
                ALLOCATOR.disable();
            }
            commands::bench::run(&a)?;
            false
        }
    };
    Ok(if interrupted {
        ExitCode::from(130)
    } else {
        ExitCode::SUCCESS
    })
}
