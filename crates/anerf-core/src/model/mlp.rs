//! The NeRF trunk: a ReLU MLP whose input is re-joined after one hidden layer, with an optional
//! per-batch conditioning vector (a latent code) that is part of the input.

use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::codes::Codes;

/// A `depth`-layer ReLU MLP of `width` units. Its input is `[point features ⊕ conditioning]`; after layer
/// `skip` (0-based) the input is concatenated to the activations again (the reference's `skips = [4]`).
///
/// The conditioning (a per-frame latent code, the same for every point of a frame) enters the first and the
/// skip layer through its own bias-free projection computed once per code instead of being tiled over the
/// points ([`Codes::project`]): mathematically the same layer as a `Linear` over the concatenation, but
/// `[G, C] · [C, W]` for `G` codes instead of `[N, C] · [C, W]`. Weights are initialised as PyTorch initialises the concatenated layer,
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

/// Rows per chunk of the batched matmuls that [`rows_matmul`] runs on a GPU.
pub const GPU_CHUNK_ROWS: usize = 1024;

/// `x · w` for a batch of `[N, C]` point rows. On a GPU backend with at least two chunks of rows, computed
/// as a batched matmul over chunks of [`GPU_CHUNK_ROWS`] rows ([`chunked_matmul`]); elsewhere as one matmul.
/// Why: the weight gradient of `x · w` is `xᵀ · g`, one matmul whose inner dimension is N (65,536 points)
/// and whose output is the small `[C, W]` weight: a GPU runs it on the few thread blocks that output
/// tiles into, looping over all N. Batched over chunks, autodiff computes one `xᵀ · g` per chunk and sums
/// them (the broadcast weight's gradient): a split-K that keeps the whole GPU busy (measured on an H200 in
/// docs/PERFORMANCE.md). The CPU backend gains nothing from it and keeps the plain matmul.
pub fn rows_matmul(x: Tensor<2>, w: Tensor<2>) -> Tensor<2> {
    let [n, _] = x.dims();
    if n >= 2 * GPU_CHUNK_ROWS && anerf_device::runs_on_gpu(&x.device()) {
        chunked_matmul(x, w, GPU_CHUNK_ROWS)
    } else {
        x.matmul(w)
    }
}

/// `x · w` (`[N, C] · [C, D]`) as a batched matmul over chunks of `rows` rows: `x` padded with zero rows
/// to whole chunks, viewed as `[chunks, rows, C]`, multiplied by `w` broadcast over the chunks, and cut
/// back to N rows. The same values and gradients as `x.matmul(w)` (the padding's rows get no gradient).
pub fn chunked_matmul(x: Tensor<2>, w: Tensor<2>, rows: usize) -> Tensor<2> {
    let [n, c] = x.dims();
    let [_, d] = w.dims();
    let chunks = n.div_ceil(rows.max(1)).max(1);
    let rows = n.div_ceil(chunks).max(1);
    let padded = chunks * rows;
    let x = if padded > n {
        let device = x.device();
        Tensor::cat(vec![x, Tensor::zeros([padded - n, c], &device)], 0)
    } else {
        x
    };
    let z = x
        .reshape([chunks, rows, c])
        .matmul(w.unsqueeze::<3>())
        .reshape([padded, d]);
    if padded > n {
        z.slice([0..n])
    } else {
        z
    }
}

/// `layer` (weight `[C, W]`, optional bias) applied to `[N, C]` point rows through [`rows_matmul`].
pub fn linear_rows(layer: &Linear, x: Tensor<2>) -> Tensor<2> {
    let z = rows_matmul(x, layer.weight.val());
    match &layer.bias {
        Some(b) => z + b.val().unsqueeze(),
        None => z,
    }
}

