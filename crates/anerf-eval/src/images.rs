//! Image files: reading images and masks, atomic PNG writing, side-by-side composites with an error heat
//! map, animated GIFs, and MP4 through ffmpeg when it is installed.

use std::path::{Path, PathBuf};
use std::process::Command;

use anerf_data::DataError;
use image::codecs::gif::{GifEncoder, Repeat};
use image::codecs::png::PngEncoder;
use image::{Delay, DynamicImage, Frame, ImageBuffer, Luma, Rgb32FImage, RgbaImage};

use crate::error::{EvalError, MetricError};
use crate::pixels::{ensure_same_size, ImageSize, PixelMask, RgbImageExt};
use anerf_data::atomic::{temp_dir_beside, write_with};

/// Reads an RGB image; 8-bit values become `v / 255` and 16-bit values `v / 65535` (in f32), any alpha
/// channel is ignored.
pub fn read_rgb(path: &Path) -> Result<Rgb32FImage, EvalError> {
    let image = decode(path, "an RGB image")?.into_rgb32f();
    image.check_finite().map_err(|source| EvalError::Metric {
        context: path.display().to_string(),
        source,
    })?;
    Ok(image)
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

/// Decodes through the data layer's one checked reader, so a cut-short or damaged file is refused here too.
fn decode(path: &Path, expected: &'static str) -> Result<DynamicImage, EvalError> {
    anerf_data::formats::images::decode(path).map_err(|e| match e {
        DataError::Missing { path, .. } => EvalError::MissingFile { path, expected },
        DataError::Image { path, source } => EvalError::UnreadableImage { path, source },
        DataError::Io { path, source } => EvalError::Io { path, source },
        other => EvalError::Format {
            path: other.path().to_path_buf(),
            detail: other.to_string(),
        },
    })
}

/// Bits per channel of a written PNG.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PngDepth {
    /// For viewing: composites, video frames.
    Eight,
    /// For re-measuring: quantisation steps of 1/65535, and 8-bit sources round-trip exactly.
    Sixteen,
}

impl PngDepth {
    fn max(self) -> f32 {
        match self {
            PngDepth::Eight => 255.0,
            PngDepth::Sixteen => 65535.0,
        }
    }
}

/// Values clamped to [0, 1] and rounded to the nearest level of `depth`.
fn quantise(v: f32, depth: PngDepth) -> u16 {
    (v.clamp(0.0, 1.0) * depth.max()).round() as u16
}

/// `image` exactly as [`read_rgb`] returns it after [`write_png`] at `depth`.
pub fn quantised(image: &Rgb32FImage, depth: PngDepth) -> Rgb32FImage {
    let mut out = image.clone();
    for v in out.iter_mut() {
        *v = f32::from(quantise(*v, depth)) / depth.max();
    }
    out
}

/// Writes `image` as an RGB PNG atomically; values are clamped to [0, 1].
pub fn write_png(path: &Path, image: &Rgb32FImage, depth: PngDepth) -> Result<(), EvalError> {
    let (w, h) = (image.width(), image.height());
    let values = image.iter().map(|&v| quantise(v, depth));
    let dynamic = match depth {
        PngDepth::Eight => {
            DynamicImage::ImageRgb8(raw_buffer(w, h, values.map(|v| v as u8).collect()))
        }
        PngDepth::Sixteen => DynamicImage::ImageRgb16(raw_buffer(w, h, values.collect())),
    };
    write_dynamic_png(path, &dynamic)
}

/// Writes `mask` as an 8-bit greyscale PNG (0 outside, 255 inside) atomically.
pub fn write_mask_png(path: &Path, mask: &PixelMask) -> Result<(), EvalError> {
    let size = mask.size();
    let pixels = mask
        .bits()
        .iter()
        .map(|&b| if b { 255 } else { 0 })
        .collect();
    let buffer: ImageBuffer<Luma<u8>, Vec<u8>> = raw_buffer(size.width, size.height, pixels);
    write_dynamic_png(path, &DynamicImage::ImageLuma8(buffer))
}

