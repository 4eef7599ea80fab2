//! EasyMocap capture folders, read directly (docs/DATA.md, "EasyMocap captures"):
//!
//! ```text
//! <capture>/intri.yml, extri.yml         OpenCV YAML calibration (names, K_, dist_, Rot_/R_, T_ in metres)
//! <capture>/images/<cam>/<frame>.jpg     frames named by number
//! <capture>/mask/<cam>/<frame>.png       or mask-schp/, or the folder LoadOptions::masks names; non-zero = body
//! <capture>/output-smpl-3d/smpl/<frame>.json   or output/smpl/: the SMPL fits of every person
//! ```
//!
//! The body comes from the SMPL-family model file the fits were made with ([`LoadOptions::body_model`]):
//! the canonical T-pose with the subject's betas, and each frame's posed vertices (with pose correctives)
//! computed from its fit.

mod cameras;
pub(crate) mod fits;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anerf_core::geometry::Pose;
use anerf_core::FrameId;

use self::fits::{read_fit_file, PersonFit};
use super::annots::FramePaths;
use super::check::Checker;
use super::image_files::{self, MaskRule};
use super::{build_cameras, LoadOptions};
use crate::error::DataError;
use crate::paths::Folder;
use crate::smpl::SmplModel;
use crate::subject::{
    check_body_size, DatasetKind, FittedPose, FrameRecord, PosedVertices, Subject,
};

/// Where EasyMocap writes its SMPL fits, in the order they are looked for.
pub const FIT_FOLDERS: [&str; 2] = ["output-smpl-3d/smpl", "output/smpl"];
/// Mask folders looked for when the options name none.
pub const MASK_FOLDERS: [&str; 2] = ["mask", "mask-schp"];
/// Image extensions of a frame.
const IMAGE_EXTENSIONS: [&str; 3] = ["jpg", "jpeg", "png"];

/// Whether `root` looks like an EasyMocap capture (its two calibration files).
pub fn is_capture(root: &Path) -> bool {
    root.join("intri.yml").is_file() && root.join("extri.yml").is_file()
}

