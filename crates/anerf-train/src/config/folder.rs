//! The config of a subject folder trained without a config file (`anerf train --data`).

use std::path::Path;

use anerf_data::prepare::ImageScale;
use anerf_data::LoadOptions;
use anyhow::{Context, Result};
use serde::Serialize;
use toml::Table;

use super::{DatasetFormat, FrameRange, FrameSplit};

/// What a folder gives a config: its name, layout and the split (from `splits.json`, written by
/// `anerf synth`, or four evenly spaced cameras and the first two thirds of the frames), and pose
/// refinement unless the fits are known to be exact.
#[derive(Serialize)]
struct FolderConfig {
    name: String,
    dataset: FolderDataset,
    model: FolderModel,
    #[serde(skip_serializing_if = "Option::is_none")]
    train: Option<FolderTrain>,
}

/// `[train]` of a folder whose fits are refined: [`REFINED_FRAMES_PER_STEP`] frames a step.
#[derive(Serialize)]
struct FolderTrain {
    frames_per_step: usize,
}

/// Training frames a stage-1 step draws where the fits are refined: each frame's correction then moves
/// on four times as many steps, which wins 1–1.5 dB on held-out views of fits off by 4 cm (for a fifth to a
/// quarter more of stage 1's time than one frame); with exact fits it wins nothing, so other folders keep one
/// (docs/POSE-REFINEMENT.md, "Several frames a step").
pub const REFINED_FRAMES_PER_STEP: usize = 4;

/// `model.pose_refinement.silhouette_weight` where a folder's fits are refined: the posed body's outline
/// held to the masks' edges places the body where the photometric loss alone leaves it 0.5–0.8 cm off
/// (docs/POSE-REFINEMENT.md, "The body's silhouette").
pub const REFINED_SILHOUETTE_WEIGHT: f32 = 0.01;

#[derive(Serialize)]
struct FolderDataset {
    format: DatasetFormat,
    root: String,
    ratio: ImageScale,
    train_views: Vec<usize>,
    iccv: FrameSplit,
    #[serde(skip_serializing_if = "Option::is_none")]
    body_model: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    person: Option<i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    masks: Option<String>,
}

#[derive(Serialize)]
struct FolderModel {
    preset: &'static str,
    pose_refinement: FolderRefinement,
}

/// `[model.pose_refinement]` of a folder: on unless its body fits are known to be exact, and then with
/// the body silhouette term at [`REFINED_SILHOUETTE_WEIGHT`].
#[derive(Serialize)]
struct FolderRefinement {
    enabled: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    silhouette_weight: Option<f32>,
}

/// Whether a folder's body fits are known to be exact: a subject `anerf synth` wrote (it leaves
/// `splits.json`) without fit errors (`--pose-noise` stores the true poses in `true_params/`). Every other
/// folder's fits come from a fitter and are off by centimetres, which pose refinement learns away
/// (docs/POSE-REFINEMENT.md).
fn fits_are_exact(data: &Path) -> bool {
    data.join("splits.json").is_file() && !data.join("true_params").exists()
}

/// The folder's values as a config table, for [`super::assemble`] with the command's flags;
/// `load` (body model, person, masks) is what reading the folder takes and goes into the config.
pub fn folder_table(data: &Path, load: &LoadOptions) -> Result<Table> {
    let kind = anerf_data::loaders::detect_kind(data);
    let subject = anerf_data::load(data, kind, load).with_context(|| {
        format!(
            "reading {} as {:?} (expected a subject folder in the ZJU-MoCap layout or an EasyMocap capture)",
            data.display(),
            DatasetFormat::of(kind)
        )
    })?;
    let cameras = subject.cameras.len();
    let frames = subject.frames.len();
    let splits: Option<anerf_data::synthetic::Splits> =
        std::fs::read_to_string(data.join("splits.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
    let (train_views, iccv) = match &splits {
        Some(s) => (
            s.training_views.clone(),
            FrameSplit {
                train_frames: span(&s.training_frames),
                novel_pose_frames: span(&s.novel_pose_frames),
            },
        ),
        None => {
            let n = 4.min(cameras);
            let views: Vec<usize> = (0..n).map(|i| i * cameras / n).collect();
            let cut = (frames * 2 / 3).max(1);
            let range = |start, end| FrameRange {
                start,
                end,
                step: 1,
            };
            (
                views,
                FrameSplit {
                    train_frames: range(0, cut),
                    novel_pose_frames: range(cut, frames.max(cut)),
                },
            )
        }
    };
    let name = data
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("subject")
        .replace(['/', '\\'], "_");
    // Full-HD captures train at half resolution, as the ZJU-MoCap configs do.
    let ratio = if subject.cameras.first().is_some_and(|c| c.width >= 1000) {
        ImageScale::HALF
    } else {
        ImageScale::FULL
    };
    let refine = !fits_are_exact(data);
    let folder = FolderConfig {
        name,
        dataset: FolderDataset {
            format: DatasetFormat::of(kind),
            root: data.display().to_string(),
            ratio,
            train_views,
            iccv,
            body_model: load.body_model.as_ref().map(|p| p.display().to_string()),
            person: load.person,
            masks: load.masks.clone(),
        },
        model: FolderModel {
            preset: "cpu",
            pose_refinement: FolderRefinement {
                enabled: refine,
                silhouette_weight: refine.then_some(REFINED_SILHOUETTE_WEIGHT),
            },
        },
        train: refine.then_some(FolderTrain {
            frames_per_step: REFINED_FRAMES_PER_STEP,
        }),
    };
    Ok(Table::try_from(folder).expect("a folder config serialises to TOML"))
}

/// The range covering a sorted list of consecutive frame indices (`splits.json` lists them explicitly).
fn span(frames: &[usize]) -> FrameRange {
    let (start, end) = match (frames.first(), frames.last()) {
        (Some(a), Some(b)) => (*a, b + 1),
        _ => (0, 0),
    };
    FrameRange {
        start,
        end,
        step: 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only a folder `anerf synth` wrote without fit errors counts as exact.
    #[test]
    fn only_a_synthetic_subject_without_fit_errors_has_exact_fits() {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path();
        assert!(!fits_are_exact(folder), "a capture");
        std::fs::write(folder.join("splits.json"), "{}").unwrap();
        assert!(fits_are_exact(folder), "a synthetic subject");
        std::fs::create_dir(folder.join("true_params")).unwrap();
        assert!(
            !fits_are_exact(folder),
            "a synthetic subject with noisy fits"
        );
    }
}
