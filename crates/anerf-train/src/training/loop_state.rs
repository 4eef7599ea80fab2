//! The training loop's counters that a checkpoint saves beside the model and optimiser: the step, the
//! plateau stop's state and the open log window.

use serde::{Deserialize, Serialize};

use super::schedule::Plateau;
use super::window::Window;

/// The loop's counters, saved with each checkpoint so that a resumed fit continues as if it had never
/// stopped.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct LoopState {
    /// Steps completed.
    pub step: usize,
    /// The early stop on a loss plateau (absent in checkpoints written before it existed).
    #[serde(default)]
    pub plateau: Plateau,
    /// The log window open at this step (absent in checkpoints written before it existed).
    #[serde(default)]
    pub window: Window,
}
