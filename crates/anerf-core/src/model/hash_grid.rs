//! Multiresolution hash-grid encoding (Müller et al., Instant-NGP, 2022): `L` grids of increasing
//! resolution over a cube, each vertex holding `F` learned features (densely stored while a level's vertices
//! fit in its table of `T` rows, else at a spatial hash of the vertex), read by trilinear interpolation and
//! concatenated over levels.
//!
//! This module holds the learned module and its sizes. Three implementations compute the same function:
//! the hand-written CPU and CubeCL kernels of [`crate::kernels::hash_grid`] (through a Burn backend
//! extension on the flex and wgpu backends, forward and backward) and the plain-tensor reference here
//! ([`encode_reference`]: every corner of every level gathered with one `select`), which serves every other
//! backend and which the kernels' tests compare against.

use burn::module::{Initializer, Param};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::kernels::hash_grid::{extension, GridSpec, HASH_PRIMES};

/// Sizes of a hash grid (a part of [`crate::model::ModelConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HashGridConfig {
    /// Number of resolutions `L`.
    pub levels: usize,
    /// `log2 T`: rows of each level's table.
    pub log2_table_size: u32,
    /// Features per vertex `F`.
    pub features_per_level: usize,
    /// Cells per axis of the coarsest level.
    pub base_resolution: u32,
    /// Cells per axis of the finest level; the levels between grow geometrically.
    pub finest_resolution: u32,
    /// The grid covers `[−h, h]³` (metres) of the space it encodes; points outside read the border.
    pub half_extent: f32,
}

impl HashGridConfig {
    /// Checks the sizes; the error names the field.
    pub fn validate(&self, name: &str) -> Result<(), String> {
        if self.levels == 0 || self.levels > 32 {
            return Err(format!("{name}.levels = {}: expected 1 to 32", self.levels));
        }
        if !(4..=24).contains(&self.log2_table_size) {
            return Err(format!(
                "{name}.log2_table_size = {}: expected 4 to 24",
                self.log2_table_size
            ));
        }
        if self.features_per_level == 0 || self.features_per_level > 8 {
            return Err(format!(
                "{name}.features_per_level = {}: expected 1 to 8",
                self.features_per_level
            ));
        }
        if self.base_resolution < 1 || self.finest_resolution < self.base_resolution {
            return Err(format!(
                "{name}.base_resolution = {} / finest_resolution = {}: expected 1 ≤ base ≤ finest",
                self.base_resolution, self.finest_resolution
            ));
        }
        if self.finest_resolution > 1 << 20 {
            return Err(format!(
                "{name}.finest_resolution = {}: expected at most 2^20",
                self.finest_resolution
            ));
        }
        if !(self.half_extent.is_finite() && self.half_extent > 0.0) {
            return Err(format!(
                "{name}.half_extent = {}: expected a positive length in metres",
                self.half_extent
            ));
        }
        Ok(())
    }

    /// Width of the encoding, `L · F`.
    pub fn output_dim(&self) -> usize {
        self.levels * self.features_per_level
    }

    /// The resolved grid.
    pub fn spec(&self) -> GridSpec {
        let l = self.levels;
        let growth = if l > 1 {
            ((self.finest_resolution as f64).ln() - (self.base_resolution as f64).ln())
                / (l - 1) as f64
        } else {
            0.0
        };
        GridSpec {
            features: self.features_per_level,
            table_size: 1 << self.log2_table_size,
            resolutions: (0..l)
                .map(|i| ((self.base_resolution as f64) * (growth * i as f64).exp()).round() as u32)
                .collect(),
            half_extent: self.half_extent,
        }
    }
}

/// The learned tables of one hash grid, `[L·T, F]`.
#[derive(Module, Debug)]
pub struct HashGrid {
    pub table: Param<Tensor<2>>,
    #[module(skip)]
    spec: GridSpec,
}

impl HashGrid {
    /// A grid with features drawn from `U(±1e-4)` (Instant-NGP's initialisation).
    pub fn new(config: &HashGridConfig, device: &Device) -> Self {
        let spec = config.spec();
        let table = Initializer::Uniform {
            min: -1e-4,
            max: 1e-4,
        }
        .init([spec.table_rows(), spec.features], device);
        Self { table, spec }
    }

    /// The resolved sizes.
    pub fn spec(&self) -> &GridSpec {
        &self.spec
    }

    /// Width of the encoding.
    pub fn output_dim(&self) -> usize {
        self.spec.output_dim()
    }

    /// Encodes points `[N, 3]` (metres, in the frame the grid covers) → `[N, L·F]`, differentiable in the
    /// points and the table. Uses the kernels on the flex and wgpu backends, the tensor reference elsewhere.
    pub fn forward(&self, points: Tensor<2>) -> Tensor<2> {
        if crate::kernels::available(&points.device()) {
            extension::encode(points, self.table.val(), &self.spec)
        } else {
            encode_reference(points, self.table.val(), &self.spec)
        }
    }
}

/// The encoding in plain tensor operations: all `8 L` corners of every point are gathered from the table
/// with one `select` (one `select` per corner makes the backward pass about 25× slower).
pub fn encode_reference(points: Tensor<2>, table: Tensor<2>, spec: &GridSpec) -> Tensor<2> {
    let [n, _] = points.dims();
    let (levels, f) = (spec.levels(), spec.features);
    let h = spec.half_extent;
    let unit = ((points + h) / (2.0 * h)).clamp(0.0, 1.0);
    let mut indices = Vec::with_capacity(8 * levels);
    let mut weights = Vec::with_capacity(8 * levels);
    for (level, &res) in spec.resolutions.iter().enumerate() {
        let x = unit.clone() * res as f32;
        let base = x.clone().detach().floor().clamp(0.0, (res - 1) as f32);
        let frac = x - base.clone();
        let base = base.int();
        let axis = |t: &Tensor<2, Int>, a: usize| t.clone().narrow(1, a, 1);
        for c in 0..8 {
            let v: Vec<Tensor<2, Int>> = (0..3)
                .map(|a| axis(&base, a) + ((c >> a) & 1) as i64)
                .collect();
            let row = if spec.is_dense(level) {
                let side = res as i64 + 1;
                v[0].clone() + (v[1].clone() + v[2].clone() * side) * side
            } else {
                // The kernels hash in u32 arithmetic. The primes as (wrapped) i32 values fit every
                // backend's integers (wgpu's are i32), and the products' low 32 bits, all the mask keeps,
                // are the same in wrapping i32, i64 and u32 arithmetic.
                let prime = |a: usize| HASH_PRIMES[a] as i32 as i64;
                (v[0].clone() * prime(0))
                    .bitwise_xor(v[1].clone() * prime(1))
                    .bitwise_xor(v[2].clone() * prime(2))
                    .bitwise_and_scalar(spec.table_size as i64 - 1)
            };
            indices.push((row + (level * spec.table_size) as i64).reshape([n]));
            let w = (0..3)
                .map(|a| {
                    let fa = frac.clone().narrow(1, a, 1);
                    if (c >> a) & 1 == 1 {
                        fa
                    } else {
                        fa.neg() + 1.0
                    }
                })
                .reduce(|a, b| a * b)
                .expect("three axes");
            weights.push(w);
        }
    }
    let gathered = table
        .select(0, Tensor::cat(indices, 0))
        .reshape([levels, 8, n, f]);
    let w = Tensor::stack::<3>(weights, 0).reshape([levels, 8, n, 1]);
    (gathered * w)
        .sum_dim(1)
        .reshape([levels, n, f])
        .swap_dims(0, 1)
        .reshape([n, levels * f])
}
