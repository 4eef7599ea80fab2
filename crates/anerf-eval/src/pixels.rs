//! In-memory images for evaluation: sizes, rectangles, boolean pixel masks, and what evaluation adds to the
//! workspace's RGB image type ([`RgbImageExt`] on `image::Rgb32FImage`).
//!
//! Pixel (x, y) is column x, row y from the top-left corner; storage is row-major.

use image::Rgb32FImage;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Width and height of an image in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ImageSize {
    pub width: u32,
    pub height: u32,
}

impl ImageSize {
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height }
    }

    /// Number of pixels.
    pub fn pixels(self) -> usize {
        self.width as usize * self.height as usize
    }
}

impl std::fmt::Display for ImageSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

/// An axis-aligned pixel rectangle: columns `x..x + width`, rows `y..y + height`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    pub x: u32,
    pub y: u32,
    pub size: ImageSize,
}

/// What evaluation needs of an RGB image beyond the `image` crate's: the one RGB image type of the workspace
/// is [`Rgb32FImage`] (three interleaved f32 channels per pixel, row-major, nominally in [0, 1]; 8-bit
/// sources become `value / 255` computed in f32, exactly as the reference loader converts them), read by
/// the data layer and rendered by the model alike.
pub trait RgbImageExt: Sized {
    /// Wraps row-major RGB values; fails unless they hold 3 finite values per pixel.
    fn from_values(size: ImageSize, data: Vec<f32>) -> Result<Self, MetricError>;

    /// An all-black image.
    fn black(size: ImageSize) -> Self;

    /// Width and height.
    fn size(&self) -> ImageSize;

    /// The RGB values of pixel `(x, y)`; panics outside the image.
    fn pixel(&self, x: u32, y: u32) -> [f32; 3];

    /// Sets one pixel; non-finite values are the caller's bug, so they panic.
    fn set_pixel(&mut self, x: u32, y: u32, rgb: [f32; 3]);

    /// The rectangle `rect` as a new image; panics if it leaves the image.
    fn crop_rect(&self, rect: PixelRect) -> Self;

    /// A copy with every pixel outside `mask` set to 0 (black).
    fn zeroed_outside(&self, mask: &PixelMask) -> Result<Self, MetricError>;

    /// Fails with the first non-finite value's index.
    fn check_finite(&self) -> Result<(), MetricError>;
}

impl RgbImageExt for Rgb32FImage {
    fn from_values(size: ImageSize, data: Vec<f32>) -> Result<Self, MetricError> {
        let expected = size.pixels() * 3;
        if data.len() != expected {
            return Err(MetricError::DataLength {
                size,
                expected,
                got: data.len(),
            });
        }
        let image = Rgb32FImage::from_raw(size.width, size.height, data)
            .expect("the length is checked above");
        image.check_finite()?;
        Ok(image)
    }

    fn black(size: ImageSize) -> Self {
        Rgb32FImage::new(size.width, size.height)
    }

    fn size(&self) -> ImageSize {
        ImageSize::new(self.width(), self.height())
    }

    fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        assert!(
            x < self.width() && y < self.height(),
            "pixel ({x}, {y}) outside {}",
            self.size()
        );
        self.get_pixel(x, y).0
    }

    fn set_pixel(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        assert!(
            rgb.iter().all(|v| v.is_finite()),
            "non-finite pixel value {rgb:?}"
        );
        self.put_pixel(x, y, image::Rgb(rgb));
    }

    fn crop_rect(&self, rect: PixelRect) -> Self {
        assert!(
            rect.x + rect.size.width <= self.width() && rect.y + rect.size.height <= self.height(),
            "crop {rect:?} leaves a {} image",
            self.size()
        );
        image::imageops::crop_imm(self, rect.x, rect.y, rect.size.width, rect.size.height)
            .to_image()
    }

    fn zeroed_outside(&self, mask: &PixelMask) -> Result<Self, MetricError> {
        ensure_same_size(self.size(), mask.size())?;
        let mut out = self.clone();
        for (rgb, &inside) in out.pixels_mut().zip(mask.bits()) {
            if !inside {
                rgb.0 = [0.0; 3];
            }
        }
        Ok(out)
    }

    fn check_finite(&self) -> Result<(), MetricError> {
        match self
            .as_raw()
            .iter()
            .enumerate()
            .find(|(_, v)| !v.is_finite())
        {
            Some((index, &value)) => Err(MetricError::NonFinite { index, value }),
            None => Ok(()),
        }
    }
}

/// A set of pixels of an image (for evaluation: the pixels whose ray hits the padded body box).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PixelMask {
    size: ImageSize,
    bits: Vec<bool>,
}

impl PixelMask {
    /// Wraps row-major flags; fails unless there is one per pixel.
    pub fn new(size: ImageSize, bits: Vec<bool>) -> Result<Self, MetricError> {
        if bits.len() != size.pixels() {
            return Err(MetricError::DataLength {
                size,
                expected: size.pixels(),
                got: bits.len(),
            });
        }
        Ok(Self { size, bits })
    }

