//! Comparing computed values with expected ones (a reference implementation's, another backend's, a
//! fixture's): one measure of the difference and one assertion that names the worst element.

/// How far apart two values may be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tolerance {
    /// `|got − expected| ≤ t`.
    Absolute(f64),
    /// `|got − expected| / (1 + |expected|) ≤ t`: absolute near zero, relative for large values.
    Relative(f64),
}

impl Tolerance {
    /// The difference of one pair in this tolerance's measure: 0 for equal values (infinities included),
    /// NaN when either is NaN.
    pub fn difference(self, got: f64, expected: f64) -> f64 {
        if got == expected {
            return 0.0;
        }
        let d = (got - expected).abs();
        match self {
            Tolerance::Absolute(_) => d,
            Tolerance::Relative(_) => d / (1.0 + expected.abs()),
        }
    }

    fn bound(self) -> f64 {
        match self {
            Tolerance::Absolute(t) | Tolerance::Relative(t) => t,
        }
    }
}

/// The index and the [`Tolerance::difference`] of the worst pair (a NaN difference is the worst); `(0, 0)`
/// for empty slices.
pub fn worst_difference<T: Copy + Into<f64>>(
    got: &[T],
    expected: &[T],
    measure: Tolerance,
) -> (usize, f64) {
    got.iter()
        .zip(expected)
        .map(|(&g, &e)| measure.difference(g.into(), e.into()))
        .enumerate()
        .fold((0, 0.0), |worst, (i, d)| {
            if d > worst.1 || (d.is_nan() && !worst.1.is_nan()) {
                (i, d)
            } else {
                worst
            }
        })
}

/// Asserts that `got` and `expected` have the same length and that every pair is within `tolerance`,
/// naming `what` and the worst element; prints the worst difference (seen with `--nocapture`) and returns
/// it.
pub fn assert_close<T: Copy + Into<f64> + std::fmt::Debug>(
    what: &str,
    got: &[T],
    expected: &[T],
    tolerance: Tolerance,
) -> f64 {
    assert_eq!(got.len(), expected.len(), "{what}: lengths differ");
    let (i, worst) = worst_difference(got, expected, tolerance);
    eprintln!("{what}: worst difference {worst:.1e} ({tolerance:?})");
    assert!(
        worst <= tolerance.bound(),
        "{what}: element {i} is {:?}, expected {:?} (difference {worst:e}, {tolerance:?})",
        got[i],
        expected[i]
    );
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_difference_is_absolute_near_zero_relative_when_large_and_nan_worst() {
        // 0.01 off at 0 scores 0.01; 1.0 off at 999 scores 1e-3; 0.02 off at 1 scores 0.01.
        let expected = [0.0f32, 999.0, 1.0];
        let relative = Tolerance::Relative(0.0);
        let (i, d) = worst_difference(&[0.01f32, 1000.0, 1.02], &expected, relative);
        assert_eq!(i, 0);
        assert!((d - 0.01).abs() < 1e-6, "{d}");
        let (i, d) = worst_difference(&[0.0f32, 999.5, 1.0], &expected, relative);
        assert_eq!(i, 1);
        assert!((d - 0.5e-3).abs() < 1e-6, "{d}");
        let (i, d) = worst_difference(&[0.5f32, f32::NAN, 1.0], &expected, relative);
        assert!(i == 1 && d.is_nan(), "{i} {d}");
    }

    #[test]
    fn equal_infinities_are_close_and_an_absolute_bound_is_absolute() {
        let inf = [f64::INFINITY];
        assert_eq!(
            assert_close("inf", &inf, &inf, Tolerance::Absolute(0.0)),
            0.0
        );
        assert_eq!(
            worst_difference(&[1000.5f64], &[1000.0], Tolerance::Absolute(1.0)),
            (0, 0.5)
        );
        let far = std::panic::catch_unwind(|| {
            assert_close("far", &[2.0f64], &[1.0], Tolerance::Absolute(0.5))
        });
        assert!(far.is_err(), "a difference of 1 passed a bound of 0.5");
    }
}
