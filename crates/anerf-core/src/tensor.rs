//! Small helpers between host memory and Burn tensors.

use burn::module::{ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

/// Reads a float tensor back to the host as `f32`, row-major.
///
/// Panics only when the backend cannot read back synchronously (never on the CPU backends).
pub fn to_host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>()
        .expect("reading a tensor back to the host")
}

/// A `[rows, cols]` tensor from row-major host data.
pub fn from_rows(data: &[f32], rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    assert_eq!(
        data.len(),
        rows * cols,
        "from_rows: {} values for a {rows}×{cols} tensor",
        data.len()
    );
    Tensor::<1>::from_floats(data, device).reshape([rows, cols])
}

/// The gradient of every float parameter of `module`, read back to the host in the module's visiting order
/// (`None` where `grads` holds none): for checking where gradients reach and comparing them across backends.
pub fn parameter_gradients<M: Module>(
    module: &M,
    grads: &GradientsParams,
) -> Vec<Option<Vec<f32>>> {
    struct Collect<'a> {
        grads: &'a GradientsParams,
        values: Vec<Option<Vec<f32>>>,
    }
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.values.push(self.grads.get::<D>(param.id).map(to_host));
        }
    }
    let mut collect = Collect {
        grads,
        values: Vec::new(),
    };
    module.visit(&mut collect);
    collect.values
}

/// The element where `got` is furthest from `expected`, as `(index, |got − expected| / (1 + |expected|))`:
/// an absolute difference near zero, a relative one for large values; a NaN counts as the worst. For
/// comparing backends, whose f32 results differ in the order of their sums. Panics when the lengths differ.
pub fn worst_relative_difference(got: &[f32], expected: &[f32]) -> (usize, f32) {
    assert_eq!(
        got.len(),
        expected.len(),
        "compared slices differ in length"
    );
    got.iter()
        .zip(expected)
        .map(|(g, e)| (g - e).abs() / (1.0 + e.abs()))
        .enumerate()
        .fold((0, 0.0), |worst, (i, d)| {
            if d > worst.1 || (d.is_nan() && !worst.1.is_nan()) {
                (i, d)
            } else {
                worst
            }
        })
}

/// Asserts that `got` is within `tolerance` of `expected` by [`worst_relative_difference`], naming `what`
/// and the worst element; prints the worst difference (seen with `--nocapture`). For tests comparing
/// backends.
pub fn assert_close(what: &str, got: &[f32], expected: &[f32], tolerance: f32) {
    assert_eq!(got.len(), expected.len(), "{what}: lengths differ");
    let (i, worst) = worst_relative_difference(got, expected);
    eprintln!("{what}: worst relative difference {worst:.1e}");
    assert!(
        worst <= tolerance,
        "{what}: element {i} is {}, expected {} (relative difference {worst:e})",
        got[i],
        expected[i]
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worst_relative_difference_is_absolute_near_zero_relative_when_large_and_nan_worst() {
        // 0.01 off at 0 scores 0.01; 1.0 off at 999 scores 1e-3; 0.02 off at 1 scores 0.01.
        let expected = [0.0, 999.0, 1.0];
        let (i, d) = worst_relative_difference(&[0.01, 1000.0, 1.02], &expected);
        assert_eq!(i, 0);
        assert!((d - 0.01).abs() < 1e-6, "{d}");
        let (i, d) = worst_relative_difference(&[0.0, 999.5, 1.0], &expected);
        assert_eq!(i, 1);
        assert!((d - 0.5e-3).abs() < 1e-6, "{d}");
        let (i, d) = worst_relative_difference(&[0.5, f32::NAN, 1.0], &expected);
        assert!(i == 1 && d.is_nan(), "{i} {d}");
    }
}
