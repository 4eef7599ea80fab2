//! The option groups several commands share (device and overrides, capture folders, how a run starts, the
//! surface, motions), and the Ctrl-C flag the training commands hand their jobs.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anerf_core::{DeviceChoice, InvalidValue};
use anerf_data::motion::FrameRange;
use anerf_run::mesh::MeshJob;
use anerf_run::motion::{MotionRequest, Place};
use anerf_run::JobOptions;
use anerf_run::{Avatar, Surface};
use anerf_train::run_start::RunStart;
use clap::Args;
use glam::DVec3;

/// Options every command that computes takes.
#[derive(Debug, Clone, Args)]
pub struct Common {
    /// Compute backend (flex, ndarray, wgpu, cuda); overrides the config's `device`.
    #[arg(long)]
    pub device: Option<DeviceChoice>,
    /// Override a config value, e.g. `--set train.iterations=1000` (repeatable).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    pub overrides: Vec<String>,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

impl Common {
    /// The library's options of a job.
    pub fn options(&self) -> JobOptions {
        JobOptions {
            device: self.device,
            devices: None,
            set: self.overrides.clone(),
            progress: !self.quiet,
        }
    }
}

/// What reading a dataset folder without a config needs besides the folder (`train --data`, `info`).
#[derive(Debug, Clone, Default, Args)]
pub struct CaptureArgs {
    /// SMPL-family body-model file (.npz, or .pkl read without running code): the body of an EasyMocap
    /// capture, or weights and faces for a ZJU folder whose lbs/ lacks them.
    #[arg(long)]
    pub body_model: Option<PathBuf>,
    /// EasyMocap: the id of the person whose fits to use (default: the only person).
    #[arg(long)]
    pub person: Option<i64>,
    /// EasyMocap: the mask folder inside the capture (default: mask/, else mask-schp/).
    #[arg(long)]
    pub masks: Option<String>,
}

impl CaptureArgs {
    pub fn load_options(&self) -> anerf_data::LoadOptions {
        anerf_data::LoadOptions {
            body_model: self.body_model.clone(),
            person: self.person,
            masks: self.masks.clone(),
        }
    }
}

/// How `train` and `animate` treat the stage's earlier checkpoints, and when they stop.
#[derive(Debug, Clone, Args)]
pub struct StartArgs {
    /// Continue the stage from its newest intact checkpoint.
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Start the stage again, replacing what an earlier run of it wrote (`train`: the whole run folder,
    /// deleted once the new run's config and data have been checked).
    #[arg(long)]
    pub overwrite: bool,
    /// Stop (with a checkpoint) after this many steps; `--resume` continues.
    #[arg(long)]
    pub steps: Option<usize>,
}

impl StartArgs {
    pub fn run_start(&self) -> RunStart {
        RunStart::from_flags(self.resume, self.overwrite)
    }
}

/// How the canonical surface is extracted (marching cubes on the canonical density).
#[derive(Debug, Args)]
pub struct SurfaceArgs {
    /// Voxel size in metres.
    #[arg(long, default_value_t = 0.005)]
    pub voxel: f32,
    /// Iso level on raw density (the reference uses 5).
    #[arg(long, default_value_t = 5.0)]
    pub level: f32,
    /// Taubin smoothing iterations (0 = none).
    #[arg(long, default_value_t = 0)]
    pub smooth: usize,
}

impl SurfaceArgs {
    /// These settings.
    pub fn surface(&self) -> Surface {
        Surface {
            voxel: self.voxel,
            level: self.level,
            smooth: self.smooth,
        }
    }

