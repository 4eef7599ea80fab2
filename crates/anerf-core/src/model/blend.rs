//! The neural blend weight field: body-model prior weights corrected by an MLP conditioned on a per-frame
//! latent code (paper §3.2, docs/REFERENCE.md §3.1).

use burn::module::Param;
use burn::nn::{Embedding, EmbeddingConfig, Linear};
use burn::prelude::*;

use super::codes::CodeRows;
use super::encoding::{encode_points, point_input, PositionalEncoding};
use super::hash_grid::HashGrid;
use super::mlp::{linear_rows, torch_linear, SkipMlp, SkipMlpConfig};
use super::{BlendParameterisation, ModelConfig, PointEncoding, ResidualInit};

/// `w(x) = combine(F_Δw(γ(x), ψ), w^s(x))` for one table of latent codes ψ.
///
/// In stage 1 one field serves every training frame and the canonical space: row 0 of the code table is
/// `ψ^can`, row `f + 1` is training frame `f` (the reference's layout). Stage 2 builds a fresh field whose
/// rows are the novel-pose frames.
#[derive(Module, Debug)]
pub struct BlendWeightField {
    /// The hash grid over pose and canonical space ([`PointEncoding::HashGrid`]); `None` for frequencies.
    grid: Option<HashGrid>,
    #[module(skip)]
    xyz: PositionalEncoding,
    trunk: SkipMlp,
    head: Linear,
    /// Latent codes ψ.
    pub codes: Embedding,
    #[module(skip)]
    parameterisation: BlendParameterisation,
}

impl BlendWeightField {
    /// A freshly initialised field with `codes` latent rows and `joints` outputs, its output layer started
    /// as `init` says.
    pub fn new(
        config: &ModelConfig,
        codes: usize,
        joints: usize,
        init: ResidualInit,
        device: &Device,
    ) -> Self {
        let xyz_pe = PositionalEncoding {
            frequencies: config.xyz_frequencies,
        };
        let grid_config = match &config.encoding {
            PointEncoding::HashGrid { blend, .. } => Some(blend),
            PointEncoding::Frequency => None,
        };
        let (grid, xyz) = point_input(grid_config, xyz_pe, device);
        let trunk = SkipMlpConfig {
            input: xyz,
            conditioning: config.blend_code_dim,
            width: config.width,
            depth: config.depth,
            skip: config.skip,
        };
        Self {
            grid,
            xyz: xyz_pe,
            trunk: trunk.init(device),
            head: residual_head(config.width, joints, init, device),
            codes: EmbeddingConfig::new(codes.max(1), config.blend_code_dim).init(device),
            parameterisation: config.blend,
        }
    }

    /// The MLP output `F` (`[N, K]`) at points `[N, 3]` (metres, pose or canonical space) for code row `code`.
    pub fn residual(&self, points: Tensor<2>, code: usize) -> Tensor<2> {
        self.residual_of(points, &CodeRows::One(code))
    }

    /// [`Self::residual`] with each point's code row from `codes` (several frames' points at once).
    pub fn residual_of(&self, points: Tensor<2>, codes: &CodeRows) -> Tensor<2> {
        let psi = codes.codes(self.codes.weight.val());
        let encoded = encode_points(self.grid.as_ref(), self.xyz, points);
        linear_rows(&self.head, self.trunk.forward(encoded, Some(&psi)))
    }

    /// Blend weights `[N, K]` (rows sum to 1) at points `[N, 3]`, for code row `code` and prior weights `[N, K]`.
    pub fn forward(&self, points: Tensor<2>, code: usize, prior: Tensor<2>) -> Tensor<2> {
        combine(self.parameterisation, self.residual(points, code), prior)
    }

    /// The weights with the residual forced to zero: the normalised prior under this parameterisation.
    pub fn prior_only(&self, prior: Tensor<2>) -> Tensor<2> {
        let zero = Tensor::zeros(prior.dims(), &prior.device());
        combine(self.parameterisation, zero, prior)
    }

    /// Number of outputs `K`.
    pub fn num_joints(&self) -> usize {
        self.head.weight.dims()[1]
    }
}

/// The output layer `F` of a field: zero (the field starts at the prior) or PyTorch's initialisation.
fn residual_head(width: usize, joints: usize, init: ResidualInit, device: &Device) -> Linear {
    let mut head = torch_linear(width, joints, device);
    if init == ResidualInit::Zero {
        head.weight = Param::from_tensor(Tensor::zeros(head.weight.dims(), device));
        head.bias = Some(Param::from_tensor(Tensor::zeros([joints], device)));
    }
    head
}

/// Combines an MLP output `F` with prior weights `w^s` (both `[N, K]`).
pub fn combine(
    parameterisation: BlendParameterisation,
    residual: Tensor<2>,
    prior: Tensor<2>,
) -> Tensor<2> {
    match parameterisation {
        BlendParameterisation::LogSoftmax => crate::kernels::warp::prior_softmax(prior, residual),
        BlendParameterisation::ExpNorm => {
            // exp(F) is clamped at e^30 to stay finite; rows then still normalise to 1.
            let w = residual.clamp_max(30.0).exp() + prior;
            w.clone() / w.sum_dim(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::{from_rows, to_host};
    use anerf_device::cpu_device;

    #[test]
    fn zero_residual_returns_the_prior_under_both_parameterisations() {
        let device = cpu_device();
        let prior = from_rows(&[0.2, 0.8, 0.0, 0.5, 0.25, 0.25], 2, 3, &device);
        let zero = Tensor::<2>::zeros([2, 3], &device);
        let log = to_host(combine(
            BlendParameterisation::LogSoftmax,
            zero.clone(),
            prior.clone(),
        ));
        for (a, b) in log.iter().zip([0.2, 0.8, 0.0, 0.5, 0.25, 0.25]) {
            assert!((a - b).abs() < 1e-6, "{log:?}");
        }
        // exp(0) = 1 is added to every weight: norm(1 + w^s) = (1 + w^s) / (K + 1).
        let exp = to_host(combine(BlendParameterisation::ExpNorm, zero, prior));
        for (a, b) in exp.iter().zip([1.2 / 4.0, 1.8 / 4.0, 1.0 / 4.0]) {
            assert!((a - b).abs() < 1e-6, "{exp:?}");
        }
    }

    #[test]
    fn log_softmax_correction_is_multiplicative() {
        let device = cpu_device();
        let prior = from_rows(&[0.2, 0.3, 0.5], 1, 3, &device);
        let f = from_rows(&[0.0, 2f32.ln(), 0.0], 1, 3, &device);
        let w = to_host(combine(BlendParameterisation::LogSoftmax, f, prior));
        // Joint 1's prior doubles, then the row renormalises: (0.2, 0.6, 0.5) / 1.3.
        for (a, b) in w.iter().zip([0.2 / 1.3, 0.6 / 1.3, 0.5 / 1.3]) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
