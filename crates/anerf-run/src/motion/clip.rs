//! Motions on a trained run: a motion file read, resampled, cut and retargeted onto the run's subject
//! (placed in its capture's world), and the stage-2 blend-weight field fitted for its frames, stored in
//! `<run>/motions/<name>-<key>/` (the key a digest of its joint rotations) so that rendering it again does
//! not refit, and two motions of one name never replace each other's fit.

use std::path::{Path, PathBuf};

use anerf_core::geometry::{BoneMatrices, Pose};
use anerf_core::model::{AnimatableNerf, BlendWeightField, FrameCode, FrameInputs};
use anerf_core::{FrameId, ViewId};
use anerf_data::atomic::{replace_dir, temp_dir_beside, write_bytes};
use anerf_data::motion::{retarget, FrameRange, Motion, Placement, Scene, Timing};
use anerf_data::paths::safe_component;
use anerf_data::prepare::PosedBody;
use anyhow::{bail, Context, Result};
use burn::module::Module;
use burn::prelude::Device;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use anerf_train::experiment::Experiment;
use anerf_train::training::{PoseTarget, PoseTargets};

/// Where a motion's body is put in the capture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize, Deserialize)]
pub enum Place {
    /// On the floor for motions of a world of their own (AMASS), as recorded otherwise.
    #[default]
    Auto,
    /// Where the motion's own world puts it (a motion recorded in this capture).
    Recorded,
    /// On the capture's floor, starting where the subject stood in `start_frame`, facing `face_view`.
    Floor,
}

/// A motion and how to put it on a run's subject (the `--motion` options).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionRequest {
    /// An AMASS `.npz`, an EasyMocap fit folder or a ZJU `params/` folder (see [`Motion::read`]).
    pub path: PathBuf,
    /// EasyMocap person id (default: the lowest).
    pub person: Option<i64>,
    /// Output frames per second (default: the motion's own).
    pub fps: Option<f64>,
    /// The motion's rate where its format records none (default: `fps`, else 30).
    pub motion_fps: Option<f64>,
    /// Frames of the resampled motion.
    pub frames: FrameRange,
    pub place: Place,
    /// Training frame (dataset index) whose pelvis position the motion starts from (default: the first).
    pub start_frame: Option<usize>,
    /// Dataset camera the motion's first frame faces (default: the render view).
    pub face_view: Option<usize>,
    /// World-space shift after placement (metres).
    pub offset: Option<DVec3>,
}

impl MotionRequest {
    /// A request for `path` with every option at its default.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            person: None,
            fps: None,
            motion_fps: None,
            frames: FrameRange::ALL,
            place: Place::Auto,
            start_frame: None,
            face_view: None,
            offset: None,
        }
    }

    /// The clip's name: the file's (or folder's) stem made one safe path component
    /// ([`safe_component`]: a stem of `..` or `.` becomes `motion`).
    pub fn name(&self) -> String {
        let stem = self
            .path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        safe_component(&stem, "motion")
    }
}

/// A motion retargeted onto the run's subject.
#[derive(Debug, Clone)]
pub struct MotionClip {
    pub name: String,
    /// Frames per second of `poses`.
    pub fps: f64,
    pub poses: Vec<Pose>,
}

impl MotionClip {
    /// Reads, resamples, cuts and retargets `request` onto `exp`'s subject; `view` is the camera the
    /// body faces by default.
    pub fn new(request: &MotionRequest, exp: &Experiment, view: ViewId) -> Result<Self> {
        let timing = Timing {
            declared_fps: request.motion_fps.or(request.fps).or(Some(30.0)),
            fps: request.fps,
            frames: request.frames,
        };
        let motion = Motion::read_timed(&request.path, request.person, &timing)?;
        let floor = match request.place {
            Place::Auto => motion.up.is_some(),
            Place::Recorded => false,
            Place::Floor => true,
        };
        let placement = if floor {
            Placement::InScene(scene(exp, request, view)?)
        } else {
            if request.start_frame.is_some()
                || request.face_view.is_some()
                || request.offset.is_some()
            {
                bail!(
                    "--start-frame, --face-view and --offset place a motion on the floor; {} is used as \
                     recorded (add --place floor)",
                    request.path.display()
                );
            }
            Placement::AsRecorded
        };
        let poses = retarget(&motion, exp.prepared.target_body(), &placement)?;
        Ok(Self {
            name: request.name(),
            fps: motion.fps.expect("a timed motion records its output rate"),
            poses,
        })
    }

