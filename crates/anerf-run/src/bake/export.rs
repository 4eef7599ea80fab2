//! `anerf export --format ply`: the baked avatar in 3D Gaussian Splatting's PLY layout — the canonical
//! Gaussians (`avatar.ply`) with their skin and skeleton beside them (`skin.json`), and the Gaussians posed
//! at every frame of an animation (`frames/frame_<k>.ply`, world space) for viewers that do not skin, and
//! what a viewer that skins needs to play it (`motion.json`: the frames' joint matrices and the cameras).

use std::path::{Path, PathBuf};

use anerf_core::gaussians::{sh, Splats};
use anerf_core::geometry::{
    blend_transforms, mean_up, BoneTransforms, Camera, CanonicalPose, GlobalTransform,
};
use anerf_data::atomic::write_bytes;
use anerf_eval::splat_ply::{write_splat_ply, SplatCloud};
use anyhow::{bail, Context, Result};
use glam::{Mat3, Quat, Vec3};
use serde::Serialize;

use super::store::{BakedAvatar, SKIN_SLOTS};
use crate::export::animation;
use crate::memory::Work;
use crate::motion::MotionRequest;
use crate::{device, load_trained, open_run, JobOptions};
use anerf_train::experiment::Experiment;

/// What `anerf export --format ply` writes.
#[derive(Debug, Clone)]
pub struct SplatExportJob {
    /// The animation: this motion, else the training frames.
    pub motion: Option<MotionRequest>,
    /// Dataset camera a placed motion faces (default: the first training view).
    pub view: Option<usize>,
    /// The folder (default `<run>/export/splats/`).
    pub out: Option<PathBuf>,
    /// Replace existing files.
    pub overwrite: bool,
}

/// What a splat export wrote.
#[derive(Debug, Clone)]
pub struct SplatExported {
    pub dir: PathBuf,
    pub gaussians: usize,
    pub frames: usize,
    pub fps: f64,
}

/// `skin.json`: each Gaussian's four joints and weights (the rows of `avatar.ply`), and the skeleton they
/// index (rest joints in canonical space, metres; parent of each joint, `null` for the root).
#[derive(Debug, Serialize)]
struct SkinFile<'a> {
    joints: &'a [[u16; SKIN_SLOTS]],
    weights: &'a [[f32; SKIN_SLOTS]],
    rest_joints: Vec<[f32; 3]>,
    parents: &'a [Option<usize>],
}

/// `motion.json`: what a viewer needs to skin `avatar.ply` on the GPU and see it as the dataset did.
#[derive(Debug, Serialize)]
struct SplatMotion {
    fps: f64,
    /// Per frame, per joint: canonical → world, the bone's transform then the frame's global one
    /// (column-major 4×4, as WebGL takes matrices). A Gaussian's is the blend of its four joints'.
    frames: Vec<Vec<[f32; 16]>>,
    /// The dataset frame each animation frame is (the training motion's; empty for a motion file's).
    dataset_frames: Vec<usize>,
    cameras: Vec<ViewerCamera>,
    /// The world's up (the cameras' mean), for an orbit.
    up: [f32; 3],
}

/// A dataset camera as a viewer takes it: world → camera `x_cam = R x + T` (metres), `K` in pixels of a
/// `width × height` image (rows), the first pixel's centre at (0, 0) (the images' lens distortion is left
/// out).
#[derive(Debug, Serialize)]
struct ViewerCamera {
    view: usize,
    /// Whether the run trained on this view.
    training: bool,
    width: u32,
    height: u32,
    intrinsics: [[f32; 3]; 3],
    rotation: [[f32; 3]; 3],
    translation: [f32; 3],
}

impl ViewerCamera {
    fn of(view: usize, training: bool, camera: &Camera) -> Self {
        Self {
            view,
            training,
            width: camera.width,
            height: camera.height,
            intrinsics: camera.intrinsics.transpose().to_cols_array_2d(),
            rotation: camera.rotation.transpose().to_cols_array_2d(),
            translation: camera.translation.to_array(),
        }
    }
}

