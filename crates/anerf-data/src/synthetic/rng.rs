//! A small seeded generator whose stream never changes between versions, so a seed names one subject.

/// SplitMix64 (Steele, Lea and Flood 2014).
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// An independent stream for item `index` (a frame, a frame's camera) of the purpose `salt`. The key is
    /// hashed, so streams of nearby seeds, salts and indices share nothing, and the subject's main stream
    /// (`new(seed)`) is left as it was: adding a purpose changes no other file.
    pub fn keyed(seed: u64, salt: u64, index: u64) -> Self {
        let key = SplitMix64::new(salt ^ SplitMix64::new(index).next_u64()).next_u64();
        Self::new(SplitMix64::new(seed ^ key).next_u64())
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`, 53 bits.
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit() as f32
    }

    /// Standard normal, by Box–Muller (the cosine branch; one value per call, two draws).
    pub fn gaussian(&mut self) -> f32 {
        // 1 − u lies in (0, 1], so the logarithm is finite.
        let radius = (-2.0 * (1.0 - self.unit()).ln()).sqrt();
        (radius * (std::f64::consts::TAU * self.unit()).cos()) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_zero_mean_and_unit_variance() {
        let mut rng = SplitMix64::keyed(7, 1, 2);
        let n = 20_000;
        let draws: Vec<f64> = (0..n).map(|_| f64::from(rng.gaussian())).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: 1/√n ≈ 0.007 for the mean, √(2/n) ≈ 0.01 for the variance; 5 of each.
        assert!(mean.abs() < 0.035, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "variance {var}");
    }

    #[test]
    fn keyed_streams_differ_from_each_other_and_from_the_main_stream() {
        let first = |mut r: SplitMix64| r.next_u64();
        let main = first(SplitMix64::new(0));
        let keyed = [(0, 1, 0), (0, 1, 1), (0, 2, 0), (1, 1, 0)]
            .map(|(s, salt, i)| first(SplitMix64::keyed(s, salt, i)));
        for (i, a) in keyed.iter().enumerate() {
            assert_ne!(*a, main);
            assert!(keyed[i + 1..].iter().all(|b| b != a));
        }
    }
}