fn raw_buffer<P: image::Pixel>(
    w: u32,
    h: u32,
    data: Vec<P::Subpixel>,
) -> ImageBuffer<P, Vec<P::Subpixel>> {
    ImageBuffer::from_raw(w, h, data).expect("buffer length matches the image size")
}

fn write_dynamic_png(path: &Path, image: &DynamicImage) -> Result<(), EvalError> {
    write_with(path, |w| {
        image
            .write_with_encoder(PngEncoder::new(w))
            .map_err(|source| EvalError::Encode {
                path: path.to_path_buf(),
                source,
            })
    })
}

/// Per-pixel error as a "hot" colour ramp (black → red → yellow → white): the mean absolute error over the
/// three channels divided by `full_scale` (clamped to 1) is `t`, and the colour is
/// (3t, 3t − 1, 3t − 2) clamped to [0, 1].
pub fn error_heat_map(
    pred: &Rgb32FImage,
    gt: &Rgb32FImage,
    full_scale: f32,
) -> Result<Rgb32FImage, MetricError> {
    ensure_same_size(pred.size(), gt.size())?;
    assert!(
        full_scale > 0.0,
        "heat-map full scale must be positive, got {full_scale}"
    );
    let data = pred
        .as_raw()
        .chunks_exact(3)
        .zip(gt.as_raw().chunks_exact(3))
        .flat_map(|(p, g)| {
            let error = p.iter().zip(g).map(|(a, b)| (a - b).abs()).sum::<f32>() / 3.0;
            let t = (error / full_scale).min(1.0);
            [0.0, 1.0, 2.0].map(|k| (3.0 * t - k).clamp(0.0, 1.0))
        })
        .collect();
    Rgb32FImage::from_values(pred.size(), data)
}

/// Mean absolute error that saturates the heat map of [`side_by_side`].
pub const HEAT_MAP_FULL_SCALE: f32 = 0.5;

/// The evaluation composite: prediction | ground truth | error heat map (see [`error_heat_map`]).
pub fn side_by_side(pred: &Rgb32FImage, gt: &Rgb32FImage) -> Result<Rgb32FImage, MetricError> {
    let heat = error_heat_map(pred, gt, HEAT_MAP_FULL_SCALE)?;
    let size = ImageSize::new(pred.width() * 3, pred.height());
    let row_len = pred.width() as usize * 3;
    let mut data = Vec::with_capacity(size.pixels() * 3);
    for y in 0..pred.height() as usize {
        for part in [pred, gt, &heat] {
            data.extend_from_slice(&part.as_raw()[y * row_len..(y + 1) * row_len]);
        }
    }
    Rgb32FImage::from_values(size, data)
}

/// Frames of an animation: all the same size, at least one, shown at `fps` frames per second.
fn check_frames(frames: &[Rgb32FImage], fps: u32) -> Result<ImageSize, EvalError> {
    let first = frames.first().ok_or(EvalError::InvalidInput {
        what: "frame sequence",
        detail: "it is empty; expected at least one frame".into(),
    })?;
    if let Some((i, frame)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.size() != first.size())
    {
        return Err(EvalError::InvalidInput {
            what: "frame sequence",
            detail: format!(
                "frame {i} is {} but frame 0 is {}; expected one size",
                frame.size(),
                first.size()
            ),
        });
    }
    if fps == 0 {
        return Err(EvalError::InvalidInput {
            what: "frame rate",
            detail: "0 fps; expected at least 1".into(),
        });
    }
    Ok(first.size())
}

fn to_rgba8(image: &Rgb32FImage) -> RgbaImage {
    let pixels = image
        .as_raw()
        .chunks_exact(3)
        .flat_map(|rgb| {
            [rgb[0], rgb[1], rgb[2]]
                .map(|v| quantise(v, PngDepth::Eight) as u8)
                .into_iter()
                .chain([255])
        })
        .collect();
    raw_buffer(image.width(), image.height(), pixels)
}

