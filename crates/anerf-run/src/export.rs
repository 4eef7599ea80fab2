//! Exporting a run as a skinned glTF binary: the canonical mesh with its NeRF colours and the learned
//! canonical blend weights (four per vertex), the skeleton, and the training motion or any motion.

use std::path::{Path, PathBuf};

use anerf_core::geometry::Pose;
use anerf_eval::gltf_export::{top_weights, write_glb, JointAnimation, JointFrame, SkinnedMesh};
use anyhow::{bail, Context, Result};
use glam::{Quat, Vec3};

use crate::memory::Work;
use crate::mesh::canonical_surface;
use crate::mesh::MeshJob;
use crate::motion::{MotionClip, MotionRequest};
use crate::{device, load_trained, open_run, JobOptions};
use anerf_train::experiment::Experiment;

/// Frames per second of the training motion (the datasets' captures record none).
pub const TRAINING_FPS: f64 = 30.0;

/// What `anerf export` writes.
#[derive(Debug, Clone)]
pub struct ExportJob {
    /// Voxel, iso level and smoothing of the canonical mesh (its frame lists are unused).
    pub surface: MeshJob,
    /// The animation: this motion, else the training frames at [`TRAINING_FPS`].
    pub motion: Option<MotionRequest>,
    /// Dataset camera a placed motion faces (default: the first training view).
    pub view: Option<usize>,
    /// The file (default `<run>/export/avatar.glb`).
    pub out: Option<PathBuf>,
    /// Replace an existing file.
    pub overwrite: bool,
}

/// What an export wrote.
#[derive(Debug, Clone)]
pub struct Exported {
    pub path: PathBuf,
    pub vertices: usize,
    pub joints: usize,
    pub frames: usize,
    pub fps: f64,
}

/// Writes the run as a `.glb` (see the module doc); an existing file is kept unless `job.overwrite`.
pub fn export(run_path: &Path, job: &ExportJob, options: &JobOptions) -> Result<Exported> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let path = job
        .out
        .clone()
        .unwrap_or_else(|| run.exports().join("avatar.glb"));
    if path.exists() && !job.overwrite {
        bail!(
            "{} exists; give --overwrite to replace it, or another --out",
            path.display()
        );
    }
    let device = device(&config, options)?;
    let model = load_trained(&run, &config, &device)?;
    let exp = Experiment::open(config, device, options.progress)?;
    let (name, fps, poses) = animation(job.motion.as_ref(), job.view, &exp, &model)?;
    let cm = canonical_surface(&model, &exp, &job.surface).context(
        "the canonical mesh (a run whose model has no density above the iso level cannot be exported)",
    )?;
    let (joints, weights) = top_weights(&cm.weights, cm.num_joints);
    let skeleton = &exp.prepared.skeleton;
    let mesh = SkinnedMesh {
        positions: &cm.mesh.vertices,
        faces: &cm.mesh.faces,
        colors: &cm.colors,
        joints: &joints,
        weights: &weights,
        rest_joints: skeleton.rest_joints(),
        parents: skeleton.parents(),
    };
    let animation = JointAnimation {
        name: name.clone(),
        fps: fps as f32,
        frames: poses
            .iter()
            .map(|p| joint_frame(p, skeleton.rest_joints()[0]))
            .collect(),
    };
    write_glb(&path, &mesh, &animation, capture_to_gltf(&exp))?;
    Ok(Exported {
        path,
        vertices: cm.mesh.vertices.len(),
        joints: skeleton.num_joints(),
        frames: poses.len(),
        fps,
    })
}

/// The poses an export animates: `motion` put on the subject facing dataset camera `view` (default: the
/// first training view), else the training frames (their refined fits where the model refines them) at
/// [`TRAINING_FPS`]; with the animation's name and frame rate.
pub(crate) fn animation(
    motion: Option<&MotionRequest>,
    view: Option<usize>,
    exp: &Experiment,
    model: &anerf_core::model::AnimatableNerf,
) -> Result<(String, f64, Vec<Pose>)> {
    Ok(match motion {
        Some(request) => {
            let view = anerf_core::ViewId(view.unwrap_or(exp.train_views[0].0));
            let clip = MotionClip::new(request, exp, view)?;
            (clip.name, clip.fps, clip.poses)
        }
        None => {
            let poses = exp
                .train_frames
                .iter()
                .map(|&f| exp.frame_pose(model, f))
                .collect::<Result<Vec<Pose>>>()?;
            ("training".to_string(), TRAINING_FPS, poses)
        }
    })
}

/// The glTF joint transforms of `pose`: joint 0 carries the global placement, `R(Rh) R₀` about
/// `R(Rh) J₀ + Th`; the others their own rotation (their translations are the rest offsets).
pub fn joint_frame(pose: &Pose, pelvis: Vec3) -> JointFrame {
    let global = Quat::from_scaled_axis(pose.global.rh);
    let mut rotations: Vec<Quat> = pose
        .joint_rotations
        .iter()
        .map(|&r| Quat::from_scaled_axis(r))
        .collect();
    rotations[0] = global * rotations[0];
    JointFrame {
        root_translation: global * pelvis + pose.global.th,
        rotations,
    }
}

/// The rotation taking the capture's up (the cameras' mean up) to glTF's +Y.
pub fn capture_to_gltf(exp: &Experiment) -> Quat {
    Quat::from_rotation_arc(
        anerf_core::geometry::mean_up(&exp.prepared.cameras),
        Vec3::Y,
    )
}
