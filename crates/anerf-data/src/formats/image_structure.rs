//! Whether a PNG or JPEG file is whole, from its structure alone: every JPEG segment and the scan data up to
//! the end-of-image marker, every PNG chunk with a matching CRC up to `IEND`. The `image` decoders accept a
//! JPEG cut in half (the missing part decodes as grey) and a PNG cut after its pixel data, so this check
//! comes first; it reads bytes and never decodes pixels, so `anerf info` can afford it on every image.

use image::error::{DecodingError, ImageFormatHint, UnsupportedError, UnsupportedErrorKind};
use image::{ImageError, ImageFormat};
use thiserror::Error;

/// What shows that an image file is cut short or damaged.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum Damage {
    #[error("the file ends at byte {len} inside {inside}, before the end-of-image marker (FF D9): it is cut short")]
    JpegTruncated { len: usize, inside: &'static str },
    #[error("byte {at} should start a marker (0xFF) but is 0x{byte:02x}: the file is damaged")]
    JpegNotAMarker { at: usize, byte: u8 },
    #[error("the segment at byte {at} has length {length}, less than its own two length bytes: the file is damaged")]
    JpegSegmentLength { at: usize, length: usize },
    #[error("the end-of-image marker comes before any scan data: the file holds no image")]
    JpegNoScan,
    #[error("the file ends at byte {len}, before the end of the chunk at byte {at} and the IEND chunk: it is cut short")]
    PngTruncated { len: usize, at: usize },
    #[error("chunk {chunk:?} at byte {at} fails its CRC check: the file is damaged")]
    PngCrc { chunk: String, at: usize },
}

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
const JPEG_SOI: &[u8] = &[0xff, 0xd8];

/// The format of `bytes` by its signature, once the file is found whole; otherwise the damage, or (for
/// anything but PNG and JPEG) an unsupported-format error, as the `image` crate's decoders report theirs.
pub fn check(bytes: &[u8]) -> Result<ImageFormat, ImageError> {
    let (format, found) = if bytes.starts_with(PNG_SIGNATURE) {
        (ImageFormat::Png, png(bytes))
    } else if bytes.starts_with(JPEG_SOI) {
        (ImageFormat::Jpeg, jpeg(bytes))
    } else {
        return Err(ImageError::Unsupported(
            UnsupportedError::from_format_and_kind(
                ImageFormatHint::Unknown,
                UnsupportedErrorKind::Format(ImageFormatHint::Unknown),
            ),
        ));
    };
    found.map(|()| format).map_err(|damage| {
        ImageError::Decoding(DecodingError::new(ImageFormatHint::Exact(format), damage))
    })
}

/// Walks the marker segments from SOI to EOI, skipping each scan's entropy-coded data (where `FF 00` is an
/// escaped byte and `FF D0`–`FF D7` are restart markers).
fn jpeg(b: &[u8]) -> Result<(), Damage> {
    let truncated = |inside| Damage::JpegTruncated {
        len: b.len(),
        inside,
    };
    let mut i = JPEG_SOI.len();
    let mut scanned = false;
    loop {
        match b.get(i) {
            None => return Err(truncated("the marker segments")),
            Some(0xff) => {}
            Some(&byte) => return Err(Damage::JpegNotAMarker { at: i, byte }),
        }
        while b.get(i) == Some(&0xff) {
            i += 1; // fill bytes before the marker code
        }
        let Some(&marker) = b.get(i) else {
            return Err(truncated("the marker segments"));
        };
        i += 1;
        match marker {
            0xd9 if scanned => return Ok(()),
            0xd9 => return Err(Damage::JpegNoScan),
            0x01 | 0xd0..=0xd7 => continue, // markers without a segment
            _ => {}
        }
        let length = match b.get(i..i + 2) {
            Some(l) => usize::from(u16::from_be_bytes([l[0], l[1]])),
            None => return Err(truncated("a segment's length")),
        };
        if length < 2 {
            return Err(Damage::JpegSegmentLength { at: i - 2, length });
        }
        i += length;
        if i > b.len() {
            return Err(truncated("a marker segment"));
        }
        if marker == 0xda {
            i = scan_end(b, i).ok_or_else(|| truncated("the scan data"))?;
            scanned = true;
        }
    }
}

