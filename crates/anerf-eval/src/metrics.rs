//! PSNR and SSIM exactly as the reference evaluator computes them (docs/REFERENCE.md §4.2), in f64.
//!
//! SSIM reproduces scikit-image's `structural_similarity(a, b, win_size=7, data_range=2, channel_axis=-1,
//! use_sample_covariance=True, gaussian_weights=False)`, i.e. skimage 0.14's `compare_ssim` defaults on
//! float64 input that the published numbers came from: a 7×7 uniform window, sample covariance
//! (N/(N−1)), K1 = 0.01, K2 = 0.03, data range 2, the mean over the pixels at least 3 px from the border,
//! averaged over the three channels.

use image::Rgb32FImage;
use serde::{Deserialize, Serialize};

use crate::error::MetricError;
use crate::pixels::{ensure_same_size, ImageSize, PixelMask, RgbImageExt};

/// Side of the square SSIM window, in pixels.
pub const SSIM_WINDOW: usize = 7;
/// SSIM's luminance stabiliser constant.
pub const SSIM_K1: f64 = 0.01;
/// SSIM's contrast stabiliser constant.
pub const SSIM_K2: f64 = 0.03;
/// The data range the reference passes to SSIM implicitly (skimage's float dtype range −1..1).
pub const SSIM_DATA_RANGE: f64 = 2.0;

/// PSNR (dB) and SSIM of one predicted image against its ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImageMetrics {
    /// −10·log10(MSE); +∞ when the compared pixels are identical.
    pub psnr: f64,
    pub ssim: f64,
}

impl ImageMetrics {
    /// Without a mask: PSNR and SSIM of the whole images. With a mask, the reference protocol: PSNR over the
    /// mask's pixels, SSIM over the mask's bounding crop with pixels outside the mask set to 0 in both.
    pub fn compute(
        pred: &Rgb32FImage,
        gt: &Rgb32FImage,
        mask: Option<&PixelMask>,
    ) -> Result<Self, MetricError> {
        pred.check_finite()?;
        gt.check_finite()?;
        match mask {
            None => Ok(Self {
                psnr: psnr(pred, gt, None)?,
                ssim: ssim(pred, gt)?,
            }),
            Some(mask) => Ok(Self {
                psnr: psnr(pred, gt, Some(mask))?,
                ssim: masked_ssim(pred, gt, mask)?,
            }),
        }
    }
}

/// PSNR in dB, −10·log10(MSE) over the pixels of `mask` (all pixels without one) × 3 channels, for
/// values in [0, 1]; +∞ when those pixels are identical.
pub fn psnr(
    pred: &Rgb32FImage,
    gt: &Rgb32FImage,
    mask: Option<&PixelMask>,
) -> Result<f64, MetricError> {
    ensure_same_size(pred.size(), gt.size())?;
    if let Some(mask) = mask {
        ensure_same_size(pred.size(), mask.size())?;
    }
    let selected = |i: usize| mask.is_none_or(|m| m.bits()[i]);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (i, (p, g)) in pred
        .as_raw()
        .chunks_exact(3)
        .zip(gt.as_raw().chunks_exact(3))
        .enumerate()
    {
        if selected(i) {
            sum += p
                .iter()
                .zip(g)
                .map(|(&p, &g)| (f64::from(p) - f64::from(g)).powi(2))
                .sum::<f64>();
            count += 3;
        }
    }
    if count == 0 {
        return Err(MetricError::EmptyMask);
    }
    Ok(-10.0 * (sum / count as f64).log10())
}

/// SSIM of two whole images (see the module documentation for the exact definition).
pub fn ssim(a: &Rgb32FImage, b: &Rgb32FImage) -> Result<f64, MetricError> {
    ensure_same_size(a.size(), b.size())?;
    let size = a.size();
    if (size.width as usize) < SSIM_WINDOW || (size.height as usize) < SSIM_WINDOW {
        return Err(MetricError::TooSmallForSsim { size });
    }
    let per_channel: f64 = (0..3)
        .map(|c| {
            let channel = |img: &Rgb32FImage| -> Vec<f64> {
                img.as_raw()
                    .iter()
                    .skip(c)
                    .step_by(3)
                    .map(|&v| f64::from(v))
                    .collect()
            };
            ssim_channel(&channel(a), &channel(b), size)
        })
        .sum();
    Ok(per_channel / 3.0)
}

/// The reference protocol's SSIM: both images cropped to the bounding rectangle of `mask`, with pixels
/// outside the mask set to 0, then [`ssim`].
pub fn masked_ssim(
    pred: &Rgb32FImage,
    gt: &Rgb32FImage,
    mask: &PixelMask,
) -> Result<f64, MetricError> {
    ensure_same_size(pred.size(), gt.size())?;
    ensure_same_size(pred.size(), mask.size())?;
    let rect = mask.bounding_rect().ok_or(MetricError::EmptyMask)?;
    let pred = pred.zeroed_outside(mask)?.crop_rect(rect);
    let gt = gt.zeroed_outside(mask)?.crop_rect(rect);
    ssim(&pred, &gt)
}