/// Writes `frames` as a looping animated GIF at `fps` frames per second (GIF delays are in 1/100 s, so the
/// rate is rounded to the nearest whole delay), atomically.
pub fn write_gif(path: &Path, frames: &[Rgb32FImage], fps: u32) -> Result<(), EvalError> {
    check_frames(frames, fps)?;
    let encode_error = |source| EvalError::Encode {
        path: path.to_path_buf(),
        source,
    };
    write_with(path, |w| {
        let mut encoder = GifEncoder::new_with_speed(w, 10);
        encoder.set_repeat(Repeat::Infinite).map_err(encode_error)?;
        let delay = Delay::from_numer_denom_ms(1000, fps);
        encoder
            .encode_frames(
                frames
                    .iter()
                    .map(|f| Frame::from_parts(to_rgba8(f), 0, 0, delay)),
            )
            .map_err(encode_error)
    })
}

/// What [`write_mp4`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum VideoOutcome {
    Written(PathBuf),
    /// ffmpeg is not on PATH; nothing was written.
    SkippedNoFfmpeg,
}

/// Writes `frames` as an H.264 MP4 at `fps` when ffmpeg is on PATH; otherwise prints a note and skips.
pub fn write_mp4(path: &Path, frames: &[Rgb32FImage], fps: u32) -> Result<VideoOutcome, EvalError> {
    match find_program("ffmpeg") {
        Some(ffmpeg) => write_mp4_with(&ffmpeg, path, frames, fps),
        None => {
            eprintln!(
                "note: ffmpeg is not on PATH; skipping the video {}",
                path.display()
            );
            Ok(VideoOutcome::SkippedNoFfmpeg)
        }
    }
}

/// The first executable file called `name` in the folders of PATH.
pub fn find_program(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join(name))
        .find(|candidate| is_executable(candidate))
}

fn is_executable(path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        path.metadata()
            .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
    }
    #[cfg(not(unix))]
    {
        path.is_file()
    }
}

/// Writes the frames as 8-bit PNGs into a temporary folder beside `path`, encodes them with `ffmpeg` into
/// a temporary file there and renames it to `path` on success.
pub fn write_mp4_with(
    ffmpeg: &Path,
    path: &Path,
    frames: &[Rgb32FImage],
    fps: u32,
) -> Result<VideoOutcome, EvalError> {
    check_frames(frames, fps)?;
    let io_error = |source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    };
    let work = temp_dir_beside(path)?;
    for (i, frame) in frames.iter().enumerate() {
        write_png(
            &work.path().join(format!("frame_{i:05}.png")),
            frame,
            PngDepth::Eight,
        )?;
    }
    let encoded = work.path().join("video.mp4");
    let output = Command::new(ffmpeg)
        .args([
            "-y",
            "-loglevel",
            "error",
            "-framerate",
            &fps.to_string(),
            "-i",
        ])
        .arg(work.path().join("frame_%05d.png"))
        // H.264 with 4:2:0 chroma needs even sides; pad odd ones with a black line.
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-c:v",
            "libx264",
            "-pix_fmt",
            "yuv420p",
        ])
        .arg(&encoded)
        .output()
        .map_err(|source| EvalError::Io {
            path: ffmpeg.to_path_buf(),
            source,
        })?;
    if !output.status.success() || !encoded.is_file() {
        return Err(EvalError::Ffmpeg {
            path: path.to_path_buf(),
            status: output.status.to_string(),
            stderr: String::from_utf8_lossy(&output.stderr).trim().to_string(),
        });
    }
    std::fs::rename(&encoded, path).map_err(io_error)?;
    Ok(VideoOutcome::Written(path.to_path_buf()))
}

#[cfg(test)]
mod tests {
    use image::AnimationDecoder;

    use super::*;

