//! Pose sequences from pose files (the `params/{i}.npy` format) for `anerf render --poses`: each pose is
//! posed and given a volume as a dataset frame is, then receives a blend-weight code fitted as stage 2 does.

use std::path::{Path, PathBuf};

use anerf_core::geometry::BoneMatrices;
use anerf_core::model::{FrameCode, FrameInputs};
use anerf_data::loaders::{pose_files, read_pose_file};
use anerf_data::prepare::PosedBody;
use anerf_data::PreparedSubject;
use anyhow::{Context, Result};
use burn::prelude::Device;

use crate::training::PoseTarget;

/// Poses read from files, in file order.
pub struct PoseSequence {
    pub files: Vec<PathBuf>,
    pub bodies: Vec<PosedBody>,
}

impl PoseSequence {
    /// Reads the pose file `path`, or every pose file of the folder `path` in numeric order, and poses the
    /// prepared subject's body with each.
    pub fn load(path: &Path, prepared: &PreparedSubject) -> Result<Self> {
        let files = pose_files(path)?;
        let joints = prepared.skeleton.num_joints();
        let bodies = files
            .iter()
            .map(|file| {
                let pose = read_pose_file(file, joints)?;
                prepared
                    .pose_body(&pose, file)
                    .with_context(|| format!("posing the body with {}", file.display()))
            })
            .collect::<Result<_>>()?;
        Ok(Self { files, bodies })
    }

    /// The stage-2 targets of the poses (code `Novel(j)` for the `j`-th file), rendered with appearance
    /// code `appearance`, on `device`.
    pub fn targets(&self, appearance: usize, device: &Device) -> Vec<PoseTarget> {
        self.bodies
            .iter()
            .enumerate()
            .map(|(j, body)| PoseTarget {
                inputs: FrameInputs {
                    bones: BoneMatrices::new(&body.bones, device),
                    global: body.pose.global,
                    volume: body.volume.to_tensor(device),
                    code: FrameCode::Novel(j),
                    appearance,
                },
                bounds: body.bounds,
            })
            .collect()
    }
}
