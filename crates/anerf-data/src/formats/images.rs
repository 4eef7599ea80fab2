//! Images (jpg, png) and foreground masks through the `image` crate. Every decode goes through [`decode`],
//! which first checks that the file is whole ([`super::image_structure`]): the decoders themselves accept
//! a JPEG cut in half.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, GrayImage, ImageFormat, ImageReader, Rgb32FImage, RgbImage};

use super::image_structure;
use crate::error::DataError;

fn image_error(path: &Path) -> impl FnOnce(image::ImageError) -> DataError + '_ {
    move |source| DataError::Image {
        path: path.to_path_buf(),
        source,
    }
}

/// The bytes and format of a PNG or JPEG file found whole.
fn read_whole(path: &Path) -> Result<(Vec<u8>, ImageFormat), DataError> {
    let bytes = super::read_bytes(path)?;
    let format = image_structure::check(&bytes).map_err(image_error(path))?;
    Ok((bytes, format))
}

/// A whole PNG or JPEG file, decoded; a cut-short or damaged file is an error naming it.
pub fn decode(path: &Path) -> Result<DynamicImage, DataError> {
    decode_bytes(&super::read_bytes(path)?).map_err(image_error(path))
}

/// [`decode`] of bytes in memory: the structure check, then the decoder (within the `image` crate's default
/// limit of 512 MiB, whatever size a damaged header claims).
pub fn decode_bytes(bytes: &[u8]) -> Result<DynamicImage, image::ImageError> {
    let format = image_structure::check(bytes)?;
    image::load_from_memory_with_format(bytes, format)
}

/// A channel in `[0, 1]` as an 8-bit value (clamped, rounded): what the prepared cache stores, and the
/// inverse of [`read_rgb`]'s `/ 255` on 8-bit values.
pub fn channel_byte(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// An 8-bit value as a channel in `[0, 1]`: what [`read_rgb`] makes of an 8-bit file's values.
pub fn byte_channel(b: u8) -> f32 {
    f32::from(b) / 255.0
}

/// An RGB image as 8-bit values (a deeper file's rounded down to 8 bits): a quarter of [`read_rgb`]'s memory.
pub fn read_rgb8(path: &Path) -> Result<RgbImage, DataError> {
    Ok(decode(path)?.into_rgb8())
}

/// An RGB image with channels in `[0, 1]` (8-bit values / 255, as the reference reads them).
pub fn read_rgb(path: &Path) -> Result<Rgb32FImage, DataError> {
    Ok(decode(path)?.into_rgb32f())
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
    Ok(match decode(path)? {
        DynamicImage::ImageLuma8(g) => g,
        other => {
            let rgb = other.into_rgb8();
            GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                image::Luma([rgb.get_pixel(x, y)[0]])
            })
        }
    })
}

/// Width and height from the file header alone: cheap, but blind to a file cut short after its header.
pub fn image_size(path: &Path) -> Result<(u32, u32), DataError> {
    super::check_regular(path).map_err(|e| match e {
        DataError::Missing { path, .. } => DataError::Missing {
            path,
            what: "an image file".into(),
        },
        other => other,
    })?;
    image::image_dimensions(path).map_err(image_error(path))
}

/// Width and height of a file found whole (structure and CRCs checked, pixels not decoded): what
/// `anerf info` reads of every image and mask.
pub fn whole_image_size(path: &Path) -> Result<(u32, u32), DataError> {
    let (bytes, format) = read_whole(path)?;
    ImageReader::with_format(Cursor::new(&bytes), format)
        .into_dimensions()
        .map_err(image_error(path))
}