    /// A mask from a predicate on (x, y).
    pub fn from_fn(size: ImageSize, mut inside: impl FnMut(u32, u32) -> bool) -> Self {
        let bits = (0..size.height)
            .flat_map(|y| (0..size.width).map(move |x| (x, y)))
            .map(|(x, y)| inside(x, y));
        Self {
            size,
            bits: bits.collect(),
        }
    }

    /// Every pixel of an image of `size`.
    pub fn full(size: ImageSize) -> Self {
        Self {
            size,
            bits: vec![true; size.pixels()],
        }
    }

    pub fn size(&self) -> ImageSize {
        self.size
    }

    /// Row-major flags, one per pixel.
    pub fn bits(&self) -> &[bool] {
        &self.bits
    }

    pub fn contains(&self, x: u32, y: u32) -> bool {
        assert!(
            x < self.size.width && y < self.size.height,
            "pixel ({x}, {y}) outside {}",
            self.size
        );
        self.bits[y as usize * self.size.width as usize + x as usize]
    }

    /// Number of pixels in the mask.
    pub fn count(&self) -> usize {
        self.bits.iter().filter(|&&b| b).count()
    }

    /// The smallest rectangle holding every mask pixel, or `None` for an empty mask.
    pub fn bounding_rect(&self) -> Option<PixelRect> {
        let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
        for y in 0..self.size.height {
            for x in 0..self.size.width {
                if self.contains(x, y) {
                    (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
                }
            }
        }
        (x0 != u32::MAX).then(|| PixelRect {
            x: x0,
            y: y0,
            size: ImageSize::new(x1 - x0 + 1, y1 - y0 + 1),
        })
    }

    /// The rectangle `rect` as a new mask; panics if it leaves the mask.
    pub fn crop(&self, rect: PixelRect) -> Self {
        Self::from_fn(rect.size, |x, y| self.contains(rect.x + x, rect.y + y))
    }
}

/// Fails with [`MetricError::SizeMismatch`] unless `a == b`.
pub(crate) fn ensure_same_size(a: ImageSize, b: ImageSize) -> Result<(), MetricError> {
    if a == b {
        Ok(())
    } else {
        Err(MetricError::SizeMismatch { a, b })
    }
}

/// Invalid inputs to the metrics or to in-memory image operations.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MetricError {
    #[error("images differ in size: {a} vs {b}; expected the same size")]
    SizeMismatch { a: ImageSize, b: ImageSize },
    #[error("mask has no foreground pixel; expected at least one")]
    EmptyMask,
    #[error(
        "SSIM needs at least 7x7 pixels (its window), got a {size} region; the reference's skimage call \
         rejects it too"
    )]
    TooSmallForSsim { size: ImageSize },
    #[error("image data has {got} values, expected {expected} (3 per pixel of {size})")]
    DataLength {
        size: ImageSize,
        expected: usize,
        got: usize,
    },
    #[error("image value {index} is not finite: {value}")]
    NonFinite { index: usize, value: f32 },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounding_rect_spans_the_extreme_pixels() {
        let mask = PixelMask::from_fn(ImageSize::new(10, 8), |x, y| {
            (x, y) == (2, 6) || (x, y) == (7, 1)
        });
        let rect = mask.bounding_rect().unwrap();
        assert_eq!((rect.x, rect.y, rect.size), (2, 1, ImageSize::new(6, 6)));
        assert_eq!(mask.crop(rect).count(), 2);
        assert!(PixelMask::from_fn(ImageSize::new(3, 3), |_, _| false)
            .bounding_rect()
            .is_none());
    }

    #[test]
    fn crop_and_zeroing_keep_the_right_pixels() {
        let size = ImageSize::new(4, 3);
        let data: Vec<f32> = (0..36).map(|i| i as f32 / 36.0).collect();
        let image = Rgb32FImage::from_values(size, data).unwrap();
        let rect = PixelRect {
            x: 1,
            y: 1,
            size: ImageSize::new(2, 2),
        };
        let cropped = image.crop_rect(rect);
        assert_eq!(cropped.pixel(0, 0), image.pixel(1, 1));
        assert_eq!(cropped.pixel(1, 1), image.pixel(2, 2));
        let mask = PixelMask::from_fn(size, |x, _| x == 3);
        let zeroed = image.zeroed_outside(&mask).unwrap();
        assert_eq!(zeroed.pixel(3, 2), image.pixel(3, 2));
        assert_eq!(zeroed.pixel(2, 2), [0.0; 3]);
    }

    #[test]
    fn bad_data_is_rejected_with_its_position() {
        let size = ImageSize::new(2, 1);
        assert_eq!(
            Rgb32FImage::from_values(size, vec![0.0; 5]),
            Err(MetricError::DataLength {
                size,
                expected: 6,
                got: 5
            })
        );
        let err =
            Rgb32FImage::from_values(size, vec![0.0, 0.0, 0.0, f32::NAN, 0.0, 0.0]).unwrap_err();
        assert!(
            matches!(err, MetricError::NonFinite { index: 3, .. }),
            "{err}"
        );
        assert!(PixelMask::new(size, vec![true]).is_err());
    }
}