/// Writes the baked avatar of the run at `run_path` as PLY files (see the module doc).
pub fn export_splats(
    run_path: &Path,
    job: &SplatExportJob,
    options: &JobOptions,
) -> Result<SplatExported> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let dir = job
        .out
        .clone()
        .unwrap_or_else(|| run.exports().join("splats"));
    let canonical_file = dir.join("avatar.ply");
    if canonical_file.exists() && !job.overwrite {
        bail!(
            "{} exists; give --overwrite to replace it, or another --out",
            canonical_file.display()
        );
    }
    let avatar = super::load_baked(&run)?;
    let device = device(&config, options)?;
    let model = load_trained(&run, &config, &device)?;
    let exp = Experiment::open(config, device, options.progress)?;
    let (_, fps, poses) = animation(job.motion.as_ref(), job.view, &exp, &model)?;
    write_splat_ply(
        &canonical_file,
        &SplatCloud {
            splats: avatar.splats(),
            sh_degree: avatar.info.sh_degree,
        },
    )?;
    let skeleton = &exp.prepared.skeleton;
    let skin = SkinFile {
        joints: &avatar.skin_joints,
        weights: &avatar.skin_weights,
        rest_joints: skeleton
            .rest_joints()
            .iter()
            .map(|j| j.to_array())
            .collect(),
        parents: skeleton.parents(),
    };
    write_bytes(
        &dir.join("skin.json"),
        serde_json::to_string(&skin)?.as_bytes(),
    )?;
    let mut frames = Vec::with_capacity(poses.len());
    for (k, pose) in poses.iter().enumerate() {
        let bones = skeleton.bone_transforms(pose, CanonicalPose::TPose)?;
        let posed = PosedSplats::of(&avatar, &bones, &pose.global)?;
        let file = dir.join("frames").join(format!("frame_{k:06}.ply"));
        write_splat_ply(&file, &posed.cloud(&avatar))?;
        let world = pose.global.pose_to_world_matrix();
        frames.push(
            bones
                .matrices()
                .iter()
                .map(|a| (world * *a).to_cols_array())
                .collect(),
        );
    }
    let cameras = &exp.prepared.cameras;
    let dataset_frames = match job.motion {
        Some(_) => Vec::new(),
        None => exp.train_frames.iter().map(|f| f.0).collect(),
    };
    let motion = SplatMotion {
        fps,
        frames,
        dataset_frames,
        cameras: cameras
            .iter()
            .enumerate()
            .map(|(v, c)| ViewerCamera::of(v, exp.train_views.iter().any(|t| t.0 == v), c))
            .collect(),
        up: mean_up(cameras).to_array(),
    };
    write_bytes(
        &dir.join("motion.json"),
        serde_json::to_string(&motion)?.as_bytes(),
    )?;
    Ok(SplatExported {
        dir,
        gaussians: avatar.means.len(),
        frames: poses.len(),
        fps,
    })
}

/// The avatar's Gaussians posed into world space: means by their blended bone transform then the global
/// transform; orientations turned by the rotation nearest the blended linear part (the blend's small
/// stretch is left out, as splat files hold no shear); degree-1 colour coefficients turned with them, so
/// that a viewer's world-space view direction sees the colours the canonical directions gave.
#[derive(Debug, Clone)]
pub struct PosedSplats {
    pub means: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub colours: Vec<f32>,
}

impl PosedSplats {
    /// The posed Gaussians with `avatar`'s scales and opacities, for a splat file.
    pub fn cloud<'a>(&'a self, avatar: &'a BakedAvatar) -> SplatCloud<'a> {
        SplatCloud {
            splats: Splats {
                means: &self.means,
                rotations: &self.rotations,
                colours: &self.colours,
                ..avatar.splats()
            },
            sh_degree: avatar.info.sh_degree,
        }
    }

    pub fn of(
        avatar: &BakedAvatar,
        bones: &BoneTransforms,
        global: &GlobalTransform,
    ) -> Result<Self> {
        let k = avatar.info.joints;
        let width = 3 * sh::coefficients(avatar.info.sh_degree);
        let rh = global.rotation();
        let mut out = Self {
            means: Vec::with_capacity(avatar.means.len()),
            rotations: Vec::with_capacity(avatar.means.len()),
            colours: avatar.colours.clone(),
        };
        for i in 0..avatar.means.len() {
            let mut dense = vec![0.0f32; k];
            for (&j, &w) in avatar.skin_joints[i].iter().zip(&avatar.skin_weights[i]) {
                dense[j as usize] += w;
            }
            let m = blend_transforms(&dense, bones)
                .with_context(|| format!("the skin of Gaussian {i}"))?;
            let mean = global.pose_to_world(m.transform_point3(Vec3::from(avatar.means[i])));
            let turn = rh * nearest_rotation(Mat3::from_mat4(m));
            let [w, x, y, z] = avatar.rotations[i];
            let q = (Quat::from_mat3(&turn) * Quat::from_xyzw(x, y, z, w)).normalize();
            out.means.push(mean.to_array());
            out.rotations.push([q.w, q.x, q.y, q.z]);
            if avatar.info.sh_degree == 1 {
                let row = &mut out.colours[i * width..(i + 1) * width];
                for c in 0..3 {
                    // The degree-1 term is C1·(d · v) with v = (−k₃, −k₁, k₂): v turns as a vector.
                    let v = turn * Vec3::new(-row[9 + c], -row[3 + c], row[6 + c]);
                    row[3 + c] = -v.y;
                    row[6 + c] = v.z;
                    row[9 + c] = -v.x;
                }
            }
        }
        Ok(out)
    }
}

