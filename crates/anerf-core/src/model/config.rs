//! Model configuration with named presets: the paper's sizes and smaller CPU sizes, same code.

use serde::{Deserialize, Serialize};

use super::hash_grid::HashGridConfig;
use super::occupancy::OccupancyConfig;
use super::pose_refinement::PoseRefinementConfig;
use crate::error::InvalidValue;
use crate::named::Named;

/// How the neural blend weight field combines its MLP output `F` with the body-model prior `w^s`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BlendParameterisation {
    /// `softmax(log(w^s + 1e-9) + F)`, the authors' code (a multiplicative correction of the prior).
    #[default]
    LogSoftmax,
    /// `norm(exp(F) + w^s)`, the paper's text.
    ExpNorm,
}

/// The blend-weight consistency loss between `w_i(x)` and `w^can(x')`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ConsistencyLoss {
    /// Smooth-L1 with β = 1 (PyTorch's default), the authors' code; ≈ 0.5·MSE since |Δw| < 1.
    #[default]
    SmoothL1,
    /// Mean absolute difference, the paper's text.
    L1,
}

/// The frame in which the colour head sees the view direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewDirection {
    /// The world-space ray direction (the paper and its ICCV code).
    #[default]
    World,
    /// The ray direction carried into canonical space by the sample's inverse skinning rotation,
    /// `rot(Σ w_k A_k)⁻¹ R_hᵀ d` (the authors' later code).
    Canonical,
    /// No view dependence: the head gets a constant direction, so colour depends on the point and the
    /// frame's appearance code alone.
    None,
}

/// How the blend-weight field's output layer starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResidualInit {
    /// PyTorch's default initialisation of a linear layer (the authors' code; the `paper` preset's
    /// stage-1 field).
    #[default]
    Random,
    /// Zero weights and bias: the residual `F` starts at 0, so a field starts at the body model's
    /// weights.
    Zero,
}

/// How points enter the MLPs.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PointEncoding {
    /// NeRF's positional encoding with `xyz_frequencies` (the paper).
    #[default]
    Frequency,
    /// Multiresolution hash grids (Instant-NGP): one learned by the canonical NeRF (canonical space), one by
    /// the blend-weight fields (pose and canonical space).
    HashGrid {
        nerf: HashGridConfig,
        blend: HashGridConfig,
    },
}

/// Every size and switch of the model and its renderer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// Hidden width of the NeRF and blend-weight trunks (256 in the paper).
    pub width: usize,
    /// Number of hidden layers of each trunk (8 in the paper).
    pub depth: usize,
    /// Layer after which the input is re-joined (4 in the paper); absent for none.
    #[serde(default)]
    pub skip: Option<usize>,
    /// Positional-encoding frequencies for points (10) and view directions (4).
    pub xyz_frequencies: usize,
    pub dir_frequencies: usize,
    /// Size of the blend-weight latent codes ψ (128).
    pub blend_code_dim: usize,
    /// Size of the appearance codes ℓ (128).
    pub appearance_code_dim: usize,
    /// Samples per ray (64).
    pub samples_per_ray: usize,
    /// Samples farther than this from the body (metres, distance channel of the frame's volume) are culled.
    pub cull_distance: f32,
    pub blend: BlendParameterisation,
    pub consistency: ConsistencyLoss,
    /// `false` drops the learned residual and warps with the body model's weights alone (the paper's
    /// "SMPL blend weights" ablation).
    #[serde(default = "default_true")]
    pub neural_blend_weights: bool,
    /// How the stage-1 blend-weight field's residual starts.
    #[serde(default)]
    pub residual_init: ResidualInit,
    /// How the stage-2 (novel-pose) field's residual starts. Zero: stage 2 starts at the body model's
    /// weights, which on the realistic subjects is already as good as the authors' 1,000 to 10,000 steps
    /// from a random start (docs/QUALITY.md).
    #[serde(default = "zero_init")]
    pub novel_residual_init: ResidualInit,
    /// The frame of the colour head's view direction.
    #[serde(default)]
    pub view_direction: ViewDirection,
    /// Point encoding of the NeRF and blend-weight fields (absent: the paper's frequencies).
    #[serde(default)]
    pub encoding: PointEncoding,
    /// An occupancy grid over the canonical box that lets samples in empty space skip the canonical NeRF.
    #[serde(default)]
    pub occupancy: Option<OccupancyConfig>,
    /// Per-frame corrections of the training frames' body fits, learned in stage 1 (off by default).
    #[serde(default)]
    pub pose_refinement: PoseRefinementConfig,
}

