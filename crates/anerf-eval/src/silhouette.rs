//! Where an image's error lies relative to the true silhouette: the PSNR inside a band around the
//! ground-truth silhouette's boundary and outside it, and how large the rendered silhouette is against the
//! true one. A soft, dilated silhouette (a halo of partial opacity) shows as a low band PSNR and an area
//! ratio above 1 while the protocol's PSNR, dominated by the body's inside, barely moves.

use image::Rgb32FImage;
use serde::{Deserialize, Serialize};

use crate::error::MetricError;
use crate::metrics::psnr;
use crate::pixels::{ensure_same_size, ImageSize, PixelMask, RgbImageExt};

/// Radius of the boundary band, pixels.
pub const BAND_RADIUS: u32 = 2;

/// The silhouette figures of one image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SilhouetteMetrics {
    /// PSNR (dB) over the evaluated pixels within [`BAND_RADIUS`] of the true silhouette's boundary.
    #[serde(with = "crate::report::metric_value")]
    pub band_psnr: f64,
    /// PSNR (dB) over the other evaluated pixels.
    #[serde(with = "crate::report::metric_value")]
    pub outside_band_psnr: f64,
    /// The rendered silhouette's area (the sum of the rendered opacity over the image, so a half-transparent
    /// halo counts by half) over the true silhouette's pixel count.
    #[serde(with = "crate::report::metric_value")]
    pub area_ratio: f64,
}

/// The true silhouette of an image and the rendered opacity, per pixel.
pub struct Silhouettes<'a> {
    /// The ground truth's foreground pixels.
    pub truth: &'a PixelMask,
    /// Row-major rendered opacity in `[0, 1]` (0 where no ray was rendered).
    pub opacity: &'a [f32],
}

impl SilhouetteMetrics {
    /// The figures of `pred` against `gt` over the evaluated pixels `mask` (the protocol's), split by the
    /// band around `silhouettes.truth`. A side of the split without pixels has a PSNR of NaN; an empty true
    /// silhouette gives an area ratio of +∞ (or NaN when nothing was rendered either).
    pub fn compute(
        pred: &Rgb32FImage,
        gt: &Rgb32FImage,
        mask: &PixelMask,
        silhouettes: &Silhouettes,
    ) -> Result<Self, MetricError> {
        let size = pred.size();
        ensure_same_size(size, silhouettes.truth.size())?;
        ensure_same_size(size, mask.size())?;
        if silhouettes.opacity.len() != size.pixels() {
            return Err(MetricError::DataLength {
                size,
                expected: size.pixels(),
                got: silhouettes.opacity.len(),
            });
        }
        let band = edge_band(silhouettes.truth, BAND_RADIUS);
        let part = |in_band: bool| -> Result<f64, MetricError> {
            let bits = mask
                .bits()
                .iter()
                .zip(band.bits())
                .map(|(&m, &b)| m && b == in_band)
                .collect();
            match psnr(pred, gt, Some(&PixelMask::new(size, bits)?)) {
                Err(MetricError::EmptyMask) => Ok(f64::NAN),
                other => other,
            }
        };
        let rendered: f64 = silhouettes.opacity.iter().map(|&a| f64::from(a)).sum();
        let truth = silhouettes.truth.bits().iter().filter(|&&b| b).count();
        Ok(Self {
            band_psnr: part(true)?,
            outside_band_psnr: part(false)?,
            area_ratio: rendered / truth as f64,
        })
    }
}

/// The pixels within Euclidean distance `radius` of a pixel of the other class of `silhouette` (inside
/// the image): foreground pixels near the background and background pixels near the foreground.
pub fn edge_band(silhouette: &PixelMask, radius: u32) -> PixelMask {
    let ImageSize { width, height } = silhouette.size();
    let r = radius as i64;
    let offsets: Vec<(i64, i64)> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| dx * dx + dy * dy <= r * r)
        .collect();
    PixelMask::from_fn(silhouette.size(), |x, y| {
        let own = silhouette.contains(x, y);
        offsets.iter().any(|&(dx, dy)| {
            let (u, v) = (x as i64 + dx, y as i64 + dy);
            (0..width as i64).contains(&u)
                && (0..height as i64).contains(&v)
                && silhouette.contains(u as u32, v as u32) != own
        })
    })
}
