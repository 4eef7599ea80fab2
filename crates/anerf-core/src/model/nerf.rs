//! The canonical radiance field `F_σ`, `F_c` (docs/REFERENCE.md §3.1).

use burn::nn::{Embedding, EmbeddingConfig, Linear};
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid};

use super::codes::CodeRows;
use super::encoding::{encode_points, point_input, PositionalEncoding};
use super::hash_grid::HashGrid;
use super::mlp::{
    linear_over_parts, linear_rows, linear_with_codes, torch_linear, SkipMlp, SkipMlpConfig,
};
use super::{ModelConfig, PointEncoding};

/// Density and colour in canonical space: trunk on `γ(x_can)` (or the field's hash grid) → raw density (no
/// activation); a feature (linear) joined with the frame's appearance code `ℓ_i` (linear) and `γ(d)` → ReLU
/// layer of width/2 → sigmoid colour. Only the colour sees `ℓ_i`.
#[derive(Module, Debug)]
pub struct CanonicalNerf {
    /// The hash grid over canonical space ([`PointEncoding::HashGrid`]); `None` for frequencies.
    grid: Option<HashGrid>,
    #[module(skip)]
    xyz: PositionalEncoding,
    #[module(skip)]
    dir: PositionalEncoding,
    trunk: SkipMlp,
    density: Linear,
    feature: Linear,
    appearance_fc: Linear,
    view_fc: Linear,
    rgb: Linear,
    /// Appearance codes ℓ, one per training frame.
    pub appearance: Embedding,
}

/// Raw outputs at canonical points.
#[derive(Debug, Clone)]
pub struct RadianceSample {
    /// `[N, 1]` raw density σ (before ReLU).
    pub density: Tensor<2>,
    /// `[N, 3]` colour in `[0, 1]`.
    pub rgb: Tensor<2>,
}

/// Raw density every point starts with under a hash grid (per metre; see [`density_head`]).
const HASH_GRID_INITIAL_DENSITY: f32 = 1.0;

/// The density head. A hash grid's tables start near zero, so at initialisation every point gets the same
/// raw density, the head's bias: a negative draw leaves the ReLU dead everywhere and training never starts
/// (the demo subject with seed 1 stayed black). With a hash grid the bias starts at
/// [`HASH_GRID_INITIAL_DENSITY`] instead; frequency encodings keep PyTorch's initialisation.
fn density_head(width: usize, hash_grid: bool, device: &Device) -> Linear {
    let mut head = torch_linear(width, 1, device);
    if hash_grid {
        head.bias = Some(burn::module::Param::from_tensor(Tensor::full(
            [1],
            HASH_GRID_INITIAL_DENSITY,
            device,
        )));
    }
    head
}

impl CanonicalNerf {
    /// A freshly initialised field with `appearance_codes` rows of ℓ.
    pub fn new(config: &ModelConfig, appearance_codes: usize, device: &Device) -> Self {
        let xyz_pe = PositionalEncoding {
            frequencies: config.xyz_frequencies,
        };
        let dir_pe = PositionalEncoding {
            frequencies: config.dir_frequencies,
        };
        let grid_config = match &config.encoding {
            PointEncoding::HashGrid { nerf, .. } => Some(nerf),
            PointEncoding::Frequency => None,
        };
        let (grid, xyz) = point_input(grid_config, xyz_pe, device);
        let dir = dir_pe.output_dim();
        let w = config.width;
        let trunk = SkipMlpConfig {
            input: xyz,
            conditioning: 0,
            width: w,
            depth: config.depth,
            skip: config.skip,
        };
        Self {
            grid,
            xyz: xyz_pe,
            dir: dir_pe,
            trunk: trunk.init(device),
            density: density_head(w, grid_config.is_some(), device),
            feature: torch_linear(w, w, device),
            appearance_fc: torch_linear(w + config.appearance_code_dim, w, device),
            view_fc: torch_linear(w + dir, w / 2, device),
            rgb: torch_linear(w / 2, 3, device),
            appearance: EmbeddingConfig::new(appearance_codes.max(1), config.appearance_code_dim)
                .init(device),
        }
    }

    fn encode(&self, points: Tensor<2>) -> Tensor<2> {
        encode_points(self.grid.as_ref(), self.xyz, points)
    }

    /// Raw density only, at canonical points `[N, 3]` (metres): mesh extraction, occupancy, stage 2 masks.
    pub fn density(&self, points: Tensor<2>) -> Tensor<2> {
        linear_rows(&self.density, self.trunk.forward(self.encode(points), None))
    }

    /// Density and colour at canonical points `[N, 3]` (metres) seen along unit view directions `[N, 3]`
    /// (world space), with the appearance codes of rows `appearance` (one frame's, or each group's).
    pub fn forward(
        &self,
        points: Tensor<2>,
        dirs: Tensor<2>,
        appearance: &CodeRows,
    ) -> RadianceSample {
        let encoded_dirs = self.dir.encode(dirs);
        let h = self.trunk.forward(self.encode(points), None);
        let density = linear_rows(&self.density, h.clone());
        // The codes' part of `appearance_fc` is computed once per code and spread over its points.
        let codes = appearance.codes(self.appearance.weight.val());
        let f = linear_with_codes(&self.appearance_fc, linear_rows(&self.feature, h), &codes);
        let v = relu(linear_over_parts(&self.view_fc, &[f, encoded_dirs]));
        RadianceSample {
            density,
            rgb: sigmoid(linear_rows(&self.rgb, v)),
        }
    }

    /// Number of appearance codes.
    pub fn appearance_codes(&self) -> usize {
        self.appearance.weight.dims()[0]
    }
}
