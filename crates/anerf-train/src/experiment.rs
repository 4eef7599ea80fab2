//! An experiment opened for work: its resolved config, the prepared subject, the splits, and per-frame
//! model inputs on the device (uploaded once, then reused).

use std::collections::HashMap;
use std::sync::Arc;

use anerf_core::geometry::skinning::BoneMatrices;
use anerf_core::geometry::{Aabb, CanonicalPose, Pose, PoseBasis};
use anerf_core::model::{AnimatableNerf, CanonicalInputs, FrameCode, FrameInputs, ModelSizes};
use anerf_core::{FrameId, ViewId};
use anerf_data::prepare::{FrameSelection, NearestMethod};
use anerf_data::{DatasetKind, PrepareOptions, PreparedSubject};
use anyhow::{bail, Context, Result};
use burn::prelude::Device;

use crate::config::{ExperimentConfig, VolumeSource};
use crate::progress::PhaseProgress;

/// A config together with the data it names, ready for training, evaluation or rendering.
pub struct Experiment {
    pub config: ExperimentConfig,
    /// Shared with the thread that draws the next step's rays ([`anerf_data::Prefetch`]).
    pub prepared: Arc<PreparedSubject>,
    pub train_frames: Vec<FrameId>,
    pub novel_frames: Vec<FrameId>,
    pub train_views: Vec<ViewId>,
    pub test_views: Vec<ViewId>,
    pub device: Device,
    /// The devices of a data-parallel fit (`device` first); `None` for a fit on `device` alone.
    data_parallel: Option<Vec<Device>>,
    /// The canonical body on each device (the experiment's, then the other devices of a data-parallel fit).
    canonical: Vec<CanonicalInputs>,
    /// Frame inputs uploaded so far, by device (the experiment's, then the other devices of a data-parallel fit) and frame.
    frames: HashMap<(usize, FrameId), FrameInputs>,
}

/// The frame positions of a range, every `interval`-th, cut to the frames that exist.
fn frames_of(range: &crate::config::FrameRange, interval: usize, available: usize) -> Vec<FrameId> {
    range
        .within(available)
        .frames()
        .into_iter()
        .step_by(interval.max(1))
        .map(FrameId)
        .collect()
}