/// Mean SSIM of one channel (row-major values of an image of `size`) over the pixels whose 7×7 window lies
/// inside the image; that is skimage's `crop(S, 3).mean()`, so its border handling never matters.
fn ssim_channel(x: &[f64], y: &[f64], size: ImageSize) -> f64 {
    let (w, h) = (size.width as usize, size.height as usize);
    let n = (SSIM_WINDOW * SSIM_WINDOW) as f64;
    let cov_norm = n / (n - 1.0);
    let c1 = (SSIM_K1 * SSIM_DATA_RANGE).powi(2);
    let c2 = (SSIM_K2 * SSIM_DATA_RANGE).powi(2);
    let products: [Vec<f64>; 5] = [
        x.to_vec(),
        y.to_vec(),
        x.iter().map(|v| v * v).collect(),
        y.iter().map(|v| v * v).collect(),
        x.iter().zip(y).map(|(a, b)| a * b).collect(),
    ];
    let [ux, uy, uxx, uyy, uxy] = products.map(|p| window_means(&p, w, h));
    let mut total = 0.0;
    for i in 0..ux.len() {
        let vx = cov_norm * (uxx[i] - ux[i] * ux[i]);
        let vy = cov_norm * (uyy[i] - uy[i] * uy[i]);
        let vxy = cov_norm * (uxy[i] - ux[i] * uy[i]);
        let numerator = (2.0 * ux[i] * uy[i] + c1) * (2.0 * vxy + c2);
        let denominator = (ux[i] * ux[i] + uy[i] * uy[i] + c1) * (vx + vy + c2);
        total += numerator / denominator;
    }
    total / ux.len() as f64
}

/// Means over every full 7×7 window of a `w`×`h` row-major array, as a (h−6)×(w−6) row-major array
/// (separable: 7-sums along rows, then along columns).
fn window_means(values: &[f64], w: usize, h: usize) -> Vec<f64> {
    let k = SSIM_WINDOW;
    let (ow, oh) = (w + 1 - k, h + 1 - k);
    let mut rows = Vec::with_capacity(h * ow);
    for row in values.chunks_exact(w) {
        rows.extend(row.windows(k).map(|win| win.iter().sum::<f64>()));
    }
    let scale = 1.0 / (k * k) as f64;
    let mut out = Vec::with_capacity(oh * ow);
    for y in 0..oh {
        for x in 0..ow {
            out.push((0..k).map(|dy| rows[(y + dy) * ow + x]).sum::<f64>() * scale);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(size: ImageSize, f: impl Fn(u32, u32, usize) -> f32) -> Rgb32FImage {
        let data = (0..size.height)
            .flat_map(|y| (0..size.width).flat_map(move |x| (0..3).map(move |c| (x, y, c))))
            .map(|(x, y, c)| f(x, y, c))
            .collect();
        Rgb32FImage::from_values(size, data).unwrap()
    }

    #[test]
    fn psnr_of_a_uniform_offset_is_analytic() {
        // MSE = 0.1² → PSNR = 20 dB exactly; the masked PSNR ignores pixels outside the mask.
        let size = ImageSize::new(9, 8);
        let gt = image(size, |x, y, c| {
            0.05 * (x + y) as f32 / 16.0 + 0.1 * c as f32
        });
        let pred = image(size, |x, y, c| gt.pixel(x, y)[c] + 0.1);
        assert!((psnr(&pred, &gt, None).unwrap() - 20.0).abs() < 1e-5);
        let mask = PixelMask::from_fn(size, |x, _| x < 4);
        let mut spoiled = pred.clone();
        spoiled.set_pixel(8, 7, [1.0, 0.0, 1.0]);
        assert!((psnr(&spoiled, &gt, Some(&mask)).unwrap() - 20.0).abs() < 1e-5);
        assert_eq!(psnr(&gt, &gt, None).unwrap(), f64::INFINITY);
    }

    #[test]
    fn ssim_of_constant_images_follows_the_luminance_term() {
        // Zero variance leaves only the luminance term: (2ab + C1) / (a² + b² + C1).
        let size = ImageSize::new(8, 7);
        let (a, b) = (0.2f64, 0.6f64);
        let c1 = (SSIM_K1 * SSIM_DATA_RANGE).powi(2);
        let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
        let got = ssim(
            &image(size, |_, _, _| a as f32),
            &image(size, |_, _, _| b as f32),
        )
        .unwrap();
        assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    }

    #[test]
    fn ssim_is_one_for_identical_images_and_symmetric() {
        let size = ImageSize::new(12, 10);
        let a = image(size, |x, y, c| {
            ((x * 7 + y * 3 + c as u32) % 11) as f32 / 10.0
        });
        let b = image(size, |x, y, c| {
            ((x * 5 + y * 2 + c as u32) % 13) as f32 / 12.0
        });
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        assert!((ssim(&a, &b).unwrap() - ssim(&b, &a).unwrap()).abs() < 1e-12);
    }

    #[test]
    fn invalid_inputs_are_reported() {
        let small = Rgb32FImage::black(ImageSize::new(6, 9));
        assert_eq!(
            ssim(&small, &small),
            Err(MetricError::TooSmallForSsim { size: small.size() })
        );
        let other = Rgb32FImage::black(ImageSize::new(9, 6));
        assert!(matches!(
            psnr(&small, &other, None),
            Err(MetricError::SizeMismatch { .. })
        ));
        let empty = PixelMask::from_fn(small.size(), |_, _| false);
        assert_eq!(
            psnr(&small, &small, Some(&empty)),
            Err(MetricError::EmptyMask)
        );
        assert_eq!(
            masked_ssim(&small, &small, &empty),
            Err(MetricError::EmptyMask)
        );
        // A mask whose bounding crop is narrower than the window cannot be scored.
        let big = Rgb32FImage::black(ImageSize::new(20, 20));
        let thin = PixelMask::from_fn(big.size(), |x, _| (4..10).contains(&x));
        assert!(matches!(
            masked_ssim(&big, &big, &thin),
            Err(MetricError::TooSmallForSsim { .. })
        ));
    }
}