/// `layer` applied to the concatenation of `parts` along dimension 1, without building it: `Σ_i x_i · W_i + b`
/// where `W_i` are the rows of the weight that meet part `i`. Saves copying every activation into a wider
/// tensor (and slicing its gradient apart again); a part with one row (a per-batch code) is broadcast.
pub fn linear_over_parts(layer: &Linear, parts: &[Tensor<2>]) -> Tensor<2> {
    linear_parts(layer, parts, None)
}

/// `layer` applied to `[x ⊕ code]` for each point's code (the codes' part of the weight is the last rows):
/// [`linear_over_parts`] with the codes' part mapped once per code ([`Codes::project`]).
pub fn linear_with_codes(layer: &Linear, x: Tensor<2>, codes: &Codes) -> Tensor<2> {
    linear_parts(layer, &[x], Some(codes))
}

/// [`linear_over_parts`] of `parts`, then of `codes` as the last part.
fn linear_parts(layer: &Linear, parts: &[Tensor<2>], codes: Option<&Codes>) -> Tensor<2> {
    let weight = layer.weight.val();
    let [width, _] = weight.dims();
    let mut row = 0;
    let mut out: Option<Tensor<2>> = None;
    let mut add = |z: Tensor<2>| {
        out = Some(match out.take() {
            Some(o) => o + z,
            None => z,
        })
    };
    for part in parts {
        let [_, d] = part.dims();
        add(rows_matmul(part.clone(), weight.clone().narrow(0, row, d)));
        row += d;
    }
    if let Some(codes) = codes {
        let d = width - row;
        add(codes.project(|c| rows_matmul(c, weight.clone().narrow(0, row, d))));
        row += d;
    }
    assert_eq!(
        row, width,
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

    /// `[N, input]` point features and optional codes of the points → `[N, width]` activations.
    pub fn forward(&self, input: Tensor<2>, conditioning: Option<&Codes>) -> Tensor<2> {
        let projected: Vec<Tensor<2>> = match conditioning {
            Some(c) => self
                .conditioning
                .iter()
                .map(|l| c.project(|rows| l.forward(rows)))
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
                linear_rows(layer, h)
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
    use crate::tensor::to_host;
    use anerf_device::cpu_device;
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
        let codes = crate::model::codes::CodeRows::One(0).codes(c.clone());
        let got = to_host(mlp.forward(x.clone(), Some(&codes)));

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

    /// The chunked matmul (what a GPU runs) gives the plain matmul's values and both gradients, also when
    /// the rows are not a whole number of chunks (padding) and when they fit one chunk.
    #[test]
    fn chunked_matmul_equals_the_plain_one_with_its_gradients() {
        let device = cpu_device().autodiff();
        for (n, rows) in [(37, 8), (64, 16), (5, 100)] {
            let x =
                Tensor::<2>::random([n, 6], Distribution::Normal(0.0, 1.0), &device).require_grad();
            let w =
                Tensor::<2>::random([6, 3], Distribution::Normal(0.0, 1.0), &device).require_grad();
            let target = Tensor::<2>::random([n, 3], Distribution::Normal(0.0, 1.0), &device);
            let run = |chunked: bool| {
                let z = if chunked {
                    chunked_matmul(x.clone(), w.clone(), rows)
                } else {
                    x.clone().matmul(w.clone())
                };
                let loss = (z.clone() * target.clone()).sum();
                let grads = loss.backward();
                (
                    to_host(z),
                    to_host(x.grad(&grads).unwrap()),
                    to_host(w.grad(&grads).unwrap()),
                )
            };
            let (plain, chunked) = (run(false), run(true));
            for (name, a, b) in [
                ("value", &plain.0, &chunked.0),
                ("x gradient", &plain.1, &chunked.1),
                ("w gradient", &plain.2, &chunked.2),
            ] {
                assert_eq!(a.len(), b.len(), "{name}");
                for (p, q) in a.iter().zip(b) {
                    assert!(
                        (p - q).abs() <= 1e-5 * (1.0 + p.abs()),
                        "n {n}, rows {rows}, {name}: {p} vs {q}"
                    );
                }
            }
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
