//! Learning-rate schedules.

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

#[cfg(test)]
mod tests {
    use super::*;

    fn stage(schedule: LrSchedule) -> StageConfig {
        StageConfig {
            iterations: 200_000,
            batch: 1024,
            lr: 5e-4,
            lr_final: 5e-5,
            schedule,
            grad_clip: 40.0,
            checkpoint_every: 1,
            validate_every: 1,
            log_every: 1,
            skip_mask_edges: true,
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
        // 400 epochs: 0.1^0.4 of the start, about 2.0e-4, as REFERENCE.md §3.5 notes.
        assert!((learning_rate(&c, 200_000) - 5e-4 * 0.1f64.powf(0.4)).abs() < 1e-12);
    }
}
