//! Training for anerf: experiment configs, the experiment a run trains on, the stage-1 and stage-2 loops,
//! checkpoints and the run folder they write. The jobs on a run folder are `anerf-run`, the viewer
//! `anerf-view` and the command-line app `apps/anerf`.

pub mod config;
pub mod experiment;
pub mod manifest;
pub mod plots;
pub mod progress;
pub mod render;
pub mod run_dir;
pub mod run_start;
pub mod stage;
pub mod training;