    /// The body of frame `i` posed, with its volume and box.
    pub fn body(&self, exp: &Experiment, i: usize) -> Result<PosedBody> {
        let source = Path::new(&self.name);
        exp.prepared
            .pose_body(&self.poses[i], source)
            .with_context(|| format!("posing frame {i} of motion {}", self.name))
    }

    /// The model inputs of frame `i` (`Novel(i)` code, the novel-pose appearance code) and its world box.
    pub fn target(&self, exp: &Experiment, i: usize, device: &Device) -> Result<PoseTarget> {
        let body = self.body(exp, i)?;
        Ok(PoseTarget {
            inputs: FrameInputs {
                bones: BoneMatrices::new(&body.bones, device),
                global: body.pose.global,
                volume: body.volume.to_tensor(device),
                code: FrameCode::Novel(i),
                appearance: exp.novel_appearance(),
                basis: None,
                warp: None,
            },
            bounds: body.bounds,
        })
    }
}

/// A clip's frames as fit targets, posed when drawn; the last [`ClipTargets::KEEP`] drawn stay in memory
/// (a short clip's all of them, a long clip's volumes never all at once).
pub struct ClipTargets<'a> {
    clip: &'a MotionClip,
    exp: &'a Experiment,
    kept: std::collections::VecDeque<(usize, PoseTarget)>,
}

impl<'a> ClipTargets<'a> {
    /// Frames kept posed (each holds a blend-weight volume of a few to tens of MB).
    pub const KEEP: usize = 32;

    pub fn new(clip: &'a MotionClip, exp: &'a Experiment) -> Self {
        Self {
            clip,
            exp,
            kept: std::collections::VecDeque::with_capacity(Self::KEEP),
        }
    }
}

impl PoseTargets for ClipTargets<'_> {
    fn len(&self) -> usize {
        self.clip.poses.len()
    }

    fn target(&mut self, i: usize) -> Result<PoseTarget> {
        if let Some((_, t)) = self.kept.iter().find(|(j, _)| *j == i) {
            return Ok(t.clone());
        }
        let target = self.clip.target(self.exp, i, &self.exp.device)?;
        if self.kept.len() == Self::KEEP {
            self.kept.pop_front();
        }
        self.kept.push_back((i, target.clone()));
        Ok(target)
    }
}

/// The capture's floor, up, start and facing for `request` (world space, metres): up from the cameras,
/// the floor at the lowest vertex of the training frames' bodies.
fn scene(exp: &Experiment, request: &MotionRequest, view: ViewId) -> Result<Scene> {
    let prepared = &exp.prepared;
    let up = anerf_core::geometry::mean_up(&prepared.cameras).as_dvec3();
    let body = prepared.target_body();
    let mut floor = f64::INFINITY;
    for &frame in &exp.train_frames {
        let pose = &frame_pose(exp, frame)?;
        let vertices = body
            .pose_space_vertices(pose)
            .map_err(|e| anyhow::anyhow!("posing training {frame}: {e}"))?;
        for x in vertices {
            floor = floor.min(pose.global.pose_to_world(x).as_dvec3().dot(up));
        }
    }
    let start = match request.start_frame {
        Some(f) => {
            if !exp.train_frames.contains(&FrameId(f)) {
                bail!("--start-frame {f} is not a training frame of this run");
            }
            FrameId(f)
        }
        None => exp.train_frames[0],
    };
    let pose = frame_pose(exp, start)?;
    let pelvis = pose
        .global
        .pose_to_world(prepared.skeleton.rest_joints()[0]);
    let face = request.face_view.unwrap_or(view.0);
    let camera = prepared.cameras.get(face).with_context(|| {
        format!(
            "--face-view {face} does not exist (the dataset has {} cameras)",
            prepared.cameras.len()
        )
    })?;
    Ok(Scene {
        up,
        floor,
        start: pelvis.as_dvec3(),
        toward: camera.center().as_dvec3(),
        offset: request.offset.unwrap_or(DVec3::ZERO),
    })
}

fn frame_pose(exp: &Experiment, frame: FrameId) -> Result<Pose> {
    Ok(exp
        .prepared
        .frame(frame)
        .with_context(|| format!("{frame} is not prepared"))?
        .pose
        .clone())
}