impl Experiment {
    /// Loads the dataset, checks the views and frames against it, prepares (or reuses) the cache and uploads
    /// the canonical body to `device`.
    pub fn open(config: ExperimentConfig, device: Device, progress: bool) -> Result<Self> {
        let d = &config.dataset;
        let kind = d.format.kind();
        if !d.root.is_dir() {
            bail!(
                "dataset.root {} is not a folder (expected a {:?} subject folder)",
                d.root.display(),
                d.format
            );
        }
        let subject = anerf_data::load(&d.root, kind, &d.load_options()).with_context(|| {
            format!(
                "loading the dataset named by dataset.root = {}",
                d.root.display()
            )
        })?;
        let cameras = subject.cameras.len();
        let available = subject.frames.len();
        for &v in &d.train_views {
            if v >= cameras {
                bail!(
                    "dataset.train_views contains {v}, but {} has cameras 0..{cameras}",
                    d.root.display()
                );
            }
        }
        let test_views: Vec<usize> = if d.test_views.is_empty() {
            (0..cameras)
                .filter(|v| !d.train_views.contains(v))
                .collect()
        } else {
            d.test_views.clone()
        };
        if let Some(v) = test_views.iter().find(|&&v| v >= cameras) {
            bail!(
                "dataset.test_views contains {v}, but {} has cameras 0..{cameras}",
                d.root.display()
            );
        }
        let split = d.split();
        let key = |what: &str| format!("dataset.{}.{what}", d.ranges.key());
        if split.train_frames.end > available {
            bail!(
                "{} = {} reaches frame {}, but {} has {available} frames (0:{available})",
                key("train_frames"),
                split.train_frames,
                split.train_frames.end - 1,
                d.root.display()
            );
        }
        let train_frames = frames_of(&split.train_frames, d.frame_interval, available);
        let novel_frames = frames_of(&split.novel_pose_frames, d.frame_interval, available);
        let novel = &split.novel_pose_frames;
        if !novel.is_empty() && novel_frames.is_empty() {
            bail!(
                "{} = {novel} selects none of the {available} frames of {} (frames 0:{available})",
                key("novel_pose_frames"),
                d.root.display()
            );
        }
        if novel.end > available && progress {
            // The published configs name ranges past the end of shorter sequences (the authors' code clips).
            eprintln!(
                "note: {} = {novel} is clipped to the {available} frames of {}",
                key("novel_pose_frames"),
                d.root.display()
            );
        }
        if train_frames.is_empty() {
            bail!(
                "{} = {} selects none of the {available} frames of {}",
                key("train_frames"),
                split.train_frames,
                d.root.display()
            );
        }
        let all: Vec<usize> = train_frames
            .iter()
            .chain(&novel_frames)
            .map(|f| f.0)
            .collect();
        let (lo, hi) = (
            *all.iter().min().unwrap_or(&0),
            *all.iter().max().unwrap_or(&0),
        );
        let step = if all.iter().all(|f| (f - lo) % d.frame_interval == 0) {
            d.frame_interval
        } else {
            1
        };
        let views: Vec<usize> = {
            let mut v: Vec<usize> = d.train_views.iter().chain(&test_views).copied().collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        let options = PrepareOptions {
            cache_dir: d.cache.clone(),
            ratio: d.ratio,
            frames: FrameSelection {
                start: lo,
                end: Some(hi + 1),
                step,
            },
            views: Some(views),
            nearest: match d.volumes {
                VolumeSource::NearestVertex => NearestMethod::Vertex,
                _ => NearestMethod::Surface,
            },
            dataset_volumes: d.volumes == VolumeSource::Dataset,
            ..PrepareOptions::default()
        };
        let prepared = anerf_data::prepare_with(&subject, &options, &PhaseProgress::new(progress))
            .context("preparing the dataset (anerf prepare)")?;
        let canonical = CanonicalInputs {
            volume: prepared.canonical_volume()?.to_tensor(&device),
            bounds: prepared.canonical.bounds,
        };
        Ok(Self {
            train_views: d.train_views.iter().map(|&v| ViewId(v)).collect(),
            test_views: test_views.into_iter().map(ViewId).collect(),
            config,
            prepared: Arc::new(prepared),
            train_frames,
            novel_frames,
            device,
            data_parallel: None,
            canonical: vec![canonical],
            frames: HashMap::new(),
        })
    }

    /// Trains data-parallel on `devices` (with autodiff; the experiment's own device first, as
    /// `training::parallel` fits): uploads the canonical body to the others.
    pub fn with_data_parallel(mut self, devices: Vec<Device>) -> Result<Self> {
        if devices.first() != Some(&self.device) {
            bail!("a data-parallel fit runs its first replica on the experiment's device");
        }
        let volume = self.prepared.canonical_volume()?;
        for device in &devices[1..] {
            self.canonical.push(CanonicalInputs {
                volume: volume.to_tensor(device),
                bounds: self.prepared.canonical.bounds,
            });
        }
        self.data_parallel = Some(devices);
        Ok(self)
    }

    /// The devices of a data-parallel fit, `None` for a fit on one device without Burn's distributed data
    /// parallel.
    pub fn data_parallel(&self) -> Option<&[Device]> {
        self.data_parallel.as_deref()
    }

    /// Sizes of the model this experiment trains.
    pub fn model_sizes(&self) -> ModelSizes {
        ModelSizes {
            training_frames: self.train_frames.len(),
            joints: self.prepared.skeleton.num_joints(),
        }
    }

    /// The canonical body on the device.
    pub fn canonical(&self) -> &CanonicalInputs {
        &self.canonical[0]
    }

    /// The canonical body on the device of replica `replica` of a data-parallel fit (0: the experiment's).
    pub fn canonical_on(&self, replica: usize) -> &CanonicalInputs {
        &self.canonical[replica]
    }

    /// How frame `id` is conditioned: its own codes if it is a training frame, the stage-2 codes and
    /// [`Self::novel_appearance`] if it is a novel-pose frame.
    pub fn frame_code(&self, id: FrameId) -> Result<(FrameCode, usize)> {
        if let Some(f) = self.train_frames.iter().position(|&t| t == id) {
            return Ok((FrameCode::Training(f), f));
        }
        if let Some(j) = self.novel_frames.iter().position(|&t| t == id) {
            return Ok((FrameCode::Novel(j), self.novel_appearance()));
        }
        bail!("{id} is neither a training nor a novel-pose frame of this experiment")
    }

    /// The appearance code (training-frame position) a novel pose is rendered with: the last training
    /// frame's on ZJU-MoCap, the first one's on Human3.6M (the reference's rule).
    pub fn novel_appearance(&self) -> usize {
        match self.prepared.kind {
            DatasetKind::H36m => 0,
            _ => self.train_frames.len() - 1,
        }
    }

    /// Model inputs of frame `id` on the device (uploaded on first use; the clone shares the tensors).
    pub fn frame_inputs(&mut self, id: FrameId) -> Result<FrameInputs> {
        self.frame_inputs_on(id, 0)
    }

    /// The device of replica `replica` of a data-parallel fit (0: the experiment's).
    pub fn replica_device(&self, replica: usize) -> &Device {
        match (replica, &self.data_parallel) {
            (0, _) => &self.device,
            (k, Some(devices)) => &devices[k],
            (k, None) => panic!("replica {k} of a fit on one device"),
        }
    }

    /// Model inputs of frame `id` on the device of replica `replica` of a data-parallel fit (0: the
    /// experiment's), uploaded on first use.
    pub fn frame_inputs_on(&mut self, id: FrameId, replica: usize) -> Result<FrameInputs> {
        if !self.frames.contains_key(&(replica, id)) {
            let device = self.replica_device(replica).clone();
            let (code, appearance) = self.frame_code(id)?;
            let frame = self
                .prepared
                .frame(id)
                .with_context(|| format!("{id} was not prepared"))?;
            let refines = self.config.model.pose_refinement.enabled;
            let basis = (refines && matches!(code, FrameCode::Training(_))).then(|| {
                PoseBasis::new(
                    &self.prepared.skeleton,
                    &frame.pose,
                    CanonicalPose::TPose,
                    &device,
                )
            });
            let inputs = FrameInputs {
                bones: BoneMatrices::new(&frame.bones, &device),
                global: frame.pose.global,
                volume: self.prepared.volume(id)?.to_tensor(&device),
                code,
                appearance,
                basis,
                warp: None,
            };
            self.frames.insert((replica, id), inputs);
        }
        Ok(self.frames[&(replica, id)].clone())
    }

    /// Frame `id`'s body pose as `model` renders it: the given fit, corrected by the model's pose
    /// refinement where `id` is a training frame of a model that refines fits.
    pub fn frame_pose(&self, model: &AnimatableNerf, id: FrameId) -> Result<Pose> {
        let given = &self
            .prepared
            .frame(id)
            .with_context(|| format!("{id} was not prepared"))?
            .pose;
        Ok(match (&model.pose, self.frame_code(id)?.0) {
            (Some(refinement), FrameCode::Training(f)) => refinement.correction(f).apply(given),
            _ => given.clone(),
        })
    }

    /// World-space box of prepared frame `id` (metres).
    pub fn frame_bounds(&self, id: FrameId) -> Result<Aabb> {
        Ok(self
            .prepared
            .frame(id)
            .with_context(|| format!("{id} was not prepared"))?
            .bounds)
    }

    /// Fails when frame `id` is a novel pose and `model` has no stage-2 field for it yet.
    pub fn check_renderable(&self, id: FrameId, model: &AnimatableNerf) -> Result<()> {
        if matches!(self.frame_code(id)?.0, FrameCode::Novel(_)) && model.novel_blend.is_none() {
            bail!("{id} is a novel pose; run `anerf animate` first");
        }
        Ok(())
    }
}
