//! NeRF positional encoding.

use burn::prelude::*;

use super::hash_grid::{HashGrid, HashGridConfig};

/// `γ(x) = [x, sin(2⁰x), cos(2⁰x), sin(2¹x), cos(2¹x), …, sin(2^{L−1}x), cos(2^{L−1}x)]` for `[N, 3]` inputs,
/// log-sampled frequencies without a π factor, input included (the reference layout): `3 + 6L` outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PositionalEncoding {
    pub frequencies: usize,
}

impl PositionalEncoding {
    /// Output width for 3-D inputs.
    pub fn output_dim(&self) -> usize {
        3 + 6 * self.frequencies
    }

    /// Encodes `[N, 3]` → `[N, 3 + 6L]`.
    pub fn encode(&self, x: Tensor<2>) -> Tensor<2> {
        let mut parts = Vec::with_capacity(1 + 2 * self.frequencies);
        parts.push(x.clone());
        for l in 0..self.frequencies {
            let scaled = x.clone() * (1u64 << l) as f32;
            parts.push(scaled.clone().sin());
            parts.push(scaled.cos());
        }
        Tensor::cat(parts, 1)
    }
}

/// The points' input to a field: its own hash grid when it has one, else the positional encoding `pe`.
pub fn encode_points(
    grid: Option<&HashGrid>,
    pe: PositionalEncoding,
    points: Tensor<2>,
) -> Tensor<2> {
    match grid {
        Some(g) => g.forward(points),
        None => pe.encode(points),
    }
}

/// A field's hash grid (when `config` asks for one) and the width of its point input.
pub fn point_input(
    config: Option<&HashGridConfig>,
    pe: PositionalEncoding,
    device: &Device,
) -> (Option<HashGrid>, usize) {
    match config {
        Some(c) => (Some(HashGrid::new(c, device)), c.output_dim()),
        None => (None, pe.output_dim()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::{from_rows, to_host};
    use anerf_device::cpu_device;

    #[test]
    fn layout_matches_the_reference_embedder() {
        let pe = PositionalEncoding { frequencies: 3 };
        let x = [0.3f32, -1.2, 2.0];
        let got = to_host(pe.encode(from_rows(&x, 1, 3, &cpu_device())));
        assert_eq!(got.len(), pe.output_dim());
        let mut expect = x.to_vec();
        for l in 0..3 {
            let f = 2f32.powi(l);
            expect.extend(x.iter().map(|v| (v * f).sin()));
            expect.extend(x.iter().map(|v| (v * f).cos()));
        }
        for (g, e) in got.iter().zip(&expect) {
            assert!((g - e).abs() < 1e-6);
        }
    }
}