    /// A mesh job of these settings with no frames to repose.
    pub fn job(&self) -> MeshJob {
        self.surface().job()
    }
}

/// Which form of the avatar a command draws: the NeRF, the baked Gaussians or the exported mesh.
#[derive(Debug, Args)]
pub struct AvatarArgs {
    /// The Gaussians of `anerf bake` instead of the NeRF (novel poses and motions need no stage-2 field;
    /// results under <run>/baked/, renders named baked_*).
    #[arg(long, conflicts_with = "mesh")]
    pub baked: bool,
    /// The vertex-coloured mesh `anerf export` writes into the glb, extracted with --voxel, --level and
    /// --smooth (no stage-2 field needed; results under <run>/meshes/, renders named mesh_*).
    #[arg(long)]
    pub mesh: bool,
    #[command(flatten)]
    pub surface: SurfaceArgs,
}

impl AvatarArgs {
    pub fn avatar(&self) -> Avatar {
        if self.baked {
            Avatar::Baked
        } else if self.mesh {
            Avatar::Mesh(self.surface.surface())
        } else {
            Avatar::Nerf
        }
    }
}

/// A motion to drive the avatar with, and how to put it on the run's subject.
#[derive(Debug, Args)]
pub struct MotionArgs {
    /// An AMASS `.npz` (SMPL+H, SMPL-X), an EasyMocap fit folder (or its capture) or a ZJU `params/` folder.
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// Output frames per second (default: the motion's own); the motion is resampled (slerp).
    #[arg(long, requires = "motion")]
    pub fps: Option<f64>,
    /// The motion's rate where its format records none (EasyMocap, ZJU; default: --fps, else 30).
    #[arg(long, requires = "motion")]
    pub motion_fps: Option<f64>,
    /// Frames of the resampled motion, `start:end:step` (end exclusive), e.g. `0:300`.
    #[arg(long, requires = "motion")]
    pub frames: Option<FrameRange>,
    /// `floor`: on the capture's floor, starting where the subject stood, facing a camera; `recorded`: where
    /// the motion's world puts it; `auto`: floor for AMASS, recorded for EasyMocap and ZJU.
    #[arg(long, value_enum, default_value_t = Place::Auto)]
    pub place: Place,
    /// Training frame whose pelvis position the motion starts from (default: the first training frame).
    #[arg(long, requires = "motion")]
    pub start_frame: Option<usize>,
    /// Dataset camera the motion's first frame faces (default: the render view, else the first training view).
    #[arg(long, requires = "motion")]
    pub face_view: Option<usize>,
    /// World-space shift after placement, metres: `x,y,z`.
    #[arg(long, requires = "motion", value_parser = parse_offset, allow_hyphen_values = true)]
    pub offset: Option<DVec3>,
    /// EasyMocap person id (default: the lowest id).
    #[arg(long, requires = "motion")]
    pub person: Option<i64>,
}

impl MotionArgs {
    /// The request, when `--motion` was given.
    pub fn request(&self) -> Option<MotionRequest> {
        let path = self.motion.clone()?;
        Some(MotionRequest {
            person: self.person,
            fps: self.fps,
            motion_fps: self.motion_fps,
            frames: self.frames.unwrap_or(FrameRange::ALL),
            place: self.place,
            start_frame: self.start_frame,
            face_view: self.face_view,
            offset: self.offset,
            ..MotionRequest::new(path)
        })
    }
}

/// `x,y,z` in metres.
fn parse_offset(s: &str) -> Result<DVec3, InvalidValue> {
    let bad = || {
        InvalidValue::new(
            "--offset",
            format!("'{s}'"),
            "x,y,z in metres (three finite numbers)",
        )
    };
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(DVec3::new(x, y, z)),
        _ => Err(bad()),
    }
}

/// Installs the Ctrl-C handler once; the flag it sets makes the training loops checkpoint and stop.
pub fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let handler_flag = flag.clone();
    if let Err(e) = ctrlc::set_handler(move || {
        eprintln!("\ninterrupted: writing a checkpoint, then stopping (run again with --resume)");
        handler_flag.store(true, std::sync::atomic::Ordering::SeqCst);
    }) {
        eprintln!("warning: cannot install the Ctrl-C handler ({e}); an interrupt will not write a checkpoint");
    }
    flag
}