/// The rotation nearest `m` (its orthonormalised columns, Gram–Schmidt from the first): exact for rigid
/// bones, and close for the near-rigid blends of skinning.
fn nearest_rotation(m: Mat3) -> Mat3 {
    let x = m.x_axis.normalize_or_zero();
    let y = (m.y_axis - x * x.dot(m.y_axis)).normalize_or_zero();
    Mat3::from_cols(x, y, x.cross(y))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::store::AvatarInfo;
    use anerf_core::gaussians::{project, SplatView};
    use anerf_core::geometry::{BoneMatrices, Camera, Distortion, PixelConvention};
    use anerf_core::tensor::to_host;
    use glam::Mat4;

    /// Gaussians posed by rigid bones (every joint the same turn and shift) and a global transform.
    fn scene() -> (BakedAvatar, BoneTransforms, GlobalTransform, Mat3) {
        let n = 6;
        let v = |i: usize, k: usize| ((i * 37 + k * 11) % 23) as f32 / 23.0 - 0.5;
        let avatar = BakedAvatar {
            info: AvatarInfo {
                gaussians: n,
                sh_degree: 1,
                joints: 24,
                source: String::new(),
                steps: 0,
                seconds: 0.0,
                training_psnr: 0.0,
            },
            means: (0..n).map(|i| [v(i, 0), v(i, 1), v(i, 2)]).collect(),
            log_scales: (0..n)
                .map(|i| [v(i, 3) - 3.0, v(i, 4) - 3.5, v(i, 5) - 4.0])
                .collect(),
            rotations: (0..n).map(|i| [0.8, v(i, 6), v(i, 7), v(i, 8)]).collect(),
            opacity_logits: vec![1.0; n],
            colours: (0..n * 12).map(|i| v(i, 9) * 0.5).collect(),
            skin_joints: (0..n).map(|i| [(i % 24) as u16, 5, 0, 0]).collect(),
            skin_weights: (0..n).map(|_| [0.6, 0.4, 0.0, 0.0]).collect(),
        };
        let turn = Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let bone = Mat4::from_rotation_translation(turn, Vec3::new(0.2, -0.1, 0.4));
        let bones = BoneTransforms::from_matrices(vec![bone; 24]).unwrap();
        let global = GlobalTransform {
            rh: Vec3::new(0.1, 0.5, -0.2),
            th: Vec3::new(0.3, 0.0, 1.0),
        };
        let world_turn = global.rotation() * Mat3::from_quat(turn);
        (avatar, bones, global, world_turn)
    }

    /// The posed file's means, covariances and degree-1 colours are what the renderer computes from the
    /// canonical avatar (its projection, and the canonical view direction), for rigid bones.
    #[test]
    fn posed_splats_are_the_renderers_posed_gaussians() {
        let (avatar, bones, global, world_turn) = scene();
        let posed = PosedSplats::of(&avatar, &bones, &global).unwrap();
        let camera = Camera {
            intrinsics: Mat3::from_cols_array_2d(&[
                [300.0, 0.0, 0.0],
                [0.0, 300.0, 0.0],
                [128.0, 96.0, 1.0],
            ]),
            rotation: Mat3::IDENTITY,
            translation: Vec3::new(-0.3, 0.0, 5.0),
            distortion: Distortion::default(),
            width: 256,
            height: 192,
        };
        let device = anerf_device::cpu_device();
        let view = SplatView {
            camera: &camera,
            global: &global,
            convention: PixelConvention::Integer,
        };
        let rows = to_host(project(
            &avatar.cloud(&device),
            avatar.skin(&device),
            &BoneMatrices::new(&bones, &device),
            &view,
        ));
        for i in 0..avatar.means.len() {
            let row = &rows[i * 10..(i + 1) * 10];
            let mean = Vec3::from(posed.means[i]);
            let pixel = camera.project(mean, PixelConvention::Integer).unwrap();
            assert!((pixel.x - row[0]).abs() < 1e-3 && (pixel.y - row[1]).abs() < 1e-3);
            // Covariance: the exported orientation with the canonical scales is the canonical
            // covariance turned by the bone and the global rotation.
            let covariance = |q: [f32; 4]| {
                let r = Mat3::from_quat(Quat::from_xyzw(q[1], q[2], q[3], q[0]).normalize());
                let s = Mat3::from_diagonal(Vec3::from(avatar.log_scales[i]).exp());
                r * s * s * r.transpose()
            };
            let expected = world_turn * covariance(avatar.rotations[i]) * world_turn.transpose();
            let got = covariance(posed.rotations[i]);
            assert!(
                (got - expected)
                    .to_cols_array()
                    .iter()
                    .all(|d| d.abs() < 1e-6),
                "Gaussian {i}: {got} vs {expected}"
            );
            // Colour: the posed coefficients seen along the world view direction.
            let d = (mean - camera.center()).normalize();
            let k = &posed.colours[i * 12..(i + 1) * 12];
            for c in 0..3 {
                let colour = (0.5
                    + sh::C0 * k[c]
                    + sh::C1 * (-d.y * k[3 + c] + d.z * k[6 + c] - d.x * k[9 + c]))
                    .max(0.0);
                assert!(
                    (colour - row[5 + c]).abs() < 1e-4,
                    "Gaussian {i} channel {c}"
                );
            }
        }
    }
}
