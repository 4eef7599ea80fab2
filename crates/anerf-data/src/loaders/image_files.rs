//! The image and mask files a dataset names: inside the dataset folder (symbolic links included), readable
//! (whole, when inspecting), and of one size per camera. Files are read in parallel; their problems are
//! recorded in a fixed order.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::annots::{FramePaths, RawCamera};
use super::check::Checker;
use crate::error::DataError;
use crate::formats::images;
use crate::paths::Folder;
use crate::subject::DatasetKind;

/// Width and height in pixels.
pub(super) type Size = (u32, u32);

/// Each distinct item and how often it occurs, in order of first occurrence.
pub(crate) fn tally<T: PartialEq>(items: impl IntoIterator<Item = T>) -> Vec<(T, usize)> {
    let mut counts: Vec<(T, usize)> = Vec::new();
    for item in items {
        match counts.iter_mut().find(|(seen, _)| *seen == item) {
            Some((_, n)) => *n += 1,
            None => counts.push((item, 1)),
        }
    }
    counts
}

/// Every accepted entry of every usable frame as `(camera, file)`, frame by frame.
fn by_camera<T>(
    frames: &[Option<Vec<Option<T>>>],
    file: impl Fn(&T) -> PathBuf,
) -> Vec<(usize, PathBuf)> {
    frames
        .iter()
        .flatten()
        .flat_map(|frame| {
            frame
                .iter()
                .enumerate()
                .filter_map(|(c, entry)| Some((c, file(entry.as_ref()?))))
        })
        .collect()
}

/// The size of each file, checked to lie inside the folder; whole-file reads also find truncation.
fn read_sizes(
    inside: &Folder,
    paths: &[(usize, PathBuf)],
    ck: &Checker,
) -> Vec<Result<Size, DataError>> {
    let whole = ck.whole_files();
    paths
        .par_iter()
        .map(|(_, path)| {
            inside.check(path)?;
            if whole {
                images::whole_image_size(path)
            } else {
                images::image_size(path)
            }
        })
        .collect()
}

/// Every listed image's size, and each camera's: the size most of its images have (on a tie, the one its
/// principal point centres best). Unreadable images and those of another size are the problems.
pub(super) fn check_images(
    root: &Path,
    inside: &Folder,
    raw: &[Option<RawCamera>],
    ims: &[Option<FramePaths>],
    ck: &mut Checker,
) -> Result<Vec<Option<Size>>, DataError> {
    let paths = by_camera(ims, |p| root.join(p));
    let mut seen: Vec<Vec<(PathBuf, Size)>> = raw.iter().map(|_| Vec::new()).collect();
    for ((c, path), size) in paths.iter().zip(read_sizes(inside, &paths, ck)) {
        if let Some(size) = ck.check(size)? {
            seen[*c].push((path.clone(), size));
        }
    }
    seen.iter()
        .zip(raw)
        .enumerate()
        .map(|(c, (seen, raw))| {
            let Some(size) = camera_size(seen, raw.as_ref()) else {
                return Ok(None);
            };
            for (path, (w, h)) in seen.iter().filter(|(_, s)| *s != size) {
                ck.check::<()>(Err(DataError::invalid(
                    path,
                    format!(
                        "image is {w}×{h}, but most of camera {c}'s images are {}×{}; a camera's images \
                         must share one size",
                        size.0, size.1
                    ),
                )))?;
            }
            Ok(Some(size))
        })
        .collect()
}

/// The most common size; ties go to the size whose centre is nearest the principal point, then to the first.
fn camera_size(seen: &[(PathBuf, Size)], raw: Option<&RawCamera>) -> Option<Size> {
    let off_centre = |(w, h): Size| {
        raw.map_or(0.0, |r| {
            let (cx, cy) = r.principal_point();
            (2.0 * cx - w as f32).abs() + (2.0 * cy - h as f32).abs()
        })
    };
    tally(seen.iter().map(|(_, s)| *s))
        .into_iter()
        .rev()
        .max_by(|(a, n), (b, m)| n.cmp(m).then(off_centre(*b).total_cmp(&off_centre(*a))))
        .map(|(size, _)| size)
}