    fn pattern(size: ImageSize, seed: u32) -> Rgb32FImage {
        let data = (0..size.pixels() as u32 * 3)
            .map(|i| ((i * 7919 + seed * 104729) % 1000) as f32 / 999.0)
            .collect();
        Rgb32FImage::from_values(size, data).unwrap()
    }

    fn solid(size: ImageSize, rgb: [f32; 3]) -> Rgb32FImage {
        Rgb32FImage::from_values(size, rgb.repeat(size.pixels())).unwrap()
    }

    #[test]
    fn png_round_trips_at_both_depths() {
        let dir = tempfile::tempdir().unwrap();
        let mut image = pattern(ImageSize::new(13, 7), 1);
        image.set_pixel(0, 0, [-0.5, 1.5, 0.5]); // out of range: clamped on writing
        for depth in [PngDepth::Eight, PngDepth::Sixteen] {
            let path = dir.path().join(format!("{depth:?}.png"));
            write_png(&path, &image, depth).unwrap();
            let back = read_rgb(&path).unwrap();
            assert_eq!(back, quantised(&image, depth), "{depth:?}");
            assert_eq!(back.pixel(0, 0)[..2], [0.0, 1.0]);
        }
        // Values that came from 8 bits (v / 255 in f32) survive a 16-bit PNG bit for bit.
        let eight_bit = quantised(&image, PngDepth::Eight);
        let path = dir.path().join("eight_in_sixteen.png");
        write_png(&path, &eight_bit, PngDepth::Sixteen).unwrap();
        assert_eq!(read_rgb(&path).unwrap(), eight_bit);

        let mask = PixelMask::from_fn(image.size(), |x, y| (x + y) % 3 == 0);
        let mask_path = dir.path().join("mask.png");
        write_mask_png(&mask_path, &mask).unwrap();
        assert_eq!(read_mask(&mask_path).unwrap(), mask);
    }

    #[test]
    fn heat_map_follows_the_hot_ramp() {
        let size = ImageSize::new(4, 1);
        let gt = solid(size, [0.2, 0.4, 0.6]);
        let mut pred = gt.clone();
        // Mean absolute errors 0, 0.25, 0.5, 1.0 against a full scale of 0.5: t = 0, 1/2, 1, 1.
        pred.set_pixel(1, 0, [0.45, 0.65, 0.85]);
        pred.set_pixel(2, 0, [0.7, 0.9, 0.1]);
        pred.set_pixel(3, 0, [1.0, 1.0, 1.0]);
        let heat = error_heat_map(&pred, &gt, 0.5).unwrap();
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
        assert!(close(heat.pixel(0, 0), [0.0, 0.0, 0.0]));
        assert!(
            close(heat.pixel(1, 0), [1.0, 0.5, 0.0]),
            "{:?}",
            heat.pixel(1, 0)
        );
        assert!(close(heat.pixel(2, 0), [1.0, 1.0, 1.0]));
        assert!(close(heat.pixel(3, 0), [1.0, 1.0, 1.0]));
    }

    #[test]
    fn side_by_side_places_prediction_truth_and_error() {
        let size = ImageSize::new(5, 3);
        let (pred, gt) = (pattern(size, 2), pattern(size, 3));
        let composite = side_by_side(&pred, &gt).unwrap();
        let heat = error_heat_map(&pred, &gt, HEAT_MAP_FULL_SCALE).unwrap();
        assert_eq!(composite.size(), ImageSize::new(15, 3));
        for (x, y) in [(0, 0), (4, 2), (2, 1)] {
            assert_eq!(composite.pixel(x, y), pred.pixel(x, y));
            assert_eq!(composite.pixel(x + 5, y), gt.pixel(x, y));
            assert_eq!(composite.pixel(x + 10, y), heat.pixel(x, y));
        }
        assert!(side_by_side(&pred, &pattern(ImageSize::new(5, 4), 0)).is_err());
    }

