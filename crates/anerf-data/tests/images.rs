//! Cut-short images and masks are refused by every reader, naming the file: the `image` decoders alone
//! decode a JPEG cut in half (the rest comes out grey) and a PNG that lacks its final chunk.

mod common;

use std::path::Path;

use anerf_data::formats::images;
use anerf_data::DataError;
use anerf_testing::fixture;
use common::cut_file;

type Reader = fn(&Path) -> Result<(), DataError>;

const READERS: [(&str, Reader); 5] = [
    ("decode", |p| images::decode(p).map(drop)),
    ("read_rgb", |p| images::read_rgb(p).map(drop)),
    ("read_gray", |p| images::read_gray(p).map(drop)),
    ("read_mask", |p| images::read_mask(p).map(drop)),
    ("whole_image_size", |p| {
        images::whole_image_size(p).map(drop)
    }),
];

#[test]
fn cut_jpegs_and_pngs_are_refused_by_every_reader() {
    let dir = tempfile::tempdir().unwrap();
    let jpeg = fixture("zju_mocap/CoreView_377/Camera_B1/000000.jpg");
    let png = fixture("zju_mocap/CoreView_377/mask_cihp/Camera_B1/000000.png");
    type Keep = fn(usize) -> usize;
    let cases: [(&str, &Path, Keep); 4] = [
        ("half.jpg", &jpeg, |n| n / 2),
        ("no_eoi.jpg", &jpeg, |n| n - 2),
        ("half.png", &png, |n| n / 2),
        ("no_iend.png", &png, |n| n - 12),
    ];
    for (name, source, keep) in cases {
        let path = dir.path().join(name);
        std::fs::copy(source, &path).unwrap();
        for (reader, read) in READERS {
            read(&path).unwrap_or_else(|e| panic!("{reader} refuses the whole {name}: {e}"));
        }
        cut_file(&path, keep);
        for (reader, read) in READERS {
            let err = read(&path).expect_err(&format!("{reader} accepted {name}"));
            let msg = err.to_string();
            assert!(
                err.path() == path && msg.contains(name) && msg.contains("cut short"),
                "{reader}, {name}: {msg}"
            );
        }
    }
}

#[test]
fn a_flipped_bit_in_a_png_and_a_file_of_another_kind_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("flipped.png");
    std::fs::copy(
        fixture("zju_mocap/CoreView_377/mask_cihp/Camera_B1/000000.png"),
        &path,
    )
    .unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let in_idat = bytes.len() - 12 - 6;
    bytes[in_idat] ^= 0x01;
    std::fs::write(&path, &bytes).unwrap();
    let msg = images::read_mask(&path).unwrap_err().to_string();
    assert!(msg.contains("flipped.png") && msg.contains("CRC"), "{msg}");
    let text = dir.path().join("notes.jpg");
    std::fs::write(&text, b"not an image").unwrap();
    let msg = images::whole_image_size(&text).unwrap_err().to_string();
    assert!(
        msg.contains("notes.jpg") && msg.contains("could not be determined"),
        "{msg}"
    );
}

/// An 8-bit PNG read as bytes gives, through `byte_channel`, the channels `read_rgb` gives, for every value:
/// the training cache keeps bytes and draws the same colours as a fresh read.
#[test]
fn bytes_read_back_as_the_float_readers_channels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ramp.png");
    let ramp = image::RgbImage::from_fn(256, 2, |x, y| {
        let v = x as u8;
        image::Rgb([v, v.wrapping_mul(7), if y == 0 { 255 - v } else { v / 3 }])
    });
    ramp.save(&path).unwrap();
    let (bytes, floats) = (
        images::read_rgb8(&path).unwrap(),
        images::read_rgb(&path).unwrap(),
    );
    assert_eq!(bytes, ramp);
    for (b, f) in bytes.as_raw().iter().zip(floats.as_raw()) {
        assert_eq!(images::byte_channel(*b).to_bits(), f.to_bits(), "{b}");
    }
}
