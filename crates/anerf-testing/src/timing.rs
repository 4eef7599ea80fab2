//! The benches' one timing rule (`cargo bench` targets with `harness = false`): a call untimed to warm
//! caches, then repeated timed calls, reported as median and range.

use std::time::Instant;

/// Runs `f` once untimed and `repeats` times timed (at least once); prints `label`, the median and the
/// range in milliseconds, and returns the median.
pub fn report_ms(label: &str, repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut ms: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let started = Instant::now();
            f();
            started.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    let median = ms[ms.len() / 2];
    println!(
        "{label:<36} median {median:8.2} ms  (min {:.2}, max {:.2})",
        ms[0],
        ms[ms.len() - 1]
    );
    median
}

/// xorshift64: the benches' fixed, dependency-free stream of pseudo-random inputs.
#[derive(Debug, Clone)]
pub struct Xorshift(u64);

impl Default for Xorshift {
    fn default() -> Self {
        Self(0x9e37_79b9_7f4a_7c15)
    }
}

impl Xorshift {
    /// The next 64 random bits.
    pub fn next_bits(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// A uniform float in `[0, 1)` (24 random bits).
    pub fn uniform(&mut self) -> f32 {
        (self.next_bits() >> 40) as f32 / (1u64 << 24) as f32
    }
}