    #[test]
    fn gif_holds_every_frame_with_its_colour_and_delay() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("clip.gif");
        let size = ImageSize::new(8, 6);
        let colours = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let frames: Vec<_> = colours.iter().map(|&c| solid(size, c)).collect();
        write_gif(&path, &frames, 10).unwrap();
        let file = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
        let decoded = image::codecs::gif::GifDecoder::new(file)
            .unwrap()
            .into_frames()
            .collect_frames()
            .unwrap();
        assert_eq!(decoded.len(), 3);
        for (frame, colour) in decoded.iter().zip(colours) {
            assert_eq!(frame.buffer().dimensions(), (8, 6));
            assert_eq!(frame.delay().numer_denom_ms(), (100, 1));
            let expected = colour.map(|v| (v * 255.0) as i32);
            for pixel in frame.buffer().pixels() {
                assert!(
                    pixel
                        .0
                        .iter()
                        .zip(expected)
                        .all(|(&a, b)| (i32::from(a) - b).abs() <= 4),
                    "{pixel:?}"
                );
            }
        }
        let mismatched = [solid(size, [0.0; 3]), solid(ImageSize::new(6, 8), [0.0; 3])];
        assert!(matches!(
            write_gif(&dir.path().join("bad.gif"), &mismatched, 10),
            Err(EvalError::InvalidInput { .. })
        ));
        assert!(write_gif(&dir.path().join("empty.gif"), &[], 10).is_err());
        assert!(!dir.path().join("bad.gif").exists());
    }

    #[test]
    fn program_lookup_finds_executables_only() {
        assert!(find_program("anerf-no-such-program-on-any-path").is_none());
        #[cfg(unix)]
        assert!(
            find_program("sh").is_some(),
            "sh is on PATH on every unix system"
        );
    }

    /// A stand-in for ffmpeg that records its arguments into the output file (its last argument), or fails.
    #[cfg(unix)]
    fn fake_ffmpeg(dir: &Path, succeed: bool) -> PathBuf {
        use std::os::unix::fs::PermissionsExt;
        let path = dir.join(if succeed { "ffmpeg-ok" } else { "ffmpeg-fails" });
        let body = if succeed {
            "#!/bin/sh\nfor last; do :; done\nls \"$(dirname \"$last\")\" > \"$last\"\necho \"$@\" >> \"$last\"\n"
        } else {
            "#!/bin/sh\necho 'Unknown encoder libx264' >&2\nexit 1\n"
        };
        std::fs::write(&path, body).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
        path
    }

    #[cfg(unix)]
    #[test]
    fn mp4_goes_through_ffmpeg_and_leaves_nothing_behind_on_failure() {
        let tools = tempfile::tempdir().unwrap();
        let out = tempfile::tempdir().unwrap();
        let frames: Vec<_> = (0..3).map(|i| pattern(ImageSize::new(5, 3), i)).collect();
        let path = out.path().join("orbit.mp4");
        let outcome = write_mp4_with(&fake_ffmpeg(tools.path(), true), &path, &frames, 24).unwrap();
        assert_eq!(outcome, VideoOutcome::Written(path.clone()));
        let log = std::fs::read_to_string(&path).unwrap();
        for expected in [
            "frame_00000.png",
            "frame_00002.png",
            "-framerate 24",
            "libx264",
            "yuv420p",
        ] {
            assert!(
                log.contains(expected),
                "{expected} missing from the ffmpeg call: {log}"
            );
        }
        assert_eq!(
            std::fs::read_dir(out.path()).unwrap().count(),
            1,
            "the frame folder must be removed"
        );

        let failed = out.path().join("failed.mp4");
        let err =
            write_mp4_with(&fake_ffmpeg(tools.path(), false), &failed, &frames, 24).unwrap_err();
        assert!(
            err.to_string().contains("Unknown encoder") && err.to_string().contains("failed.mp4"),
            "{err}"
        );
        assert!(!failed.exists());
        assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 1);
    }
}