fn default_true() -> bool {
    true
}

fn zero_init() -> ResidualInit {
    ResidualInit::Zero
}

/// A named preset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ModelPreset {
    /// The paper: 8×256 trunks, skip at 4, 10/4 frequencies, 128-d codes, 64 samples.
    Paper,
    /// A CPU-sized model: 4×128, skip at 2, 8/4 frequencies, 32-d codes, 48 samples.
    #[default]
    Cpu,
    /// For tests: 2×32, no skip, 4/2 frequencies, 8-d codes, 16 samples.
    Tiny,
    /// Hash-grid encodings with 2×64 MLPs, 16-d codes, 64 samples, view directions in canonical space:
    /// trains in minutes on a CPU.
    Fast,
}

impl ModelPreset {
    /// Every preset, as listed to users.
    pub const ALL: [ModelPreset; 4] = [
        ModelPreset::Paper,
        ModelPreset::Cpu,
        ModelPreset::Tiny,
        ModelPreset::Fast,
    ];

    /// The configuration.
    pub fn config(self) -> ModelConfig {
        let base = ModelConfig {
            width: 256,
            depth: 8,
            skip: Some(4),
            xyz_frequencies: 10,
            dir_frequencies: 4,
            blend_code_dim: 128,
            appearance_code_dim: 128,
            samples_per_ray: 64,
            cull_distance: 0.05,
            blend: BlendParameterisation::LogSoftmax,
            consistency: ConsistencyLoss::SmoothL1,
            neural_blend_weights: true,
            residual_init: ResidualInit::Random,
            novel_residual_init: ResidualInit::Zero,
            view_direction: ViewDirection::World,
            encoding: PointEncoding::Frequency,
            occupancy: None,
            pose_refinement: PoseRefinementConfig::default(),
        };
        match self {
            ModelPreset::Paper => base,
            ModelPreset::Cpu => ModelConfig {
                width: 128,
                depth: 4,
                skip: Some(2),
                xyz_frequencies: 8,
                blend_code_dim: 32,
                appearance_code_dim: 32,
                samples_per_ray: 48,
                ..base
            },
            ModelPreset::Tiny => ModelConfig {
                width: 32,
                depth: 2,
                skip: None,
                xyz_frequencies: 4,
                dir_frequencies: 2,
                blend_code_dim: 8,
                appearance_code_dim: 8,
                samples_per_ray: 16,
                ..base
            },
            ModelPreset::Fast => ModelConfig {
                width: 64,
                depth: 2,
                skip: None,
                // Held-out views +1.9 to +2.6 dB on the demo subject and +2.1 dB on the realistic one
                // against world-space directions (docs/QUALITY.md).
                view_direction: ViewDirection::Canonical,
                // Stage 1 starts at the body model's weights: better on every split of the realistic
                // subjects and the demo, and no longer worse than the body model's weights alone where
                // those are exact (docs/QUALITY.md).
                residual_init: ResidualInit::Zero,
                blend_code_dim: 16,
                appearance_code_dim: 16,
                encoding: PointEncoding::HashGrid {
                    // 16 levels from 16 to 1024 cells over a 2.6 m cube: 2.5 mm at the finest level.
                    nerf: HashGridConfig {
                        levels: 16,
                        log2_table_size: 16,
                        features_per_level: 2,
                        base_resolution: 16,
                        finest_resolution: 1024,
                        half_extent: 1.3,
                    },
                    // Blend weights are smooth: 8 levels down to 2 cm.
                    blend: HashGridConfig {
                        levels: 8,
                        log2_table_size: 15,
                        features_per_level: 2,
                        base_resolution: 8,
                        finest_resolution: 128,
                        half_extent: 1.3,
                    },
                },
                // The same steps as the default's at the hash grids' learning rate (1e-2, not 5e-4).
                pose_refinement: PoseRefinementConfig {
                    rotation_scale: 0.05,
                    translation_scale: 0.0125,
                    ..PoseRefinementConfig::default()
                },
                occupancy: Some(OccupancyConfig {
                    resolution: 64,
                    density_threshold: 0.01,
                    update_every: 16,
                    warmup_steps: 256,
                }),
                ..base
            },
        }
    }
}

impl Named for ModelPreset {
    const KIND: &'static str = "model preset";

    fn all() -> &'static [Self] {
        &Self::ALL
    }

    /// The preset's name in configs and on the command line.
    fn name(self) -> &'static str {
        match self {
            ModelPreset::Paper => "paper",
            ModelPreset::Cpu => "cpu",
            ModelPreset::Tiny => "tiny",
            ModelPreset::Fast => "fast",
        }
    }
}

