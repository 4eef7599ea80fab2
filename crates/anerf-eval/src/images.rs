//! Image files: reading PNG/JPEG images and masks into [`RgbImageF32`] / [`PixelMask`].

use std::path::Path;

use image::DynamicImage;

use crate::error::EvalError;
use crate::raster::{ImageSize, PixelMask, RgbImageF32};

/// Reads an RGB image; 8-bit values become `v / 255` and 16-bit values `v / 65535` (in f32), any alpha
/// channel is ignored.
pub fn read_rgb(path: &Path) -> Result<RgbImageF32, EvalError> {
    let image = decode(path, "an RGB image")?;
    let size = ImageSize::new(image.width(), image.height());
    let data: Vec<f32> = match &image {
        DynamicImage::ImageRgb32F(_) | DynamicImage::ImageRgba32F(_) => {
            image.to_rgb32f().into_raw()
        }
        _ if is_16_bit(&image) => image
            .to_rgb16()
            .into_raw()
            .into_iter()
            .map(|v| f32::from(v) / 65535.0)
            .collect(),
        _ => image
            .to_rgb8()
            .into_raw()
            .into_iter()
            .map(|v| f32::from(v) / 255.0)
            .collect(),
    };
    RgbImageF32::new(size, data).map_err(|source| EvalError::Metric {
        context: path.display().to_string(),
        source,
    })
}

/// Reads a mask image: a pixel is inside when any of its colour channels is non-zero (the datasets' masks
/// use 1 or 255 for the foreground); any alpha channel is ignored.
pub fn read_mask(path: &Path) -> Result<PixelMask, EvalError> {
    let image = decode(path, "a mask image")?;
    let size = ImageSize::new(image.width(), image.height());
    let bits = image
        .to_rgb16()
        .pixels()
        .map(|p| p.0.iter().any(|&v| v != 0))
        .collect();
    PixelMask::new(size, bits).map_err(|source| EvalError::Metric {
        context: path.display().to_string(),
        source,
    })
}

fn decode(path: &Path, expected: &'static str) -> Result<DynamicImage, EvalError> {
    let unreadable = |source| EvalError::UnreadableImage {
        path: path.to_path_buf(),
        source,
    };
    image::ImageReader::open(path)
        .map_err(|e| EvalError::io(path, expected, e))?
        .with_guessed_format()
        .map_err(|e| EvalError::io(path, expected, e))?
        .decode()
        .map_err(unreadable)
}

fn is_16_bit(image: &DynamicImage) -> bool {
    let color = image.color();
    color.bytes_per_pixel() / color.channel_count() == 2
}
