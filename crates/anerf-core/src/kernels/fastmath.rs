//! Branch-free approximations of elementary functions for the CPU kernels' inner loops: plain arithmetic
//! on `f32`, so that loops over them vectorise (the standard library's functions are calls into libm, one
//! element at a time).

/// `e^x` to within 2 ulp for `x ∈ [−87, 88]`; arguments below are clamped to −87 (`e^−87 ≈ 1.6e-38`, the
/// least normal result), above to 88. Cephes' `expf`: `x = n ln 2 + r` with `|r| ≤ ln 2 / 2` (`ln 2` split
/// in two parts so that `n ln 2` is exact), a degree-6 polynomial for `e^r`, and `2^n` built in the exponent
/// bits.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and subtracting 1.5 · 2^23 rounds to the nearest integer (SSE2 has no rounding instruction).
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let e = p * r * r + r + 1.0;
    e * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

#[cfg(test)]
mod tests {
    /// Against the standard library (correctly rounded to about 1 ulp) on a dense sweep of the range, and the
    /// clamped ends.
    #[test]
    fn exp_is_within_two_ulp_of_the_standard_library() {
        let mut worst = 0.0f64;
        for i in 0..=2_000_000 {
            let x = -87.0 + 175.0 * i as f32 / 2_000_000.0;
            let (got, want) = (super::exp(x), x.exp());
            let ulp = (want.to_bits() as i64 - got.to_bits() as i64).abs();
            worst = worst.max(ulp as f64);
            assert!(ulp <= 2, "exp({x}) = {got}, std {want}: {ulp} ulp");
        }
        assert!(
            worst >= 1.0,
            "a sweep this dense meets some rounding difference"
        );
        assert_eq!(super::exp(0.0), 1.0);
        assert_eq!(super::exp(-1000.0), super::exp(-87.0));
        assert!(super::exp(f32::NEG_INFINITY) > 0.0);
    }
}
