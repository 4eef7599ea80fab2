//! Training for anerf: experiment configs, the stage-1 and stage-2 loops, checkpoints, and the library
//! behind the `anerf` command-line tool.

pub mod config;
