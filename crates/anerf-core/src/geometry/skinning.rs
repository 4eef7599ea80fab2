//! Batched, differentiable linear blend skinning on Burn tensors: the per-sample warp of the renderer.
//!
//! Points are rows (`[N, 3]`, metres), weights are rows (`[N, K]`); bone transforms are stored as the top
//! three rows of each 4×4 `A_k` flattened row-major into `[K, 12]` = `[r00 r01 r02 t0 r10 … t2]`, so that
//! blending all points is one matmul `W · A`.

use burn::prelude::*;
use glam::{Mat3, Mat4, Vec3};

use super::skeleton::{BoneTransforms, GlobalTransform};

/// One frame's bone transforms `A_k` on a device, `[K, 12]` (row-major top 3×4 of each matrix).
#[derive(Debug, Clone)]
pub struct BoneMatrices {
    rows: Tensor<2>,
}

impl BoneMatrices {
    /// Uploads `transforms` to `device`.
    pub fn new(transforms: &BoneTransforms, device: &Device) -> Self {
        let data: Vec<f32> = transforms
            .matrices()
            .iter()
            .flat_map(|m| top_rows(*m))
            .collect();
        let k = transforms.len();
        Self {
            rows: Tensor::<1>::from_floats(data.as_slice(), device).reshape([k, 12]),
        }
    }

    /// Wraps bone rows `[K, 12]` already on a device (e.g. computed, with gradients, from refined poses).
    pub fn from_rows(rows: Tensor<2>) -> Self {
        assert_eq!(rows.dims()[1], 12, "bone rows are [K, 12]");
        Self { rows }
    }

    /// Number of joints `K`.
    pub fn num_joints(&self) -> usize {
        self.rows.dims()[0]
    }

    /// The `[K, 12]` tensor.
    pub fn rows(&self) -> Tensor<2> {
        self.rows.clone()
    }

    /// Blended matrices `M = W · A`, `[N, 12]`.
    fn blend(&self, weights: Tensor<2>) -> Tensor<2> {
        weights.matmul(self.rows.clone())
    }

    /// Forward LBS, canonical → pose space: `x_pose = rot(M) x + t(M)` for points `[N, 3]` and weights `[N, K]`.
    pub fn forward(&self, points: Tensor<2>, weights: Tensor<2>) -> Tensor<2> {
        let [n, _] = points.dims();
        let m = self.blend(weights).reshape([n, 3, 4]);
        let ones = Tensor::ones([n, 1], &points.device());
        let homogeneous = Tensor::cat(vec![points, ones], 1).reshape([n, 1, 4]);
        (m * homogeneous).sum_dim(2).reshape([n, 3])
    }

    /// Inverse LBS, pose space → canonical: `x_can = rot(M)⁻¹ (x_pose − t(M))` with `M` blended from the
    /// observation weights; points `[N, 3]`, weights `[N, K]` → `[N, 3]`. Differentiable in both (and in the
    /// bones, where they are tracked). A blended rotation whose `|det|` is below
    /// [`crate::kernels::warp::DET_GUARD`] (weights split between opposing bones) is inverted with the guard
    /// instead, so the output stays finite. The kernel or its reference: [`crate::kernels::warp::inverse_skinning`].
    pub fn inverse(&self, points: Tensor<2>, weights: Tensor<2>) -> Tensor<2> {
        crate::kernels::warp::inverse_skinning(points, weights, self.rows())
    }
}

/// World → pose space for points `[N, 3]`: `x_pose = R_hᵀ (x − T_h)`, i.e. rows `(x − T_h)ᵀ R_h`.
pub fn world_to_pose(points: Tensor<2>, global: &GlobalTransform) -> Tensor<2> {
    let device = points.device();
    let r =
        Tensor::<1>::from_floats(row_major(global.rotation()).as_slice(), &device).reshape([3, 3]);
    let th = Tensor::<1>::from_floats(global.th.to_array().as_slice(), &device).reshape([1, 3]);
    (points - th).matmul(r)
}

/// Directions `[N, 3]` from world to pose space (rotation only).
pub fn world_to_pose_directions(dirs: Tensor<2>, global: &GlobalTransform) -> Tensor<2> {
    let r = Tensor::<1>::from_floats(row_major(global.rotation()).as_slice(), &dirs.device())
        .reshape([3, 3]);
    dirs.matmul(r)
}

fn row_major(m: Mat3) -> [f32; 9] {
    m.transpose().to_cols_array()
}

fn top_rows(m: Mat4) -> [f32; 12] {
    let r = m.transpose().to_cols_array(); // rows of m, 4 at a time
    let mut out = [0.0; 12];
    out.copy_from_slice(&r[..12]);
    out
}