/// Reads the capture; with a collecting checker every problem is recorded and `None` returned when a
/// complete subject could not be built.
pub(super) fn read(
    root: &Path,
    options: &LoadOptions,
    ck: &mut Checker,
) -> Result<Option<Subject>, DataError> {
    let model = match &options.body_model {
        Some(path) => ck
            .check(SmplModel::read(path))?
            .map(|m| (Arc::new(m), path.clone())),
        None => {
            ck.check::<()>(Err(DataError::invalid(
                root,
                "is an EasyMocap capture, whose fits need the SMPL-family model file they were made with \
                 (SMPL .npz or .pkl): name it with --body-model or dataset.body_model",
            )))?;
            None
        }
    };
    let calibration = cameras::read_cameras(root, ck)?;
    let inside = Folder::new(root, "dataset folder");
    let mut frame_numbers = Vec::new();
    let mut cameras = None;
    let mut masks = Vec::new();
    let mut ims: Vec<Option<FramePaths>> = Vec::new();
    if let Some((names, raw)) = &calibration {
        let (numbers, paths) = list_frames(root, names, ck)?;
        frame_numbers = numbers;
        ims = paths;
        let sizes = image_files::check_images(root, &inside, raw, &ims, ck)?;
        cameras = build_cameras(&root.join("intri.yml"), raw, &sizes, ck)?;
        let rule = MaskRule::Folders(match &options.masks {
            Some(folder) => vec![folder.clone()],
            None => MASK_FOLDERS.map(String::from).to_vec(),
        });
        masks = image_files::resolve_masks(root, &inside, &rule, &ims, ck)?;
        if ck.whole_files() {
            image_files::check_masks(&inside, &masks, &sizes, ck)?;
        }
    }
    let fits = read_fits(root, &frame_numbers, options.person, ck)?;
    let Some((model, model_file)) = model else {
        return Ok(None);
    };
    let Some(mut fits) = fits else {
        return Ok(None);
    };
    let Some(Some(layout)) = ck.check(FitLayout::of(&model, &fits))? else {
        return Ok(None);
    };
    for slot in &mut fits {
        if let Some((path, fit)) = slot {
            if ck.check(layout.check(&model, path, fit))?.is_none() {
                *slot = None;
            }
        }
    }
    let first = fits
        .iter()
        .flatten()
        .next()
        .map(|(_, fit)| fit.params(layout.expression_at));
    let Some(first) = first else {
        return Ok(None);
    };
    let differing = fits
        .iter()
        .flatten()
        .any(|(_, f)| f.params(layout.expression_at).betas != first.betas);
    if differing {
        ck.note(
            root,
            "the fits' shapes differ between frames: the canonical body uses the first frame's, and each \
             frame is posed with its own"
                .into(),
        );
    }
    let body = model.body(&first.betas, layout.driven);
    let first_fit = fits.iter().flatten().next().map(|(path, _)| path.clone());
    if let Some(path) = first_fit {
        let size = check_body_size(
            &body.canonical_vertices,
            &path,
            "the canonical body (the model shaped by this first fit's shapes)",
        );
        if ck.check(size)?.is_none() {
            return Ok(None);
        }
    }
    let mut frames = Vec::with_capacity(frame_numbers.len());
    for (f, ((number, paths), masks)) in frame_numbers.iter().zip(&ims).zip(&masks).enumerate() {
        let (Some((images, masks)), Some(Some((fit_path, fit)))) =
            (image_files::frame_files(root, paths, masks), fits.get(f))
        else {
            continue;
        };
        let params = fit.params(layout.expression_at);
        let f32s: Vec<f32> = params.poses.iter().map(|&x| x as f32).collect();
        let pose = Pose::from_flat(
            &f32s,
            params.rh.as_vec3().to_array(),
            params.th.as_vec3().to_array(),
        )
        .map_err(|e| DataError::invalid(fit_path, e.to_string()));
        let Some(pose) = ck.check(pose)? else {
            continue;
        };
        let vertices = PosedVertices::Fitted(FittedPose {
            model: Arc::clone(&model),
            model_file: model_file.clone(),
            fit: fit_path.clone(),
            params,
        });
        // Inspection poses every frame, so that a fit whose shapes make an absurd body is named.
        if ck.whole_files() && ck.check(vertices.read(None))?.is_none() {
            continue;
        }
        frames.push(FrameRecord {
            id: FrameId(f),
            file_index: *number as usize,
            images,
            masks,
            pose,
            vertices,
        });
    }
    let complete = !frames.is_empty() && frames.len() == frame_numbers.len();
    Ok(match cameras {
        Some(cameras) if complete => Some(Subject {
            name: root
                .file_name()
                .map_or_else(|| "capture".into(), |n| n.to_string_lossy().into_owned()),
            root: root.to_path_buf(),
            kind: DatasetKind::EasyMocap,
            cameras,
            frames,
            body,
            notes: ck.notes.clone(),
        }),
        _ => None,
    })
}

