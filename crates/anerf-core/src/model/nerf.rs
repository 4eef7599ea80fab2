//! The canonical radiance field `F_σ`, `F_c` (REFERENCE.md §3.1).

use burn::nn::{Embedding, EmbeddingConfig, Linear};
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid};

use super::encoding::PositionalEncoding;
use super::mlp::{torch_linear, SkipMlp, SkipMlpConfig};
use super::ModelConfig;

/// Density and colour in canonical space: trunk on `γ(x_can)` → raw density (no activation); a feature
/// (linear) joined with the frame's appearance code `ℓ_i` (linear) and `γ(d)` → ReLU layer of width/2 →
/// sigmoid colour. Only the colour sees `ℓ_i`.
#[derive(Module, Debug)]
pub struct CanonicalNerf {
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

impl CanonicalNerf {
    /// A freshly initialised field with `appearance_codes` rows of ℓ.
    pub fn new(config: &ModelConfig, appearance_codes: usize, device: &Device) -> Self {
        let xyz = PositionalEncoding {
            frequencies: config.xyz_frequencies,
        }
        .output_dim();
        let dir = PositionalEncoding {
            frequencies: config.dir_frequencies,
        }
        .output_dim();
        let w = config.width;
        let trunk = SkipMlpConfig {
            input: xyz,
            conditioning: 0,
            width: w,
            depth: config.depth,
            skip: config.skip,
        };
        Self {
            trunk: trunk.init(device),
            density: torch_linear(w, 1, device),
            feature: torch_linear(w, w, device),
            appearance_fc: torch_linear(w + config.appearance_code_dim, w, device),
            view_fc: torch_linear(w + dir, w / 2, device),
            rgb: torch_linear(w / 2, 3, device),
            appearance: EmbeddingConfig::new(appearance_codes.max(1), config.appearance_code_dim)
                .init(device),
        }
    }

    /// Raw density only, for points `[N, xyz_dim]` already encoded (mesh extraction, stage 2 masks).
    pub fn density(&self, encoded_points: Tensor<2>) -> Tensor<2> {
        self.density
            .forward(self.trunk.forward(encoded_points, None))
    }

    /// Density and colour for encoded points `[N, xyz_dim]`, encoded view directions `[N, dir_dim]`, and the
    /// appearance code of row `appearance_index`.
    pub fn forward(
        &self,
        encoded_points: Tensor<2>,
        encoded_dirs: Tensor<2>,
        appearance_index: usize,
    ) -> RadianceSample {
        let [n, _] = encoded_points.dims();
        let h = self.trunk.forward(encoded_points, None);
        let density = self.density.forward(h.clone());
        let code = self
            .appearance
            .weight
            .val()
            .narrow(0, appearance_index, 1)
            .repeat_dim(0, n);
        let f = self
            .appearance_fc
            .forward(Tensor::cat(vec![self.feature.forward(h), code], 1));
        let v = relu(self.view_fc.forward(Tensor::cat(vec![f, encoded_dirs], 1)));
        RadianceSample {
            density,
            rgb: sigmoid(self.rgb.forward(v)),
        }
    }

    /// Number of appearance codes.
    pub fn appearance_codes(&self) -> usize {
        self.appearance.weight.dims()[0]
    }
}
