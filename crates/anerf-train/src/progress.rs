//! What a running stage, evaluation, render or preparation shows on standard error: a progress bar on a
//! terminal; plain lines when standard error is redirected (nohup, SLURM, a pipe), which a batch job's log
//! can be read from while it runs; nothing with `--quiet`.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anerf_data::PrepareProgress;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// The progress display of one stage.
pub struct StageProgress {
    label: String,
    total: usize,
    /// The step this invocation started at (after a resume, the checkpoint's).
    first: usize,
    started: Instant,
    mode: Mode,
}

enum Mode {
    Bar(ProgressBar),
    Lines,
    Hidden,
}

impl StageProgress {
    /// A display for `label` (e.g. "stage 1") running steps `first..total`; `visible = false` shows nothing.
    /// Whether it draws a bar or prints lines follows standard error.
    pub fn new(label: &str, first: usize, total: usize, visible: bool) -> Self {
        let mode = match (visible, std::io::stderr().is_terminal()) {
            (false, _) => Mode::Hidden,
            (true, false) => Mode::Lines,
            (true, true) => {
                let bar =
                    ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
                bar.set_style(
                    ProgressStyle::with_template(&format!(
                        "{label} {{bar:30}} {{pos}}/{{len}} {{msg}} ETA {{eta}}"
                    ))
                    .expect("valid template"),
                );
                bar.set_position(first as u64);
                Mode::Bar(bar)
            }
        };
        let progress = Self {
            label: label.to_string(),
            total,
            first,
            started: Instant::now(),
            mode,
        };
        progress.line(&format!(
            "starting at step {first} of {total}{}",
            if first > 0 { " (resumed)" } else { "" }
        ));
        progress
    }

    /// Prints `what` after the label in line mode.
    fn line(&self, what: &str) {
        if matches!(self.mode, Mode::Lines) {
            eprintln!("{}: {what}", self.label);
        }
    }

    /// After step `step`: moves the bar.
    pub fn set_step(&self, step: usize) {
        if let Mode::Bar(bar) = &self.mode {
            bar.set_position(step as u64);
        }
    }

    /// A logged window ending at `step`: the bar's message, or one line with the elapsed time and ETA.
    pub fn report(&self, step: usize, message: &str) {
        match &self.mode {
            Mode::Bar(bar) => bar.set_message(message.to_string()),
            Mode::Lines => {
                let elapsed = self.started.elapsed();
                let done = step.saturating_sub(self.first).max(1) as f64;
                let left = self.total.saturating_sub(step) as f64;
                let eta = Duration::from_secs_f64(elapsed.as_secs_f64() / done * left);
                eprintln!(
                    "{} step {step}/{} {message} elapsed {} ETA {}",
                    self.label,
                    self.total,
                    clock(elapsed),
                    clock(eta)
                );
            }
            Mode::Hidden => {}
        }
    }

    /// The end of the stage at `step`: clears the bar, or prints how it ended.
    pub fn finish(&self, step: usize, how: &str) {
        if let Mode::Bar(bar) = &self.mode {
            bar.finish_and_clear();
        }
        self.line(&format!(
            "{how} at step {step} of {} after {}",
            self.total,
            clock(self.started.elapsed())
        ));
    }
}

/// The phases of a dataset preparation, each shown as a [`StageProgress`] of its items.
pub struct PhaseProgress {
    visible: bool,
    current: Mutex<Option<StageProgress>>,
    done: AtomicUsize,
}

impl PhaseProgress {
    pub fn new(visible: bool) -> Self {
        Self {
            visible,
            current: Mutex::new(None),
            done: AtomicUsize::new(0),
        }
    }
}

impl PrepareProgress for PhaseProgress {
    fn start(&self, phase: &'static str, total: u64) {
        self.done.store(0, Ordering::SeqCst);
        *self.current.lock().expect("no panic while drawing") =
            Some(StageProgress::new(phase, 0, total as usize, self.visible));
    }

    fn advance(&self) {
        let done = self.done.fetch_add(1, Ordering::SeqCst) + 1;
        if let Some(bar) = &*self.current.lock().expect("no panic while drawing") {
            bar.set_step(done);
        }
    }

    fn finish(&self) {
        if let Some(bar) = self.current.lock().expect("no panic while drawing").take() {
            bar.finish(self.done.load(Ordering::SeqCst), "finished");
        }
    }
}

/// `1h02m03s`, `4m05s` or `6s`.
fn clock(d: Duration) -> String {
    let s = d.as_secs();
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, s) => format!("{h}h{m:02}m{s:02}s"),
    }
}

#[cfg(test)]
mod tests {
    use super::clock;
    use std::time::Duration;

    #[test]
    fn clock_reads_hours_minutes_seconds() {
        assert_eq!(clock(Duration::from_secs(6)), "6s");
        assert_eq!(clock(Duration::from_secs(245)), "4m05s");
        assert_eq!(clock(Duration::from_secs(3723)), "1h02m03s");
    }
}
