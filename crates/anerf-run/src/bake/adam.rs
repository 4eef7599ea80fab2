//! Adam for the avatar's tensors, with a learning rate per tensor and state that follows its rows when
//! Gaussians are split or pruned (Burn's optimisers keep state per parameter of fixed shape).

use burn::prelude::*;

/// Adam on one `[N, D]` tensor: `β₁ = 0.9`, `β₂ = 0.999`, `ε = 1e-15` (3DGS's).
#[derive(Debug, Clone)]
pub struct RowAdam {
    lr: f64,
    m: Tensor<2>,
    v: Tensor<2>,
    steps: i32,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPSILON: f64 = 1e-15;

impl RowAdam {
    /// Fresh state for a tensor of `dims`, stepping at `lr`.
    pub fn new(dims: [usize; 2], lr: f64, device: &Device) -> Self {
        Self {
            lr,
            m: Tensor::zeros(dims, device),
            v: Tensor::zeros(dims, device),
            steps: 0,
        }
    }

    /// Sets the learning rate of the next steps.
    pub fn set_lr(&mut self, lr: f64) {
        self.lr = lr;
    }

    /// `value` moved one step against `grad` (both without autodiff).
    pub fn step(&mut self, value: Tensor<2>, grad: Tensor<2>) -> Tensor<2> {
        self.steps += 1;
        self.m = self.m.clone() * BETA1 + grad.clone() * (1.0 - BETA1);
        self.v = self.v.clone() * BETA2 + grad.powi_scalar(2) * (1.0 - BETA2);
        let m_hat = self.m.clone() / (1.0 - BETA1.powi(self.steps));
        let v_hat = self.v.clone() / (1.0 - BETA2.powi(self.steps));
        value - m_hat / (v_hat.sqrt() + EPSILON) * self.lr
    }

    /// The state of rows `rows` (repeats allowed), for the tensor gathered the same way.
    pub fn select(&mut self, rows: Tensor<1, Int>) {
        self.m = self.m.clone().select(0, rows.clone());
        self.v = self.v.clone().select(0, rows);
    }
}
