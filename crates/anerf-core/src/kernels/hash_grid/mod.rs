//! The hash-grid encoding's kernels ([`crate::model::hash_grid`] holds the learned module): CPU kernels on
//! plain slices ([`cpu`]), CubeCL kernels for Burn's CubeCL backend (`cube`, with the `wgpu` or `cuda`
//! feature), the Burn backend extension that routes a tensor operation to one of them and supplies the
//! backward pass ([`extension`]), and the plain-tensor [`reference`]; [`encode`] picks between them.

pub mod cpu;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube;
pub mod extension;
pub mod reference;

use burn::prelude::*;

pub use cpu::HASH_PRIMES;

/// Encodes points `[N, 3]` (metres, in the frame the grid covers) with the level tables `table`
/// (`[L·T, F]`) → `[N, L·F]`, differentiable in the points and the table: the kernels where
/// [`super::available`], the [`reference`] elsewhere.
pub fn encode(points: Tensor<2>, table: Tensor<2>, spec: &GridSpec) -> Tensor<2> {
    if super::available(&points.device()) {
        extension::encode(points, table, spec)
    } else {
        reference::encode(points, table, spec)
    }
}

/// A hash grid with its resolutions resolved: everything the kernels need besides the tensors.
#[derive(Debug, Clone, PartialEq)]
pub struct GridSpec {
    /// `F`.
    pub features: usize,
    /// `T`, a power of two.
    pub table_size: usize,
    /// Cells per axis `N_l` of each level (vertices `0..=N_l`).
    pub resolutions: Vec<u32>,
    /// Metres; the grid spans `[−h, h]³`.
    pub half_extent: f32,
}

impl GridSpec {
    /// `L`.
    pub fn levels(&self) -> usize {
        self.resolutions.len()
    }

    /// `L · F`.
    pub fn output_dim(&self) -> usize {
        self.levels() * self.features
    }

    /// Rows of the whole table, `L · T`.
    pub fn table_rows(&self) -> usize {
        self.levels() * self.table_size
    }

    /// Whether `level`'s `(N + 1)³` vertices have a row each (no hashing).
    pub fn is_dense(&self, level: usize) -> bool {
        let side = self.resolutions[level] as u64 + 1;
        side * side * side <= self.table_size as u64
    }
}

#[cfg(test)]
pub(crate) mod tests;

#[cfg(all(test, any(feature = "wgpu", feature = "cuda")))]
mod cube_tests;
