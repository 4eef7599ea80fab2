//! Learning-rate schedules and the early stop on a loss plateau.

use serde::{Deserialize, Serialize};

use crate::config::{LrSchedule, StageConfig};

/// Learning rate at `step` (0-based) of a stage.
pub fn learning_rate(stage: &StageConfig, step: usize) -> f64 {
    match stage.schedule {
        // Exponential decay from lr to lr_final over the run (the paper).
        LrSchedule::Paper => {
            let t = step as f64 / stage.iterations.max(1) as f64;
            stage.lr * (stage.lr_final / stage.lr).powf(t)
        }
        // lr · 0.1^(epoch/1000), epochs of 500 iterations (the authors' code).
        LrSchedule::Code => stage.lr * 0.1f64.powf((step / 500) as f64 / 1000.0),
    }
}

/// Early stopping: the best windowed loss so far and when it was reached. Saved with each checkpoint, so a
/// resumed stage stops where an uninterrupted one would.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Plateau {
    best: Option<f32>,
    best_step: usize,
    /// True once the stage stopped on the plateau.
    pub reached: bool,
}

impl Plateau {
    /// Records the mean loss of the window ending at `step`. Returns (and remembers) true once the loss
    /// has not fallen below `(1 − stage.plateau_tolerance) · best` for `stage.plateau_steps` steps;
    /// `plateau_steps = 0` never stops.
    pub fn update(&mut self, step: usize, loss: f32, stage: &StageConfig) -> bool {
        let (patience, tolerance) = (stage.plateau_steps, stage.plateau_tolerance);
        if patience == 0 || !loss.is_finite() {
            return false;
        }
        match self.best {
            Some(best) if loss >= best * (1.0 - tolerance) => {
                if step - self.best_step >= patience {
                    self.reached = true;
                }
            }
            _ => {
                self.best = Some(loss);
                self.best_step = step;
            }
        }
        self.reached
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MaskEdges;

    #[test]
    fn a_plateau_stops_after_its_patience_and_progress_resets_it() {
        let cfg = StageConfig {
            plateau_steps: 300,
            plateau_tolerance: 0.01,
            ..stage(LrSchedule::Paper)
        };
        let mut p = Plateau::default();
        // Falling by 10 % per window: never a plateau.
        let mut loss = 1.0;
        for step in (100..=1000).step_by(100) {
            assert!(!p.update(step, loss, &cfg), "step {step}");
            loss *= 0.9;
        }
        // Then flat within the tolerance: stops 300 steps after the last real improvement.
        let best = loss / 0.9;
        assert!(!p.update(1100, best * 0.995, &cfg));
        assert!(!p.update(1200, best * 1.01, &cfg));
        assert!(p.update(1300, best * 0.999, &cfg));
        assert!(p.reached);
        // Patience 0 disables the stop.
        let off_cfg = StageConfig {
            plateau_steps: 0,
            ..cfg
        };
        let mut off = Plateau::default();
        assert!((1..100).all(|s| !off.update(s, 1.0, &off_cfg)));
    }

    fn stage(schedule: LrSchedule) -> StageConfig {
        StageConfig {
            iterations: 200_000,
            batch: 1024,
            views_per_step: 1,
            frames_per_step: 1,
            lr: 5e-4,
            lr_final: 5e-5,
            schedule,
            grad_clip: 40.0,
            checkpoint_every: 1,
            validate_every: 1,
            log_every: 1,
            mask_edges: MaskEdges::Skip,
            detail_fraction: 0.0,
            mask_weight: 0.0,
            hard_surface_weight: 0.0,
            residual_weight: 0.0,
            plateau_steps: 0,
            plateau_tolerance: 0.01,
            edge_scale: 0.1,
        }
    }

    #[test]
    fn paper_decays_to_the_final_rate_and_code_steps_per_epoch() {
        let p = stage(LrSchedule::Paper);
        assert!((learning_rate(&p, 0) - 5e-4).abs() < 1e-12);
        assert!((learning_rate(&p, 100_000) - (5e-4f64 * 5e-5).sqrt()).abs() < 1e-10);
        assert!((learning_rate(&p, 200_000) - 5e-5).abs() < 1e-12);
        let c = stage(LrSchedule::Code);
        assert_eq!(learning_rate(&c, 499), 5e-4);
        // 400 epochs: 0.1^0.4 of the start, about 2.0e-4, as docs/REFERENCE.md §3.5 notes.
        assert!((learning_rate(&c, 200_000) - 5e-4 * 0.1f64.powf(0.4)).abs() < 1e-12);
    }
}
