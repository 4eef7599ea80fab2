//! The NeRF trunk: a ReLU MLP whose input is re-joined after one hidden layer, with an optional
//! per-batch conditioning vector (a latent code) that is part of the input.

use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// A `depth`-layer ReLU MLP of `width` units. Its input is `[point features ⊕ conditioning]`; after layer
/// `skip` (0-based) the input is concatenated to the activations again (the reference's `skips = [4]`).
///
/// The conditioning (a per-frame latent code, the same for every point of a batch) enters the first and the
/// skip layer through its own bias-free projection computed once per batch instead of being tiled over the
/// points: mathematically the same layer as a `Linear` over the concatenation, but `[1, C] · [C, W]` instead
/// of `[N, C] · [C, W]`. Weights are initialised as PyTorch initialises the concatenated layer,
/// `U(±1/√fan_in)` with `fan_in` counting both parts.
#[derive(Module, Debug)]
pub struct SkipMlp {
    layers: Vec<Linear>,
    /// Projections of the conditioning into layer 0 and into the skip layer (empty without conditioning).
    conditioning: Vec<Linear>,
    skip: Option<usize>,
}

/// Sizes of a [`SkipMlp`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SkipMlpConfig {
    pub input: usize,
    pub conditioning: usize,
    pub width: usize,
    pub depth: usize,
    /// Re-join the input after this layer; `None` for a plain MLP.
    pub skip: Option<usize>,
}

fn uniform_linear(d_in: usize, d_out: usize, fan_in: usize, bias: bool, device: &Device) -> Linear {
    let bound = 1.0 / (fan_in as f64).sqrt();
    LinearConfig::new(d_in, d_out)
        .with_bias(bias)
        .with_initializer(Initializer::Uniform {
            min: -bound,
            max: bound,
        })
        .init(device)
}

/// `layer` applied to the concatenation of `parts` along dimension 1, without building it: `Σ_i x_i · W_i + b`
/// where `W_i` are the rows of the weight that meet part `i`. Saves copying every activation into a wider
/// tensor (and slicing its gradient apart again); a part with one row (a per-batch code) is broadcast.
pub fn linear_over_parts(layer: &Linear, parts: &[Tensor<2>]) -> Tensor<2> {
    let weight = layer.weight.val();
    let mut row = 0;
    let mut out: Option<Tensor<2>> = None;
    for part in parts {
        let [_, d] = part.dims();
        let z = part.clone().matmul(weight.clone().narrow(0, row, d));
        row += d;
        out = Some(match out {
            Some(o) => o + z,
            None => z,
        });
    }
    assert_eq!(
        row,
        weight.dims()[0],
        "linear_over_parts: the parts' widths must add up to the layer's input width"
    );
    let out = out.expect("at least one part");
    match &layer.bias {
        Some(b) => out + b.val().unsqueeze(),
        None => out,
    }
}

/// A `Linear` initialised as PyTorch's `nn.Linear`/`Conv1d(k=1)`: weights and bias `U(±1/√d_in)`.
pub fn torch_linear(d_in: usize, d_out: usize, device: &Device) -> Linear {
    uniform_linear(d_in, d_out, d_in, true, device)
}

impl SkipMlpConfig {
    /// Builds the MLP; panics on a zero depth or a skip index past the last layer (programming errors:
    /// configs are validated by [`crate::model::ModelConfig::validate`]).
    pub fn init(&self, device: &Device) -> SkipMlp {
        assert!(self.depth > 0, "SkipMlp needs at least one layer");
        assert!(
            self.skip.is_none_or(|s| s + 1 < self.depth),
            "skip layer must precede the last layer"
        );
        let full_in = self.input + self.conditioning;
        let mut layers = Vec::with_capacity(self.depth);
        let mut conditioning = Vec::new();
        for i in 0..self.depth {
            let joins_input = i == 0 || self.skip.is_some_and(|s| i == s + 1);
            let (d_in, fan_in) = match (i, joins_input) {
                (0, _) => (self.input, full_in),
                (_, true) => (self.width + self.input, self.width + full_in),
                _ => (self.width, self.width),
            };
            layers.push(uniform_linear(d_in, self.width, fan_in, true, device));
            if joins_input && self.conditioning > 0 {
                conditioning.push(uniform_linear(
                    self.conditioning,
                    self.width,
                    fan_in,
                    false,
                    device,
                ));
            }
        }
        SkipMlp {
            layers,
            conditioning,
            skip: self.skip,
        }
    }
}