/// The frame numbers found in any camera's `images/<cam>/` folder, sorted, and each frame's image path
/// per camera (`None` where that camera lacks the frame, each such gap recorded).
fn list_frames(
    root: &Path,
    names: &[String],
    ck: &mut Checker,
) -> Result<(Vec<u64>, Vec<Option<FramePaths>>), DataError> {
    let mut per_camera: Vec<BTreeMap<u64, String>> = Vec::with_capacity(names.len());
    for name in names {
        let folder = root.join("images").join(name);
        per_camera.push(ck.check(frame_files(&folder))?.unwrap_or_default());
    }
    let mut numbers: Vec<u64> = per_camera.iter().flat_map(|m| m.keys().copied()).collect();
    numbers.sort_unstable();
    numbers.dedup();
    let mut frames = Vec::with_capacity(numbers.len());
    for &n in &numbers {
        let mut paths = Vec::with_capacity(names.len());
        for (name, files) in names.iter().zip(&per_camera) {
            let path = match files.get(&n) {
                Some(file) => Some(format!("images/{name}/{file}")),
                None => {
                    ck.check::<()>(Err(DataError::Missing {
                        path: root.join("images").join(name),
                        what: format!("an image of frame {n}, which other cameras have"),
                    }))?;
                    None
                }
            };
            paths.push(path);
        }
        frames.push(Some(paths));
    }
    if numbers.is_empty() && per_camera.iter().all(BTreeMap::is_empty) {
        ck.check::<()>(Err(DataError::Missing {
            path: root.join("images"),
            what: "images/<camera>/<frame>.jpg for the cameras of intri.yml".into(),
        }))?;
    }
    Ok((numbers, frames))
}

/// The images of one camera folder by frame number; a file named otherwise is an error.
fn frame_files(folder: &Path) -> Result<BTreeMap<u64, String>, DataError> {
    let entries = std::fs::read_dir(folder).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => DataError::Missing {
            path: folder.to_path_buf(),
            what: "the image folder of a camera named in intri.yml".into(),
        },
        _ => DataError::io(folder, e),
    })?;
    let mut files = BTreeMap::new();
    for entry in entries {
        let entry = entry.map_err(|e| DataError::io(folder, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = Path::new(&name);
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !IMAGE_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()) {
            continue;
        }
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let number: u64 = stem.parse().map_err(|_| {
            DataError::invalid(
                folder.join(&name),
                "is not named by its frame number (EasyMocap writes 000000.jpg, 000001.jpg, …)",
            )
        })?;
        if let Some(other) = files.insert(number, name.clone()) {
            return Err(DataError::invalid(
                folder.join(&name),
                format!("is frame {number} again (also {other})"),
            ));
        }
    }
    Ok(files)
}

/// Each frame's fit file and the chosen person's fit in it (`None` where it is missing or unusable, each
/// recorded); `None` when there is no fit folder at all.
#[allow(clippy::type_complexity)]
fn read_fits(
    root: &Path,
    frames: &[u64],
    person: Option<i64>,
    ck: &mut Checker,
) -> Result<Option<Vec<Option<(PathBuf, PersonFit)>>>, DataError> {
    let Some(folder) = FIT_FOLDERS
        .iter()
        .map(|f| root.join(f))
        .find(|f| f.is_dir())
    else {
        ck.check::<()>(Err(DataError::Missing {
            path: root.join(FIT_FOLDERS[0]),
            what: format!(
                "EasyMocap's SMPL fits: {}/<frame>.json or {}/<frame>.json",
                FIT_FOLDERS[0], FIT_FOLDERS[1]
            ),
        }))?;
        return Ok(None);
    };
    let inside = Folder::new(root, "dataset folder");
    let mut people = Vec::with_capacity(frames.len());
    for &n in frames {
        let path = folder.join(format!("{n:06}.json"));
        let read = if path.is_file() {
            inside.check(&path).and_then(|()| read_fit_file(&path))
        } else {
            Err(DataError::Missing {
                path: path.clone(),
                what: format!("the fit of frame {n}, which has images"),
            })
        };
        people.push(ck.check(read)?.map(|p| (path, p)));
    }
    let chosen = match person {
        Some(id) => id,
        None => match people.iter().flatten().next() {
            Some((_, first)) if first.len() == 1 => first[0].id,
            Some((path, first)) => {
                ck.check::<()>(Err(DataError::invalid(
                    path,
                    format!(
                        "holds {} people (ids {}); choose one with --person (dataset.person)",
                        first.len(),
                        ids(first)
                    ),
                )))?;
                return Ok(None);
            }
            None => return Ok(None),
        },
    };
    people
        .into_iter()
        .map(|frame| {
            let Some((path, fits)) = frame else {
                return Ok(None);
            };
            let fit = fits
                .iter()
                .find(|p| p.id == chosen)
                .cloned()
                .ok_or_else(|| {
                    DataError::invalid(
                        &path,
                        format!("has no person {chosen} (ids: {})", ids(&fits)),
                    )
                });
            Ok(ck.check(fit)?.map(|fit| (path, fit)))
        })
        .collect::<Result<_, _>>()
        .map(Some)
}

