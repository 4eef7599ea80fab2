//! Training for anerf: experiment configs, the experiment a run trains on, the stage-1 and stage-2 loops,
//! checkpoints and run folders, and the jobs the `anerf` app runs on a run folder (train, animate,
//! evaluate, render, mesh). The command-line app itself is `src/bin/anerf/`.

pub mod checkpoint;
pub mod config;
pub mod experiment;
pub mod jobs;
pub mod memory;
pub mod mesh;
pub mod motion;
pub mod plots;
pub mod progress;
pub mod render;
pub mod run_dir;
pub mod run_start;
pub mod stage;
pub mod training;
pub mod view;