/// `<run>/motions/<name>-<key>/`: the stage-2 field fitted for a clip, with the poses it was fitted for.
/// The key is the first 48 bits of the SHA-256 of the clip's joint rotations, so the folder is the clip's
/// whatever its file was called.
#[derive(Debug, Clone)]
pub struct StoredFit {
    pub dir: PathBuf,
}

/// `fit.json`: what a stored field was fitted for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct FitRecord {
    /// The motion file it came from.
    source: PathBuf,
    /// The stage-1 checkpoint the canonical model came from.
    checkpoint: String,
    /// Every frame's joint rotations (pose space; placement does not change a fit).
    joints: Vec<Vec<[f32; 3]>>,
}

const FIELD: &str = "field.bpk";
const RECORD: &str = "fit.json";

impl StoredFit {
    pub fn new(motions: &Path, clip: &MotionClip) -> Self {
        let mut digest = Sha256::new();
        for pose in &clip.poses {
            digest.update((pose.joint_rotations.len() as u64).to_le_bytes());
            for r in &pose.joint_rotations {
                for v in r.to_array() {
                    digest.update(v.to_le_bytes());
                }
            }
        }
        let key: String = digest.finalize()[..6]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        Self {
            dir: motions.join(format!("{}-{key}", safe_component(&clip.name, "motion"))),
        }
    }

    /// The stored field when it was fitted for `clip`'s joint rotations from `checkpoint`; `None` when
    /// there is none or it was fitted for something else.
    pub fn load(
        &self,
        clip: &MotionClip,
        checkpoint: &str,
        model: AnimatableNerf,
        device: &Device,
    ) -> Result<Option<AnimatableNerf>> {
        let record_path = self.dir.join(RECORD);
        if !record_path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&record_path)
            .with_context(|| format!("reading {}", record_path.display()))?;
        let record: FitRecord = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a motion fit record", record_path.display()))?;
        if record.checkpoint != checkpoint || !same_joints(&record.joints, &clip.poses) {
            return Ok(None);
        }
        let mut model = model.with_novel_field(clip.poses.len(), device);
        let field: BlendWeightField = model
            .novel_blend
            .take()
            .expect("with_novel_field adds the field");
        let path = self.dir.join(FIELD);
        let field = field.try_load_file(&path).map_err(|e| {
            anyhow::anyhow!(
                "loading {}: {e} (refit with `anerf animate --motion`)",
                path.display()
            )
        })?;
        model.novel_blend = Some(field);
        Ok(Some(model))
    }

    /// Stores `model`'s novel-pose field as the fit of `clip` (from `source` and `checkpoint`): written
    /// beside the folder, then renamed over it.
    pub fn save(
        &self,
        model: &AnimatableNerf,
        clip: &MotionClip,
        source: &Path,
        checkpoint: &str,
    ) -> Result<()> {
        let field = model
            .novel_blend
            .clone()
            .context("the model has no fitted novel-pose field")?;
        let tmp = temp_dir_beside(&self.dir)?;
        let write = move || -> Result<()> {
            field
                .save_file(tmp.path().join(FIELD))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let record = FitRecord {
                source: source.to_path_buf(),
                checkpoint: checkpoint.to_string(),
                joints: clip
                    .poses
                    .iter()
                    .map(|p| p.joint_rotations.iter().map(|r| r.to_array()).collect())
                    .collect(),
            };
            write_bytes(
                &tmp.path().join(RECORD),
                serde_json::to_string(&record)?.as_bytes(),
            )?;
            replace_dir(tmp, &self.dir)?;
            Ok(())
        };
        write().with_context(|| format!("storing the motion fit in {}", self.dir.display()))
    }
}

/// True when `record` holds `poses`' joint rotations (within f32 rounding of a JSON round trip).
fn same_joints(record: &[Vec<[f32; 3]>], poses: &[Pose]) -> bool {
    record.len() == poses.len()
        && record.iter().zip(poses).all(|(r, p)| {
            r.len() == p.joint_rotations.len()
                && r.iter()
                    .zip(&p.joint_rotations)
                    .all(|(a, b)| (glam::Vec3::from_array(*a) - *b).abs().max_element() <= 1e-6)
        })
}
