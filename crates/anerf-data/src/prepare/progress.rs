//! How preparing reports its progress: libraries do not draw, so the caller passes a [`PrepareProgress`]
//! (the `anerf` app draws bars with it).

/// Told each phase of a preparation as it runs: its size once, then each finished item. Called from the
/// worker threads of a phase, hence `Sync`.
pub trait PrepareProgress: Sync {
    /// `phase` (`"volumes"`, `"images"`) starts with `total` items.
    fn start(&self, phase: &'static str, total: u64);
    /// One more item of the current phase is done.
    fn advance(&self);
    /// The current phase is done.
    fn finish(&self);
}

/// Reports nothing.
pub struct Silent;

impl PrepareProgress for Silent {
    fn start(&self, _: &'static str, _: u64) {}
    fn advance(&self) {}
    fn finish(&self) {}
}
