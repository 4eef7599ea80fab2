//! Training for anerf: experiment configs, the stage-1 and stage-2 loops, checkpoints, rendering and
//! evaluation of runs, and the library behind the `anerf` command-line tool.

pub mod bench;
pub mod checkpoint;
pub mod cli;
pub mod commands;
pub mod config;
pub mod experiment;
pub mod memory;
pub mod mesh;
pub mod poses;
pub mod progress;
pub mod render;
pub mod run_dir;
pub mod run_start;
pub mod schedule;
pub mod stage;
pub mod train;
pub mod window;
