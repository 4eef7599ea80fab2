//! Posing and projection: canonical Gaussians → pose space by linear blend skinning → a camera's image
//! plane, as the splat rows [`crate::kernels::splat`] rasterises (EWA splatting: the covariance through
//! the projection's Jacobian at the mean).

use burn::prelude::*;
use glam::{Mat3, Vec3};

use super::cloud::GaussianCloud;
use super::sh;
use crate::geometry::{BoneMatrices, Camera, GlobalTransform, PixelConvention};
use crate::kernels::splat::{self, RasterSpec, PIXEL_WIDTH, SPLAT_WIDTH};
use crate::tensor::from_rows;

/// Gaussians nearer the camera than this (metres, along its axis), or behind it, are dropped.
pub const NEAR: f32 = 0.01;
/// Variance added to the diagonal of every projected covariance (pixels²): 3DGS's low-pass filter, about
/// a pixel's footprint, so that no splat falls between pixel centres.
pub const DILATION: f32 = 0.3;
/// Off-screen means are clamped to this multiple of the image's half-extent before the Jacobian is taken
/// (as 3DGS), so that Gaussians far outside the view do not turn into enormous splats.
pub(super) const FRUSTUM_MARGIN: f32 = 1.3;

/// One image of one frame: its camera (world frame), the frame's global transform (pose space → world)
/// and where a pixel's ray passes through it (the run's convention, so that images line up with the
/// NeRF's).
#[derive(Debug, Clone, Copy)]
pub struct SplatView<'a> {
    pub camera: &'a Camera,
    pub global: &'a GlobalTransform,
    pub convention: PixelConvention,
}

impl SplatView<'_> {
    /// The image's size.
    pub fn spec(&self) -> RasterSpec {
        RasterSpec {
            width: self.camera.width,
            height: self.camera.height,
        }
    }

    /// Pose space → camera frame, `x_cam = W x_pose + b`: the global transform then the camera's.
    pub(super) fn pose_to_camera(&self) -> (Mat3, Vec3) {
        let (r, t) = (self.camera.rotation, self.camera.translation);
        let rh = self.global.rotation();
        (r * rh, r * self.global.th + t)
    }
}

