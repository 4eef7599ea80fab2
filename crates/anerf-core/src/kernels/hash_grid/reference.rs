//! The hash-grid encoding in plain tensor operations: what every backend without the kernels runs, and
//! what the kernels' tests compare against.

use burn::prelude::*;

use super::{GridSpec, HASH_PRIMES};

/// The encoding in plain tensor operations: all `8 L` corners of every point are gathered from the table
/// with one `select` (one `select` per corner makes the backward pass about 25× slower).
pub fn encode(points: Tensor<2>, table: Tensor<2>, spec: &GridSpec) -> Tensor<2> {
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