/// Where a layout keeps the mask of each image (given as its path relative to the dataset folder).
pub(super) enum MaskRule {
    /// `mask_cihp/<image>.png`, else `mask/<image>.png`, else (H36M, `images_to_mask`) the image path with
    /// `images` replaced by `mask`.
    Zju { images_to_mask: bool },
    /// EasyMocap: the image `images/<cam>/<frame>.jpg` has its mask at `<folder>/<cam>/<frame>.png`, the
    /// first of these folders that holds it.
    Folders(Vec<String>),
}

impl MaskRule {
    /// The rule of a ZJU-layout dataset.
    pub fn of(kind: DatasetKind) -> Self {
        MaskRule::Zju {
            images_to_mask: kind == DatasetKind::H36m,
        }
    }

    fn candidates(&self, root: &Path, image: &str) -> Vec<PathBuf> {
        let stem = Path::new(image).with_extension("png");
        match self {
            MaskRule::Zju { images_to_mask } => {
                let mut c = vec![
                    root.join("mask_cihp").join(&stem),
                    root.join("mask").join(&stem),
                ];
                if *images_to_mask {
                    c.push(root.join(stem.to_string_lossy().replace("images", "mask")));
                }
                c
            }
            MaskRule::Folders(folders) => {
                let inner = stem.strip_prefix("images").unwrap_or(&stem);
                folders.iter().map(|f| root.join(f).join(inner)).collect()
            }
        }
    }
}

/// The mask of each listed image (see [`MaskRule`]), checked to lie inside the folder. All candidates are
/// named when none exists.
pub(super) fn resolve_masks(
    root: &Path,
    inside: &Folder,
    rule: &MaskRule,
    ims: &[Option<FramePaths>],
    ck: &mut Checker,
) -> Result<Vec<Option<Vec<Option<PathBuf>>>>, DataError> {
    ims.iter()
        .map(|frame| {
            let Some(frame) = frame else { return Ok(None) };
            frame
                .iter()
                .map(|p| match p {
                    Some(p) => ck.check(
                        resolve_mask(root, rule, p).and_then(|m| inside.check(&m).map(|()| m)),
                    ),
                    None => Ok(None),
                })
                .collect::<Result<_, _>>()
                .map(Some)
        })
        .collect()
}

/// One frame's absolute image and mask paths, when every camera has both (`None` when one is missing).
pub(super) fn frame_files(
    root: &Path,
    images: &Option<FramePaths>,
    masks: &Option<Vec<Option<PathBuf>>>,
) -> Option<(Vec<PathBuf>, Vec<PathBuf>)> {
    let images: Option<Vec<PathBuf>> = images
        .iter()
        .flatten()
        .map(|p| p.as_ref().map(|p| root.join(p)))
        .collect();
    let masks: Option<Vec<PathBuf>> = masks.iter().flatten().cloned().collect();
    images.zip(masks)
}

fn resolve_mask(root: &Path, rule: &MaskRule, image: &str) -> Result<PathBuf, DataError> {
    let candidates = rule.candidates(root, image);
    candidates
        .iter()
        .find(|c| c.is_file())
        .cloned()
        .ok_or_else(|| {
            let tried: Vec<String> = candidates.iter().map(|c| c.display().to_string()).collect();
            DataError::Missing {
                path: candidates[0].clone(),
                what: format!("a mask for image {image}: tried {}", tried.join(", ")),
            }
        })
}

/// Every mask is whole and of its camera's image size (when that is known).
pub(super) fn check_masks(
    inside: &Folder,
    masks: &[Option<Vec<Option<PathBuf>>>],
    sizes: &[Option<Size>],
    ck: &mut Checker,
) -> Result<(), DataError> {
    let paths = by_camera(masks, PathBuf::clone);
    for ((c, path), size) in paths.iter().zip(read_sizes(inside, &paths, ck)) {
        let (Some((w, h)), Some(Some(expected))) = (ck.check(size)?, sizes.get(*c)) else {
            continue;
        };
        if (w, h) != *expected {
            ck.check::<()>(Err(DataError::invalid(
                path,
                format!(
                    "mask is {w}×{h}, but camera {c}'s images are {}×{}; a mask must match its image",
                    expected.0, expected.1
                ),
            )))?;
        }
    }
    Ok(())
}