/// The splat rows `[N, SPLAT_WIDTH]` of `cloud` posed by `bones` (canonical → pose space) with its blend
/// weights `weights` `[N, K]`, seen in `view`; differentiable in the cloud (and in the bones and weights).
pub fn project(
    cloud: &GaussianCloud,
    weights: Tensor<2>,
    bones: &BoneMatrices,
    view: &SplatView,
) -> Tensor<2> {
    let n = cloud.len();
    let device = weights.device();
    let blended = weights.matmul(bones.rows()).reshape([n, 3, 4]);
    let linear = blended.clone().slice([0..n, 0..3, 0..3]);
    let shift = blended.slice([0..n, 0..3, 3..4]).reshape([n, 3]);
    let posed =
        batched(linear.clone(), cloud.means.val().reshape([n, 3, 1])).reshape([n, 3]) + shift;
    let (w, b) = view.pose_to_camera();
    let w_t = matrix(w.transpose(), &device);
    let cam = posed.clone().matmul(w_t.clone()) + from_rows(&b.to_array(), 1, 3, &device);
    // Σ_cam = (W·L·R·S)(W·L·R·S)ᵀ with L the blended linear part: W·L per Gaussian as one 2-D matmul of
    // the stacked columns of L.
    let wl = linear
        .clone()
        .swap_dims(1, 2)
        .reshape([n * 3, 3])
        .matmul(w_t)
        .reshape([n, 3, 3])
        .swap_dims(1, 2);
    let factor = batched(wl, cloud.covariance_factor());
    let column = |t: &Tensor<2>, i: usize| t.clone().slice([0..n, i..i + 1]);
    let depth = column(&cam, 2);
    let in_front = depth.clone().greater_elem(NEAR).float();
    let z = depth.clamp_min(NEAR);
    let (x, y) = (column(&cam, 0), column(&cam, 1));
    let k = view.camera.intrinsics;
    let (fx, skew, cx, fy, cy) = (k.x_axis.x, k.y_axis.x, k.z_axis.x, k.y_axis.y, k.z_axis.y);
    let (width, height) = (view.camera.width as f32, view.camera.height as f32);
    let limit = |c: f32, extent: f32, f: f32| FRUSTUM_MARGIN * c.max(extent - c) / f;
    let (lx, ly) = (limit(cx, width, fx), limit(cy, height, fy));
    let tx = (x.clone() / z.clone()).clamp(-lx, lx) * z.clone();
    let ty = (y.clone() / z.clone()).clamp(-ly, ly) * z.clone();
    let inv_z = z.clone().recip();
    let inv_z2 = inv_z.clone().powi_scalar(2);
    let zero = Tensor::zeros([n, 1], &device);
    let jacobian = Tensor::cat(
        vec![
            inv_z.clone() * fx,
            inv_z.clone() * skew,
            (tx * fx + ty.clone() * skew).neg() * inv_z2.clone(),
            zero,
            inv_z.clone() * fy,
            (ty * fy).neg() * inv_z2,
        ],
        1,
    )
    .reshape([n, 2, 3]);
    let g = batched(jacobian, factor);
    let cov = batched(g.clone(), g.swap_dims(1, 2)).reshape([n, 4]);
    let xx = column(&cov, 0) + DILATION;
    let xy = column(&cov, 1);
    let yy = column(&cov, 3) + DILATION;
    let det = xx.clone() * yy.clone() - xy.clone().powi_scalar(2);
    let offset = match view.convention {
        PixelConvention::Integer => 0.0,
        PixelConvention::Center => 0.5,
    };
    let u = (x * fx + y.clone() * skew) * inv_z.clone() + (cx - offset);
    let v = y * fy * inv_z + (cy - offset);
    // View directions in canonical space: camera → Gaussian in pose space, back through Lᵀ.
    let eye = view.global.world_to_pose(view.camera.center());
    let towards = posed - from_rows(&eye.to_array(), 1, 3, &device);
    let canonical = batched(linear.swap_dims(1, 2), towards.reshape([n, 3, 1])).reshape([n, 3]);
    let norm = canonical
        .clone()
        .powi_scalar(2)
        .sum_dim(1)
        .sqrt()
        .clamp_min(1e-12);
    let colour = sh::colour(cloud.colours.val(), canonical / norm);
    Tensor::cat(
        vec![
            u,
            v,
            yy.clone() / det.clone(),
            xy.neg() / det.clone(),
            xx / det,
            colour,
            cloud.opacities() * in_front,
            z.detach(),
        ],
        1,
    )
}

/// The cloud rendered into `view`'s image, `[H·W, PIXEL_WIDTH]` (premultiplied colour and alpha, no
/// background).
pub fn render(
    cloud: &GaussianCloud,
    weights: Tensor<2>,
    bones: &BoneMatrices,
    view: &SplatView,
) -> Tensor<2> {
    let spec = view.spec();
    if cloud.is_empty() {
        return Tensor::zeros([spec.pixels(), PIXEL_WIDTH], &weights.device());
    }
    let splats = project(cloud, weights, bones, view);
    debug_assert_eq!(splats.dims()[1], SPLAT_WIDTH);
    splat::rasterize(splats, &spec)
}

/// The products `a_i · b_i` of one small matrix per row, `[N, I, K] · [N, K, J] → [N, I, J]`, as broadcast
/// products summed over `K`: flex's batched matmul calls a GEMM for each 3 × 3 pair, which costs far more
/// than their 27 multiplications.
fn batched(a: Tensor<3>, b: Tensor<3>) -> Tensor<3> {
    let [n, i, _] = a.dims();
    let j = b.dims()[2];
    (a.unsqueeze_dim::<4>(3) * b.unsqueeze_dim::<4>(1))
        .sum_dim(2)
        .reshape([n, i, j])
}

/// A glam matrix as a row-major `[3, 3]` tensor.
fn matrix(m: Mat3, device: &Device) -> Tensor<2> {
    from_rows(&m.transpose().to_cols_array(), 3, 3, device)
}