fn ids(people: &[PersonFit]) -> String {
    let ids: Vec<String> = people.iter().map(|p| p.id.to_string()).collect();
    if ids.is_empty() {
        "none".into()
    } else {
        ids.join(", ")
    }
}

/// How the fits map onto the model: how many joints their poses drive and where SMPL-X expression
/// coefficients go among the model's shape coefficients.
struct FitLayout {
    driven: usize,
    expression_at: Option<usize>,
}

impl FitLayout {
    /// The layout of the first fit: its driven joints and, when any fit has expression coefficients,
    /// where SMPL-X keeps them (10 of 20 or 300 of 400 shape coefficients).
    fn of(
        model: &SmplModel,
        fits: &[Option<(PathBuf, PersonFit)>],
    ) -> Result<Option<Self>, DataError> {
        let Some((first_path, first)) = fits.iter().flatten().next() else {
            return Ok(None);
        };
        let with_expression = fits.iter().flatten().any(|(_, f)| !f.expression.is_empty());
        let expression_at = match (with_expression, model.num_betas()) {
            (false, _) => None,
            (true, 20) => Some(10),
            (true, 400) => Some(300),
            (true, b) => {
                return Err(DataError::invalid(
                    first_path,
                    format!(
                    "the fits carry SMPL-X expression coefficients, but the model has {b} shape \
                         coefficients; expected an SMPL-X model (10 + 10 or 300 + 100)"
                ),
                ))
            }
        };
        Ok(Some(Self {
            driven: first.poses.len() / 3,
            expression_at,
        }))
    }

    /// Checks one fit against the model and the layout: pose and shape counts the model can take, the
    /// same joints driven as in the first frame.
    fn check(&self, model: &SmplModel, path: &Path, fit: &PersonFit) -> Result<(), DataError> {
        let (k, b) = (model.num_joints(), model.num_betas());
        let n = fit.poses.len() / 3;
        // SMPL-H / SMPL-X: the body (22 joints), jaw and eyes may be driven alone, or all joints, but not
        // the hands in part (hands as PCA coefficients are another layout).
        let hands_partly = k >= 52 && n > 25 && n < k;
        if n > k || hands_partly {
            return Err(DataError::invalid(
                path,
                format!(
                    "'poses' has {} numbers, which the model's {k} joints cannot take (expected {} for all \
                     joints{}; hand poses as PCA coefficients are not supported: export full axis-angle \
                     poses)",
                    fit.poses.len(),
                    3 * k,
                    if k >= 52 { ", or 66 for the body joints" } else { "" }
                ),
            ));
        }
        if n != self.driven {
            return Err(DataError::invalid(
                path,
                format!(
                    "'poses' drives {n} joints, but the first frame's drives {}; every frame must drive the same",
                    self.driven
                ),
            ));
        }
        let room = self.expression_at.unwrap_or(b);
        if fit.shapes.len() > room {
            return Err(DataError::invalid(
                path,
                format!(
                    "'shapes' has {} betas, but the model has {room}; fit with the same model",
                    fit.shapes.len()
                ),
            ));
        }
        match self.expression_at {
            Some(at) if fit.expression.len() > b - at => Err(DataError::invalid(
                path,
                format!(
                    "'expression' has {} coefficients, but the model has {}",
                    fit.expression.len(),
                    b - at
                ),
            )),
            _ => Ok(()),
        }
    }
}