crate::by_name!(ModelPreset);

impl ModelConfig {
    /// An upper bound on the bytes one ray sample occupies during a step (`radiance: true`: the encodings,
    /// the NeRF's trunk and colour head and both blend-weight fields, observation and canonical, with
    /// `joints` outputs), or one stage-2 point (`radiance: false`: the blend-weight fields alone); f32,
    /// times 3 when training (the autodiff graph keeps the forward activations and the backward pass adds
    /// their gradients). Culling and the occupancy grid usually leave far fewer samples than a batch holds;
    /// the bound serves to refuse sizes that cannot fit.
    pub fn bytes_per_sample(&self, joints: usize, radiance: bool, training: bool) -> u64 {
        let (nerf_in, blend_in) = match &self.encoding {
            PointEncoding::Frequency => {
                let f = 3 + 6 * self.xyz_frequencies;
                (f, f)
            }
            PointEncoding::HashGrid { nerf, blend } => (
                nerf.levels * nerf.features_per_level,
                blend.levels * blend.features_per_level,
            ),
        };
        let trunk = 2 * self.depth * self.width;
        let dirs = 3 + 6 * self.dir_frequencies;
        let nerf = nerf_in + trunk + self.width + dirs + self.appearance_code_dim + self.width + 4;
        let blend = 2 * (blend_in + self.blend_code_dim + trunk + 2 * joints);
        // Points, directions, distances, weights and bookkeeping of the sample itself.
        let sample = 32;
        let floats = (if radiance { nerf } else { 0 } + blend + sample) as u64;
        floats * 4 * if training { 3 } else { 1 }
    }

    /// Checks every field; the error names the field and what is allowed.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        let positive = [
            ("width", self.width),
            ("depth", self.depth),
            ("blend_code_dim", self.blend_code_dim),
            ("appearance_code_dim", self.appearance_code_dim),
            ("samples_per_ray", self.samples_per_ray),
        ];
        for (name, v) in positive {
            if v == 0 {
                return Err(InvalidValue::new(
                    format!("model.{name}"),
                    0,
                    "a positive integer",
                ));
            }
        }
        if let Some(s) = self.skip {
            if s + 1 >= self.depth {
                return Err(InvalidValue::new(
                    "model.skip",
                    s,
                    format!("a layer index below depth − 1 = {}", self.depth - 1),
                ));
            }
        }
        for (key, n) in [
            ("model.xyz_frequencies", self.xyz_frequencies),
            ("model.dir_frequencies", self.dir_frequencies),
        ] {
            if n > 16 {
                return Err(InvalidValue::new(key, n, "at most 16"));
            }
        }
        if self.samples_per_ray < 2 {
            return Err(InvalidValue::new(
                "model.samples_per_ray",
                self.samples_per_ray,
                "at least 2",
            ));
        }
        if let Some(o) = &self.occupancy {
            o.validate()?;
        }
        if let PointEncoding::HashGrid { nerf, blend } = &self.encoding {
            nerf.validate("model.encoding.nerf")?;
            blend.validate("model.encoding.blend")?;
        }
        self.pose_refinement.validate()?;
        if !(self.cull_distance.is_finite() && self.cull_distance > 0.0) {
            return Err(InvalidValue::new(
                "model.cull_distance",
                self.cull_distance,
                "a positive distance in metres",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_named() {
        for p in ModelPreset::ALL {
            p.config().validate().unwrap();
            assert_eq!(p.name().parse::<ModelPreset>().unwrap(), p);
        }
        let paper = ModelPreset::Paper.config();
        assert_eq!(
            (paper.width, paper.depth, paper.skip, paper.samples_per_ray),
            (256, 8, Some(4), 64)
        );
        assert!("huge"
            .parse::<ModelPreset>()
            .unwrap_err()
            .to_string()
            .contains("paper, cpu, tiny, fast"));
    }

    #[test]
    fn invalid_values_name_the_field() {
        let mut c = ModelPreset::Tiny.config();
        c.skip = Some(1);
        let err = c.validate().unwrap_err();
        assert_eq!((err.key.as_str(), err.value.as_str()), ("model.skip", "1"));
        c = ModelPreset::Tiny.config();
        c.cull_distance = f32::NAN;
        let err = c.validate().unwrap_err();
        assert_eq!(err.key, "model.cull_distance");
        assert!(
            err.to_string()
                .starts_with("model.cull_distance = NaN: expected a positive"),
            "{err}"
        );
    }
}
