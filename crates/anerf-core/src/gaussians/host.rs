//! The projection of [`super::project`] on plain host arrays, for drawing a baked avatar without
//! gradients at a viewer's pace: the same splat rows (EWA with the Jacobian at the clamped mean, the
//! dilation, the near cut, harmonics in canonical space) computed per Gaussian with glam on rayon's
//! threads instead of as `[N, 3, 3]` tensor operations, with each Gaussian's four joints instead of a dense
//! weight matrix. The tensor version stays the differentiable one; the tests hold the two together.

use glam::{Mat3, Quat, Vec3};
use rayon::prelude::*;

use super::project::{SplatView, DILATION, FRUSTUM_MARGIN, NEAR};
use super::sh;
use crate::geometry::{BoneTransforms, PixelConvention};
use crate::kernels::splat::SPLAT_WIDTH;

/// Joints and weights per Gaussian in a sparse skin.
pub const SKIN_SLOTS: usize = 4;

/// Gaussians on the host, borrowed, one entry per Gaussian: what a splat file holds and what the host
/// projection reads (without the skin).
#[derive(Debug, Clone, Copy)]
pub struct Splats<'a> {
    /// Means, metres (canonical space for an avatar; a splat file's world space for a posed frame).
    pub means: &'a [[f32; 3]],
    /// Logarithms of the standard deviations along the Gaussian's axes.
    pub log_scales: &'a [[f32; 3]],
    /// Quaternions `(w, x, y, z)`.
    pub rotations: &'a [[f32; 4]],
    pub opacity_logits: &'a [f32],
    /// `N × 3·(d+1)²` harmonic coefficients, coefficient-major ([`sh`]).
    pub colours: &'a [f32],
}

/// A cloud on the host, each Gaussian with its four joints: the layout a baked avatar is stored in.
#[derive(Debug, Clone, Copy)]
pub struct HostCloud<'a> {
    /// Canonical Gaussians; quaternions are normalised where they are read.
    pub splats: Splats<'a>,
    pub skin_joints: &'a [[u16; SKIN_SLOTS]],
    pub skin_weights: &'a [[f32; SKIN_SLOTS]],
}

/// The splat rows `[N · SPLAT_WIDTH]` of `cloud` posed by `bones` (canonical → pose space) and seen in
/// `view`, as [`super::project`] computes them.
pub fn project_host(cloud: &HostCloud, bones: &BoneTransforms, view: &SplatView) -> Vec<f32> {
    let splats = &cloud.splats;
    let n = splats.means.len();
    let width = splats.colours.len() / n.max(1);
    let degree = sh::degree_of(width).expect("colour coefficients of degree 0 or 1");
    let camera = view.camera;
    let (w, b) = view.pose_to_camera();
    let k = camera.intrinsics;
    let (fx, skew, cx, fy, cy) = (k.x_axis.x, k.y_axis.x, k.z_axis.x, k.y_axis.y, k.z_axis.y);
    let (width_px, height_px) = (camera.width as f32, camera.height as f32);
    let limit = |c: f32, extent: f32, f: f32| FRUSTUM_MARGIN * c.max(extent - c) / f;
    let (lx, ly) = (limit(cx, width_px, fx), limit(cy, height_px, fy));
    let offset = match view.convention {
        PixelConvention::Integer => 0.0,
        PixelConvention::Center => 0.5,
    };
    let eye = view.global.world_to_pose(camera.center());
    let matrices = bones.matrices();
    let mut rows = vec![0.0f32; n * SPLAT_WIDTH];
    rows.par_chunks_mut(SPLAT_WIDTH)
        .enumerate()
        .for_each(|(i, row)| {
            let blended = cloud.skin_joints[i]
                .iter()
                .zip(&cloud.skin_weights[i])
                .fold(glam::Mat4::ZERO, |acc, (&j, &wt)| {
                    acc + matrices[j as usize] * wt
                });
            let linear = Mat3::from_mat4(blended);
            let posed = blended.transform_point3(Vec3::from(splats.means[i]));
            let cam = w * posed + b;
            let [qw, qx, qy, qz] = splats.rotations[i];
            let q = Quat::from_xyzw(qx, qy, qz, qw);
            let q = q / q.length().max(1e-12);
            let scales = Vec3::from(splats.log_scales[i]).exp();
            let factor = w * linear * Mat3::from_quat(q) * Mat3::from_diagonal(scales);
            let z = cam.z.max(NEAR);
            let tx = (cam.x / z).clamp(-lx, lx) * z;
            let ty = (cam.y / z).clamp(-ly, ly) * z;
            // Rows of the projection's Jacobian at the clamped mean, then G = J · factor (2 × 3).
            let j0 = Vec3::new(fx / z, skew / z, -(tx * fx + ty * skew) / (z * z));
            let j1 = Vec3::new(0.0, fy / z, -(ty * fy) / (z * z));
            let ft = factor.transpose();
            let (g0, g1) = (ft * j0, ft * j1);
            let xx = g0.dot(g0) + DILATION;
            let xy = g0.dot(g1);
            let yy = g1.dot(g1) + DILATION;
            let det = xx * yy - xy * xy;
            let canonical = linear.transpose() * (posed - eye);
            let dir = canonical / canonical.length().max(1e-12);
            let c = &splats.colours[i * width..(i + 1) * width];
            let coefficient = |m: usize| Vec3::new(c[3 * m], c[3 * m + 1], c[3 * m + 2]);
            let mut colour = coefficient(0) * sh::C0 + Vec3::splat(0.5);
            if degree == 1 {
                colour +=
                    (coefficient(2) * dir.z - coefficient(1) * dir.y - coefficient(3) * dir.x)
                        * sh::C1;
            }
            let colour = colour.max(Vec3::ZERO);
            let opacity = 1.0 / (1.0 + (-splats.opacity_logits[i]).exp());
            let in_front = if cam.z > NEAR { 1.0 } else { 0.0 };
            row.copy_from_slice(&[
                (cam.x * fx + cam.y * skew) / z + (cx - offset),
                cam.y * fy / z + (cy - offset),
                yy / det,
                -xy / det,
                xx / det,
                colour.x,
                colour.y,
                colour.z,
                opacity * in_front,
                z,
            ]);
        });
    rows
}
