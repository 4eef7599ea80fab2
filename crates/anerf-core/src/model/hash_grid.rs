//! Multiresolution hash-grid encoding (Müller et al., Instant-NGP, 2022): `L` grids of increasing
//! resolution over a cube, each vertex holding `F` learned features (densely stored while a level's vertices
//! fit in its table of `T` rows, else at a spatial hash of the vertex), read by trilinear interpolation and
//! concatenated over levels.
//!
//! This module holds the learned module and its sizes; [`crate::kernels::hash_grid::encode`] computes the
//! encoding (the hand-written CPU and CubeCL kernels, or their plain-tensor reference on other backends).

use burn::module::{Initializer, Param};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::InvalidValue;
use crate::kernels::hash_grid::GridSpec;

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
    pub fn validate(&self, name: &str) -> Result<(), InvalidValue> {
        let bad = |key: &str, value: &dyn std::fmt::Display, expected: &str| {
            Err(InvalidValue::new(format!("{name}.{key}"), value, expected))
        };
        if self.levels == 0 || self.levels > 32 {
            return bad("levels", &self.levels, "1 to 32");
        }
        if !(4..=24).contains(&self.log2_table_size) {
            return bad("log2_table_size", &self.log2_table_size, "4 to 24");
        }
        if self.features_per_level == 0 || self.features_per_level > 8 {
            return bad("features_per_level", &self.features_per_level, "1 to 8");
        }
        if self.base_resolution < 1 || self.finest_resolution < self.base_resolution {
            return bad(
                "base_resolution",
                &format!(
                    "{} (finest_resolution = {})",
                    self.base_resolution, self.finest_resolution
                ),
                "1 ≤ base ≤ finest",
            );
        }
        if self.finest_resolution > 1 << 20 {
            return bad("finest_resolution", &self.finest_resolution, "at most 2^20");
        }
        if !(self.half_extent.is_finite() && self.half_extent > 0.0) {
            return bad(
                "half_extent",
                &self.half_extent,
                "a positive length in metres",
            );
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
    /// points and the table ([`crate::kernels::hash_grid::encode`]).
    pub fn forward(&self, points: Tensor<2>) -> Tensor<2> {
        crate::kernels::hash_grid::encode(points, self.table.val(), &self.spec)
    }
}
