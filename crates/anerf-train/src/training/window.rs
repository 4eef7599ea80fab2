//! The log window: running sums of the logged quantities between two lines of `metrics.jsonl`. It is saved
//! with each checkpoint, so a run resumed between two log lines logs the means an uninterrupted run would.

use std::time::Instant;

use serde::{Deserialize, Serialize};

/// One step's logged values.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepValues {
    pub loss: f32,
    /// Colour term alone (stage 1).
    pub mse: f32,
    /// Blend-weight term alone.
    pub blend: f32,
    /// Samples that survive culling / all samples.
    pub surviving: f32,
    /// Samples that reach the canonical NeRF / all samples.
    pub occupied: f32,
    /// Rays (stage 1) or points (stage 2) of the step.
    pub items: usize,
}

/// Sums since the last log line, and a wall clock for the throughput.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Window {
    steps: usize,
    loss: f64,
    mse: f64,
    blend: f64,
    surviving: f64,
    occupied: f64,
    items: usize,
    /// When this process started timing the window, and the items counted before then (a resumed window
    /// holds items of an earlier process, whose time is unknown).
    #[serde(skip)]
    clock: Option<(Instant, usize)>,
}

/// Means over a window, as logged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowMeans {
    pub loss: f32,
    pub mse: f32,
    pub blend: f32,
    pub surviving: f32,
    pub occupied: f32,
    /// Items per second of wall time since the window's clock started.
    pub items_per_second: f64,
}

impl Window {
    /// Starts timing now (a fresh window, or one restored from a checkpoint).
    pub fn start_clock(&mut self) {
        self.clock = Some((Instant::now(), self.items));
    }

    pub fn add(&mut self, v: StepValues) {
        self.steps += 1;
        self.loss += v.loss as f64;
        self.mse += v.mse as f64;
        self.blend += v.blend as f64;
        self.surviving += v.surviving as f64;
        self.occupied += v.occupied as f64;
        self.items += v.items;
    }

    /// The means so far, then a fresh window whose clock starts now.
    pub fn close(&mut self) -> WindowMeans {
        let n = self.steps.max(1) as f64;
        let mean = |v: f64| (v / n) as f32;
        let items_per_second = self.clock.map_or(0.0, |(t, before)| {
            (self.items - before) as f64 / t.elapsed().as_secs_f64().max(1e-9)
        });
        let means = WindowMeans {
            loss: mean(self.loss),
            mse: mean(self.mse),
            blend: mean(self.blend),
            surviving: mean(self.surviving),
            occupied: mean(self.occupied),
            items_per_second,
        };
        *self = Window::default();
        self.start_clock();
        means
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(loss: f32, items: usize) -> StepValues {
        StepValues {
            loss,
            items,
            ..StepValues::default()
        }
    }

    #[test]
    fn a_window_restored_from_its_saved_form_logs_the_same_means() {
        let mut straight = Window::default();
        straight.start_clock();
        straight.add(step(0.5, 10));
        let mut restored: Window =
            serde_json::from_str(&serde_json::to_string(&straight).unwrap()).unwrap();
        restored.start_clock();
        for w in [&mut straight, &mut restored] {
            w.add(step(0.25, 10));
        }
        let (a, b) = (straight.close(), restored.close());
        assert_eq!(a.loss, 0.375);
        assert_eq!(b.loss, 0.375);
    }

    #[test]
    fn throughput_is_items_over_the_wall_time_since_the_clock_started() {
        let mut w = Window::default();
        w.start_clock();
        std::thread::sleep(std::time::Duration::from_millis(50));
        w.add(step(1.0, 1000));
        let rate = w.close().items_per_second;
        // 1,000 items in at least 50 ms: at most 20,000 per second (the old clock started at the first
        // `add`, after the step's work, and read thousands of times more).
        assert!(rate > 0.0 && rate <= 20_000.0, "{rate}");
        // Items counted before a restore are not timed by this process.
        let mut restored: Window = serde_json::from_str(
            &serde_json::to_string(&{
                let mut old = Window::default();
                old.add(step(1.0, 1_000_000));
                old
            })
            .unwrap(),
        )
        .unwrap();
        restored.start_clock();
        std::thread::sleep(std::time::Duration::from_millis(50));
        restored.add(step(1.0, 1000));
        assert!(restored.close().items_per_second <= 20_000.0);
    }
}
