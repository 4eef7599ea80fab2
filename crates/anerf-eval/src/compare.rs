//! `anerf compare`: PSNR and SSIM of any two image files, optionally with the paper's mask protocol.

use std::path::{Path, PathBuf};

use crate::error::{EvalError, MetricError};
use crate::images::{read_mask, read_rgb};
use crate::metrics::ImageMetrics;
use crate::pixels::{ImageSize, RgbImageExt};

/// The result of comparing a prediction with a ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub pred: PathBuf,
    pub gt: PathBuf,
    /// The mask file and how many pixels it selects, when the protocol was applied.
    pub mask: Option<(PathBuf, usize)>,
    pub metrics: ImageMetrics,
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "PSNR {:.4} dB  SSIM {:.6}",
            self.metrics.psnr, self.metrics.ssim
        )?;
        match &self.mask {
            Some((path, pixels)) => write!(
                f,
                "  ({pixels} pixels of mask {}; SSIM on its bounding crop, outside set to 0)",
                path.display()
            ),
            None => write!(f, "  (whole images)"),
        }
    }
}

/// Compares `pred` with `gt`. Without a mask: whole-image PSNR and SSIM. With a mask, the reference
/// protocol: PSNR over the mask's pixels, SSIM over its bounding crop with pixels outside it set to 0.
pub fn compare_files(pred: &Path, gt: &Path, mask: Option<&Path>) -> Result<Comparison, EvalError> {
    let pred_image = read_rgb(pred)?;
    let gt_image = read_rgb(gt)?;
    ensure_size(pred, pred_image.size(), gt, gt_image.size())?;
    let mask_image = match mask {
        Some(path) => {
            let mask_image = read_mask(path)?;
            ensure_size(path, mask_image.size(), gt, gt_image.size())?;
            if mask_image.count() == 0 {
                return Err(EvalError::EmptyMask {
                    path: path.to_path_buf(),
                });
            }
            Some(mask_image)
        }
        None => None,
    };
    let metrics =
        ImageMetrics::compute(&pred_image, &gt_image, mask_image.as_ref()).map_err(|source| {
            let context = match (mask, &source) {
                (Some(m), MetricError::TooSmallForSsim { .. }) => {
                    format!("bounding crop of mask {}", m.display())
                }
                _ => format!("{} vs {}", pred.display(), gt.display()),
            };
            EvalError::Metric { context, source }
        })?;
    Ok(Comparison {
        pred: pred.to_path_buf(),
        gt: gt.to_path_buf(),
        mask: mask
            .zip(mask_image)
            .map(|(path, m)| (path.to_path_buf(), m.count())),
        metrics,
    })
}

fn ensure_size(
    path: &Path,
    got: ImageSize,
    reference: &Path,
    expected: ImageSize,
) -> Result<(), EvalError> {
    if got == expected {
        Ok(())
    } else {
        Err(EvalError::SizeMismatch {
            path: path.to_path_buf(),
            got,
            reference: reference.to_path_buf(),
            expected,
        })
    }
}