/// Points as a `[N, 3]` tensor.
pub fn points_tensor(points: &[Vec3], device: &Device) -> Tensor<2> {
    let flat: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
    crate::tensor::from_rows(&flat, points.len(), 3, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::lbs::tests::{random_skeleton_and_pose, TestRng};
    use crate::geometry::{forward_lbs_point, inverse_lbs_point, CanonicalPose};
    use crate::tensor::to_host;

    fn setup(
        rng: &mut TestRng,
        n: usize,
    ) -> (BoneTransforms, GlobalTransform, Vec<Vec3>, Vec<Vec<f32>>) {
        let (skeleton, pose) = random_skeleton_and_pose(rng);
        let a = skeleton
            .bone_transforms(&pose, CanonicalPose::TPose)
            .unwrap();
        let points = (0..n).map(|_| rng.vec3(1.0)).collect();
        let weights = (0..n).map(|_| rng.weights(24)).collect();
        (a, pose.global, points, weights)
    }

    fn weights_tensor(w: &[Vec<f32>], device: &Device) -> Tensor<2> {
        let flat: Vec<f32> = w.iter().flatten().copied().collect();
        crate::tensor::from_rows(&flat, w.len(), w[0].len(), device)
    }

    #[test]
    fn tensor_lbs_matches_single_point_lbs_and_inverts() {
        let device = anerf_device::cpu_device();
        let mut rng = TestRng(11);
        let (a, _, points, weights) = setup(&mut rng, 200);
        let bones = BoneMatrices::new(&a, &device);
        let p = points_tensor(&points, &device);
        let w = weights_tensor(&weights, &device);
        let posed = bones.forward(p, w.clone());
        let back = to_host(bones.inverse(posed.clone(), w));
        let posed = to_host(posed);
        for i in 0..points.len() {
            let expect = forward_lbs_point(points[i], &weights[i], &a).unwrap();
            let got = Vec3::from_slice(&posed[3 * i..3 * i + 3]);
            assert!((got - expect).length() < 1e-5);
            let inv = inverse_lbs_point(expect, &weights[i], &a).unwrap();
            assert!((Vec3::from_slice(&back[3 * i..3 * i + 3]) - inv).length() < 1e-4);
            assert!((inv - points[i]).length() < 1e-4);
        }
    }

    /// The same warp on every compiled CPU backend (flex is the reference); agreement within 1e-5 m.
    #[test]
    fn cpu_backends_agree() {
        let mut rng = TestRng(13);
        let (a, _, points, weights) = setup(&mut rng, 64);
        let run = |device: Device| {
            let bones = BoneMatrices::new(&a, &device);
            let w = weights_tensor(&weights, &device);
            to_host(bones.inverse(
                bones.forward(points_tensor(&points, &device), w.clone()) * 1.1,
                w,
            ))
        };
        let reference = run(anerf_device::cpu_device());
        let ndarray = run(crate::DeviceChoice::Ndarray
            .device()
            .expect("the ndarray feature is on by default"));
        for (a, b) in reference.iter().zip(&ndarray) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    #[test]
    fn world_to_pose_matches_glam() {
        let device = anerf_device::cpu_device();
        let mut rng = TestRng(3);
        let (_, global, points, _) = setup(&mut rng, 50);
        let got = to_host(world_to_pose(points_tensor(&points, &device), &global));
        for (i, p) in points.iter().enumerate() {
            assert!(
                (Vec3::from_slice(&got[3 * i..3 * i + 3]) - global.world_to_pose(*p)).length()
                    < 1e-5
            );
        }
    }

    #[test]
    fn singular_blends_stay_finite() {
        let device = anerf_device::cpu_device();
        let a = BoneTransforms::from_matrices(vec![
            Mat4::IDENTITY,
            Mat4::from_rotation_z(std::f32::consts::PI),
        ])
        .unwrap();
        let bones = BoneMatrices::new(&a, &device);
        let out = to_host(bones.inverse(
            points_tensor(&[Vec3::ONE], &device),
            Tensor::<2>::from_floats([[0.5, 0.5]], &device),
        ));
        assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
    }

    /// Central differences of `Σ inverse(x, w) · c` in every input coordinate against autodiff.
    #[test]
    fn inverse_gradients_match_finite_differences() {
        let device = anerf_device::cpu_device().autodiff();
        let mut rng = TestRng(5);
        let (a, _, points, weights) = setup(&mut rng, 4);
        let bones = BoneMatrices::new(&a, &device);
        let coeff = Tensor::<2>::from_floats([[0.3, -1.1, 0.7]], &device);
        let eval = |p: &[Vec3], w: &[Vec<f32>]| -> f64 {
            let out = bones.inverse(points_tensor(p, &device), weights_tensor(w, &device));
            (out * coeff.clone()).sum().into_scalar::<f32>() as f64
        };
        let p = points_tensor(&points, &device).require_grad();
        let w = weights_tensor(&weights, &device).require_grad();
        let grads = (bones.inverse(p.clone(), w.clone()) * coeff.clone())
            .sum()
            .backward();
        let gp = to_host(p.grad(&grads).unwrap());
        let gw = to_host(w.grad(&grads).unwrap());
        let h = 1e-2f32;
        for i in 0..points.len() {
            for c in 0..3 {
                let (mut plus, mut minus) = (points.clone(), points.clone());
                plus[i][c] += h;
                minus[i][c] -= h;
                let fd = (eval(&plus, &weights) - eval(&minus, &weights)) / (2.0 * h as f64);
                assert!(
                    (fd - gp[3 * i + c] as f64).abs() < 2e-2 * (1.0 + fd.abs()),
                    "dx {fd} vs {}",
                    gp[3 * i + c]
                );
            }
            for k in [0usize, 3, 16] {
                let (mut plus, mut minus) = (weights.clone(), weights.clone());
                plus[i][k] += h;
                minus[i][k] -= h;
                let fd = (eval(&points, &plus) - eval(&points, &minus)) / (2.0 * h as f64);
                let g = gw[24 * i + k] as f64;
                assert!((fd - g).abs() < 2e-2 * (1.0 + fd.abs()), "dw {fd} vs {g}");
            }
        }
    }
}