/// The offset of the first marker after the entropy-coded data starting at `from`, if the file has one.
fn scan_end(b: &[u8], mut from: usize) -> Option<usize> {
    loop {
        let at = from + b.get(from..)?.iter().position(|&x| x == 0xff)?;
        match *b.get(at + 1)? {
            0x00 | 0xd0..=0xd7 => from = at + 2,
            0xff => from = at + 1,
            _ => return Some(at),
        }
    }
}

/// Walks the chunks from the signature to `IEND`, checking each chunk's CRC.
fn png(b: &[u8]) -> Result<(), Damage> {
    let mut at = PNG_SIGNATURE.len();
    loop {
        let truncated = Damage::PngTruncated { len: b.len(), at };
        let header = b.get(at..at + 8).ok_or(truncated.clone())?;
        let length = u32::from_be_bytes(header[..4].try_into().expect("4 bytes")) as usize;
        let kind = &header[4..8];
        let body_end = (at + 8).checked_add(length).ok_or(truncated.clone())?;
        let typed = b.get(at + 4..body_end).ok_or(truncated.clone())?;
        let stored = b.get(body_end..body_end + 4).ok_or(truncated)?;
        if crc32fast::hash(typed).to_be_bytes() != stored {
            return Err(Damage::PngCrc {
                chunk: String::from_utf8_lossy(kind).into_owned(),
                at,
            });
        }
        if kind == b"IEND" {
            return Ok(());
        }
        at = body_end + 4;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal JPEG of hand-written segments: SOI, an APP0 of 4 bytes, SOS, scan data with an escaped
    /// `FF 00` and a restart marker, EOI.
    fn tiny_jpeg() -> Vec<u8> {
        let mut b = vec![0xff, 0xd8, 0xff, 0xe0, 0x00, 0x04, 0x4a, 0x46];
        b.extend([0xff, 0xda, 0x00, 0x03, 0x01]);
        b.extend([0x12, 0xff, 0x00, 0x34, 0xff, 0xd3, 0x56]);
        b.extend([0xff, 0xd9]);
        b
    }

    #[test]
    fn a_whole_jpeg_passes_and_every_cut_is_found() {
        let b = tiny_jpeg();
        assert_eq!(jpeg(&b), Ok(()));
        for cut in JPEG_SOI.len()..b.len() {
            assert!(
                matches!(jpeg(&b[..cut]), Err(Damage::JpegTruncated { len, .. }) if len == cut),
                "cut at {cut}: {:?}",
                jpeg(&b[..cut])
            );
        }
        // Trailing bytes after EOI are ignored, as decoders do.
        assert_eq!(jpeg(&[&b[..], b"trailer"].concat()), Ok(()));
        // SOI then EOI: no image.
        assert_eq!(jpeg(&[0xff, 0xd8, 0xff, 0xd9]), Err(Damage::JpegNoScan));
        let mut bad = b.clone();
        bad[8] = 0x00;
        assert_eq!(
            jpeg(&bad),
            Err(Damage::JpegNotAMarker { at: 8, byte: 0x00 })
        );
    }

    #[test]
    fn a_png_cut_anywhere_or_with_a_flipped_bit_is_found() {
        let mut b = Vec::new();
        image::GrayImage::from_fn(9, 7, |x, y| image::Luma([(x * y) as u8]))
            .write_to(&mut std::io::Cursor::new(&mut b), ImageFormat::Png)
            .unwrap();
        assert_eq!(png(&b), Ok(()));
        for cut in PNG_SIGNATURE.len()..b.len() {
            assert!(
                matches!(png(&b[..cut]), Err(Damage::PngTruncated { len, .. }) if len == cut),
                "cut at {cut}"
            );
        }
        let mut flipped = b.clone();
        let last_data = b.len() - 12 - 5; // inside IDAT, before its CRC and the IEND chunk
        flipped[last_data] ^= 0x10;
        assert!(
            matches!(png(&flipped), Err(Damage::PngCrc { ref chunk, .. }) if chunk == "IDAT"),
            "{:?}",
            png(&flipped)
        );
    }

    #[test]
    fn other_formats_are_unsupported_and_damage_names_the_format() {
        assert!(matches!(
            check(b"GIF89a......"),
            Err(ImageError::Unsupported(_))
        ));
        let cut = &tiny_jpeg()[..9];
        let err = check(cut).unwrap_err().to_string();
        assert!(err.contains("Jpeg") && err.contains("cut short"), "{err}");
    }
}