impl SkipMlp {
    /// Output width.
    pub fn width(&self) -> usize {
        self.layers[0].weight.dims()[1]
    }

    /// `[N, input]` point features and an optional `[1, conditioning]` code → `[N, width]` activations.
    pub fn forward(&self, input: Tensor<2>, conditioning: Option<Tensor<2>>) -> Tensor<2> {
        let projected: Vec<Tensor<2>> = match &conditioning {
            Some(c) => self
                .conditioning
                .iter()
                .map(|l| l.forward(c.clone()))
                .collect(),
            None => Vec::new(),
        };
        let mut projected = projected.into_iter();
        let mut h = input.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            let joins_input = i == 0 || self.skip.is_some_and(|s| i == s + 1);
            // The skip layer sees [h, input]: computed part by part instead of concatenated.
            let mut z = if i > 0 && joins_input {
                linear_over_parts(layer, &[h, input.clone()])
            } else {
                layer.forward(h)
            };
            if joins_input {
                if let Some(p) = projected.next() {
                    z = z + p;
                }
            }
            h = relu(z);
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::cpu_device;
    use crate::tensor::to_host;
    use burn::tensor::Distribution;

    /// The split conditioning equals a plain layer over the concatenated input with the same weights.
    #[test]
    fn conditioning_projection_equals_concatenated_input() {
        let device = cpu_device();
        let cfg = SkipMlpConfig {
            input: 5,
            conditioning: 3,
            width: 8,
            depth: 4,
            skip: Some(1),
        };
        let mlp = cfg.init(&device);
        let x = Tensor::<2>::random([6, 5], Distribution::Normal(0.0, 1.0), &device);
        let c = Tensor::<2>::random([1, 3], Distribution::Normal(0.0, 1.0), &device);
        let got = to_host(mlp.forward(x.clone(), Some(c.clone())));

        // Plain re-statement: every joining layer sees [h, x, c] with weights [W_h; W_c] stacked.
        let full = Tensor::cat(vec![x.clone(), c.repeat_dim(0, 6)], 1);
        let stacked = |l: &Linear, p: &Linear| Tensor::cat(vec![l.weight.val(), p.weight.val()], 0);
        let mut h = relu(
            full.clone()
                .matmul(stacked(&mlp.layers[0], &mlp.conditioning[0]))
                + mlp.layers[0].bias.as_ref().unwrap().val().unsqueeze(),
        );
        h = relu(mlp.layers[1].forward(h));
        h = Tensor::cat(vec![h, full], 1);
        h = relu(
            h.matmul(stacked(&mlp.layers[2], &mlp.conditioning[1]))
                + mlp.layers[2].bias.as_ref().unwrap().val().unsqueeze(),
        );
        h = relu(mlp.layers[3].forward(h));
        for (a, b) in got.iter().zip(to_host(h)) {
            assert!((a - b).abs() < 1e-5);
        }
    }

    /// Parts of the input (one of them a broadcast row) give the layer's output on their concatenation.
    #[test]
    fn linear_over_parts_equals_the_layer_on_the_concatenation() {
        let device = cpu_device();
        let layer = torch_linear(7, 4, &device);
        let a = Tensor::<2>::random([5, 3], Distribution::Normal(0.0, 1.0), &device);
        let b = Tensor::<2>::random([1, 4], Distribution::Normal(0.0, 1.0), &device);
        let got = to_host(linear_over_parts(&layer, &[a.clone(), b.clone()]));
        let expect = to_host(layer.forward(Tensor::cat(vec![a, b.repeat_dim(0, 5)], 1)));
        for (g, e) in got.iter().zip(&expect) {
            assert!((g - e).abs() < 1e-5, "{g} vs {e}");
        }
    }

    #[test]
    fn paper_trunk_has_the_reference_parameter_count() {
        // 8×256 with input 63+128 re-joined after layer 4: the reference's Conv1d stack.
        let cfg = SkipMlpConfig {
            input: 63,
            conditioning: 128,
            width: 256,
            depth: 8,
            skip: Some(4),
        };
        let mlp = cfg.init(&cpu_device());
        let expected = (191 * 256 + 256)
            + 4 * (256 * 256 + 256)
            + ((256 + 191) * 256 + 256)
            + 2 * (256 * 256 + 256);
        assert_eq!(mlp.num_params(), expected);
    }
}
