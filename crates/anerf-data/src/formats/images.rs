//! Images (jpg, png) and foreground masks through the `image` crate.

use std::path::Path;

use image::{GrayImage, Rgb32FImage};

use crate::error::DataError;

fn require_file(path: &Path) -> Result<(), DataError> {
    if path.is_file() {
        Ok(())
    } else {
        Err(DataError::Missing {
            path: path.to_path_buf(),
            what: "an image file".into(),
        })
    }
}

fn open(path: &Path) -> Result<image::DynamicImage, DataError> {
    require_file(path)?;
    image::open(path).map_err(|source| DataError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// An RGB image with channels in `[0, 1]` (8-bit values / 255, as the reference reads them).
pub fn read_rgb(path: &Path) -> Result<Rgb32FImage, DataError> {
    Ok(open(path)?.into_rgb32f())
}

/// A foreground mask: 1 where the stored pixel is non-zero, 0 elsewhere (multi-channel masks use their
/// first channel, as the reference's `imread(...)[..., 0]`).
pub fn read_mask(path: &Path) -> Result<GrayImage, DataError> {
    let mut m = read_gray(path)?;
    for p in m.pixels_mut() {
        p[0] = (p[0] != 0) as u8;
    }
    Ok(m)
}

/// A single-channel 8-bit image as stored (the first channel of a colour file).
pub fn read_gray(path: &Path) -> Result<GrayImage, DataError> {
    Ok(match open(path)? {
        image::DynamicImage::ImageLuma8(g) => g,
        other => {
            let rgb = other.into_rgb8();
            GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                image::Luma([rgb.get_pixel(x, y)[0]])
            })
        }
    })
}

/// Width and height from the file header, without decoding the pixels.
pub fn image_size(path: &Path) -> Result<(u32, u32), DataError> {
    require_file(path)?;
    image::image_dimensions(path).map_err(|source| DataError::Image {
        path: path.to_path_buf(),
        source,
    })
}
