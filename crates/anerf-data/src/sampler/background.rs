//! The static background of each training camera, estimated from its own frames: a capture's cameras stand
//! still while the person moves, so every pixel shows the backdrop in most frames. Training against the
//! image composited over it ([`super::MaskEdges::Backdrop`]) lets the colours say where the body ends,
//! instead of the masks, which are least sure exactly there.

use std::collections::HashMap;

use anerf_core::{FrameId, ViewId};
use image::{GrayImage, Rgb32FImage};
use rayon::prelude::*;

use crate::error::DataError;
use crate::prepare::PreparedSubject;

/// At most this many of the training frames, evenly spaced, are read per camera.
const MAX_FRAMES: usize = 64;
/// A pixel's background is known where at least this many of the frames read leave it uncovered (the
/// median then outvotes a frame whose mask misses a part of the body there).
const MIN_FRAMES: usize = 3;
/// Each mask is dilated by this many pixels (or 0.75 % of the image's larger side, if more) before its
/// uncovered pixels count: a mask's edge is off by a few pixels, and an edge pixel mixes body and backdrop.
const MARGIN_PX: u32 = 4;
/// A pixel's background is known only where its colours over those frames stay this close to their median
/// (the median absolute deviation, per channel, colours in `[0, 1]`): a backdrop that changes in most
/// frames (a screen, people passing, a camera that moved) is no background to composite over. A camera's
/// noise and JPEG's stay far under it.
const MAX_SPREAD: f32 = 0.1;
/// Hidden pixels within this many margins of a known one take its colour ([`BackgroundPlate::filled`]): a
/// subject that stays in place hides the pixels next to its body in nearly every frame, a third of the
/// band around its silhouette on the demo subject, and the backdrop there is mostly the backdrop beside it.
const FILL_MARGINS: u32 = 2;

/// One camera's background at the working resolution: per pixel the median colour (channels in
/// `[0, 1]`) over the frames whose dilated mask leaves it uncovered, or unknown where too few do or their
/// colours spread too far.
#[derive(Debug, Clone, PartialEq)]
pub struct BackgroundPlate {
    pub width: u32,
    pub height: u32,
    /// Row-major colours; black where unknown.
    colours: Vec<[f32; 3]>,
    seen: Vec<Seen>,
}

/// What the frames show of one pixel's background.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    /// One colour: the median over the frames that leave it uncovered.
    Known,
    /// Too few frames leave it uncovered: the body stays in front of it.
    Hidden,
    /// Enough frames leave it uncovered, but their colours spread: a screen, people passing, a camera
    /// that moved. No neighbour tells its colour.
    Changing,
}

impl BackgroundPlate {
    /// The median of each pixel's colours over the frames whose mask, dilated by `margin` pixels, leaves
    /// it uncovered; known where at least `min_frames` frames do and, in every channel, the median absolute
    /// deviation of those colours from it is at most `max_spread`. `images` and `masks`: one per frame, at
    /// least one, all of one size.
    pub fn estimate(
        images: &[Rgb32FImage],
        masks: &[GrayImage],
        margin: u32,
        min_frames: usize,
        max_spread: f32,
    ) -> Self {
        assert!(!images.is_empty(), "a background needs at least one frame");
        let (width, height) = images[0].dimensions();
        assert!(
            images.len() == masks.len()
                && images.iter().all(|i| i.dimensions() == (width, height))
                && masks.iter().all(|m| m.dimensions() == (width, height)),
            "a background's images and masks are one per frame, all {width}×{height}"
        );
        let uncovered: Vec<Vec<bool>> = masks
            .par_iter()
            .map(|m| dilate(m, margin).into_iter().map(|b| !b).collect())
            .collect();
        let n = (width * height) as usize;
        let (colours, seen) = (0..n)
            .into_par_iter()
            .map_init(Vec::new, |values: &mut Vec<[f32; 3]>, i| {
                values.clear();
                for (image, free) in images.iter().zip(&uncovered) {
                    if free[i] {
                        let p = &image.as_raw()[3 * i..3 * i + 3];
                        values.push([p[0], p[1], p[2]]);
                    }
                }
                if values.len() < min_frames.max(1) {
                    return ([0.0; 3], Seen::Hidden);
                }
                let mid = values.len() / 2;
                let mut median = [0.0; 3];
                let mut still = true;
                for (c, m) in median.iter_mut().enumerate() {
                    let mut channel: Vec<f32> = values.iter().map(|v| v[c]).collect();
                    *m = *channel.select_nth_unstable_by(mid, f32::total_cmp).1;
                    channel.iter_mut().for_each(|v| *v = (*v - *m).abs());
                    still &= *channel.select_nth_unstable_by(mid, f32::total_cmp).1 <= max_spread;
                }
                if still {
                    (median, Seen::Known)
                } else {
                    ([0.0; 3], Seen::Changing)
                }
            })
            .unzip();
        Self {
            width,
            height,
            colours,
            seen,
        }
    }

    /// The plate with each hidden pixel (too few frames leave it uncovered) within `radius` pixels
    /// (Euclidean) of a known one given the colour of the nearest (the first in row-major order of the
    /// offsets among equally near ones), and counted as known; the rest stays unknown. Only pixels known
    /// before the fill are copied from, and a changing pixel stays unknown: its neighbours do not tell
    /// its colour.
    pub fn filled(self, radius: u32) -> Self {
        let r = radius as i64;
        let mut offsets: Vec<(i64, i64)> = (-r..=r)
            .flat_map(|dy| (-r..=r).map(move |dx| (dy, dx)))
            .filter(|&(dy, dx)| dy * dy + dx * dx <= r * r)
            .collect();
        offsets.sort_by_key(|&(dy, dx)| dy * dy + dx * dx);
        let (w, h) = (self.width as i64, self.height as i64);
        let (colours, seen) = (0..self.seen.len())
            .into_par_iter()
            .map(|i| {
                if self.seen[i] != Seen::Hidden {
                    return (self.colours[i], self.seen[i]);
                }
                let (x, y) = (i as i64 % w, i as i64 / w);
                offsets
                    .iter()
                    .map(|&(dy, dx)| (x + dx, y + dy))
                    .filter(|&(u, v)| (0..w).contains(&u) && (0..h).contains(&v))
                    .map(|(u, v)| (v * w + u) as usize)
                    .find(|&j| self.seen[j] == Seen::Known)
                    .map_or(([0.0; 3], Seen::Hidden), |j| (self.colours[j], Seen::Known))
            })
            .unzip();
        Self {
            colours,
            seen,
            ..self
        }
    }

    /// The background of pixel `i` (row-major), where known.
    pub fn at(&self, i: usize) -> Option<[f32; 3]> {
        (self.seen[i] == Seen::Known).then(|| self.colours[i])
    }

    /// The share of the pixels whose background is known.
    pub fn known_share(&self) -> f32 {
        let known = self.seen.iter().filter(|&&s| s == Seen::Known).count();
        known as f32 / self.seen.len().max(1) as f32
    }
}

/// The estimated backgrounds of a run's training cameras.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Backgrounds {
    plates: HashMap<ViewId, BackgroundPlate>,
}

impl Backgrounds {
    /// Estimates each of `views`' backgrounds from at most [`MAX_FRAMES`] of `frames` (evenly spaced) of
    /// `subject`, as [`BackgroundPlate::estimate`] does, then fills the unknown pixels near known ones
    /// ([`BackgroundPlate::filled`]).
    pub fn estimate(
        subject: &PreparedSubject,
        frames: &[FrameId],
        views: &[ViewId],
    ) -> Result<Self, DataError> {
        let step = frames.len().div_ceil(MAX_FRAMES).max(1);
        let used: Vec<FrameId> = frames.iter().copied().step_by(step).collect();
        let mut plates = HashMap::new();
        for &view in views {
            let read: Vec<(Rgb32FImage, GrayImage)> = used
                .par_iter()
                .map(|&f| Ok((subject.image(f, view)?, subject.mask(f, view)?)))
                .collect::<Result<_, DataError>>()?;
            let (images, masks): (Vec<_>, Vec<_>) = read.into_iter().unzip();
            let Some(first) = images.first() else {
                continue;
            };
            let margin = MARGIN_PX.max(first.width().max(first.height()) * 3 / 400);
            let plate = BackgroundPlate::estimate(&images, &masks, margin, MIN_FRAMES, MAX_SPREAD);
            plates.insert(view, plate.filled(FILL_MARGINS * margin));
        }
        Ok(Self { plates })
    }

    /// Backgrounds made elsewhere, one per camera.
    pub fn new(plates: impl IntoIterator<Item = (ViewId, BackgroundPlate)>) -> Self {
        Self {
            plates: plates.into_iter().collect(),
        }
    }

    /// Camera `view`'s background, if estimated.
    pub fn plate(&self, view: ViewId) -> Option<&BackgroundPlate> {
        self.plates.get(&view)
    }

    /// The cameras whose background is known at fewer than `min_share` of their pixels, with that share,
    /// in camera order: a backdrop that changes between frames, or cameras that moved.
    pub fn sparse(&self, min_share: f32) -> Vec<(ViewId, f32)> {
        let mut sparse: Vec<(ViewId, f32)> = self
            .plates
            .iter()
            .map(|(&view, plate)| (view, plate.known_share()))
            .filter(|&(_, share)| share < min_share)
            .collect();
        sparse.sort_by_key(|&(view, _)| view);
        sparse
    }
}

/// `mask` (non-zero = set) dilated by a square of half-side `r` pixels, row-major: a running maximum
/// along the rows, then along the columns.
fn dilate(mask: &GrayImage, r: u32) -> Vec<bool> {
    let (w, h) = (mask.width() as usize, mask.height() as usize);
    let r = r as usize;
    let set: Vec<bool> = mask.as_raw().iter().map(|&v| v != 0).collect();
    let spread = |line: &[bool]| -> Vec<bool> {
        // The distance to the nearest set pixel on the left and on the right, in one pass each way.
        let n = line.len();
        let mut out = vec![false; n];
        let mut last = None;
        for (i, &s) in line.iter().enumerate() {
            if s {
                last = Some(i);
            }
            out[i] = last.is_some_and(|l| i - l <= r);
        }
        last = None;
        for i in (0..n).rev() {
            if line[i] {
                last = Some(i);
            }
            out[i] |= last.is_some_and(|l| l - i <= r);
        }
        out
    };
    let rows: Vec<bool> = set.chunks(w).flat_map(spread).collect();
    let mut out = vec![false; w * h];
    for x in 0..w {
        let column: Vec<bool> = (0..h).map(|y| rows[y * w + x]).collect();
        for (y, v) in spread(&column).into_iter().enumerate() {
            out[y * w + x] = v;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_is_the_square_neighbourhood_by_brute_force() {
        let (w, h) = (23u32, 17u32);
        let mask = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([u8::from((x * 7 + y * 13) % 29 == 0 || (x == 0 && y == 16))])
        });
        for r in [0, 1, 2, 5] {
            let got = dilate(&mask, r);
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    let r = r as i64;
                    let want = (-r..=r).any(|dy| {
                        (-r..=r).any(|dx| {
                            let (u, v) = (x + dx, y + dy);
                            (0..w as i64).contains(&u)
                                && (0..h as i64).contains(&v)
                                && mask.get_pixel(u as u32, v as u32)[0] != 0
                        })
                    });
                    assert_eq!(got[(y * w as i64 + x) as usize], want, "r {r} at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn the_plate_is_each_pixels_median_over_the_frames_that_leave_it_uncovered() {
        // A 6 × 1 strip over 5 frames: a "body" (mask 1, colour 0.9) moves along it over a backdrop
        // whose pixel x has colour x / 10 with a little per-frame noise.
        let (w, frames) = (6u32, 5usize);
        let noise = [0.0, 0.01, -0.01, 0.02, -0.02];
        let body_at = [0usize, 1, 2, 3, 5];
        let images: Vec<Rgb32FImage> = (0..frames)
            .map(|f| {
                Rgb32FImage::from_fn(w, 1, |x, _| {
                    let v = if x as usize == body_at[f] {
                        0.9
                    } else {
                        x as f32 / 10.0 + noise[f]
                    };
                    image::Rgb([v, v, v])
                })
            })
            .collect();
        let masks: Vec<GrayImage> = (0..frames)
            .map(|f| {
                GrayImage::from_fn(w, 1, |x, _| {
                    image::Luma([u8::from(x as usize == body_at[f])])
                })
            })
            .collect();
        // Without a margin: each pixel is covered in one frame at most, so four or five values remain.
        let plate = BackgroundPlate::estimate(&images, &masks, 0, 3, 1.0);
        for x in 0..w as usize {
            let mut values: Vec<f32> = (0..frames)
                .filter(|&f| body_at[f] != x)
                .map(|f| x as f32 / 10.0 + noise[f])
                .collect();
            values.sort_by(f32::total_cmp);
            let want = values[values.len() / 2];
            assert_eq!(plate.at(x), Some([want; 3]), "pixel {x}");
        }
        // With a margin of 1, pixels 1 and 2 are left uncovered by two frames only (3, 4 and 0, 4), the
        // others by three or four.
        let plate = BackgroundPlate::estimate(&images, &masks, 1, 3, 1.0);
        assert_eq!((plate.at(1), plate.at(2)), (None, None));
        // Pixel 4 from frames 0, 1, 2: 0.4, 0.41 and 0.39, whose median is frame 0's.
        assert_eq!(plate.at(4), Some([4.0 / 10.0 + noise[0]; 3]));
        assert!(
            (plate.known_share() - 4.0 / 6.0).abs() < 1e-6,
            "{}",
            plate.known_share()
        );
    }

    #[test]
    fn a_backdrop_that_changes_in_most_frames_is_not_known_one_that_changes_in_a_few_is() {
        // Two pixels, never covered, over 5 frames: the first changes in every frame (median 0.5, absolute
        // deviations 0.4, 0, 0.4, 0.2, 0.2: their median 0.2); the second is 0.5 but for two frames
        // (deviations 0, 0, 0.4, 0, 0.4: median 0).
        let values = [[0.1, 0.5], [0.5, 0.5], [0.9, 0.9], [0.3, 0.5], [0.7, 0.1]];
        let images: Vec<Rgb32FImage> = values
            .iter()
            .map(|v| Rgb32FImage::from_fn(2, 1, |x, _| image::Rgb([v[x as usize]; 3])))
            .collect();
        let masks = vec![GrayImage::new(2, 1); values.len()];
        let plate = BackgroundPlate::estimate(&images, &masks, 0, 3, 0.1);
        assert_eq!((plate.at(0), plate.at(1)), (None, Some([0.5; 3])));
        // Filling leaves the changing pixel unknown although its neighbour is known.
        assert_eq!(plate.clone().filled(1).at(0), None);
        let plate = BackgroundPlate::estimate(&images, &masks, 0, 3, 0.2);
        assert_eq!((plate.at(0), plate.at(1)), (Some([0.5; 3]), Some([0.5; 3])));
    }

    #[test]
    fn sparse_lists_the_cameras_whose_background_is_mostly_unknown() {
        // Camera v's 1 × 4 plate is known at v of its 4 pixels.
        let plate = |known: usize| BackgroundPlate {
            width: 4,
            height: 1,
            colours: vec![[0.5; 3]; 4],
            seen: (0..4)
                .map(|i| if i < known { Seen::Known } else { Seen::Hidden })
                .collect(),
        };
        let backgrounds = Backgrounds::new((0..=4).rev().map(|v| (ViewId(v), plate(v))));
        assert_eq!(
            backgrounds.sparse(0.5),
            vec![(ViewId(0), 0.0), (ViewId(1), 0.25)]
        );
        assert_eq!(backgrounds.sparse(0.0), vec![]);
    }

    #[test]
    fn filling_copies_the_nearest_known_pixel_within_the_radius_by_brute_force() {
        // A 19 × 13 plate, known on a scattered pattern, every known pixel with its own colour; of the
        // others, every fifth changes (its frames disagreed) and the rest are hidden.
        let (w, h) = (19u32, 13u32);
        let known = |i: u32| (i * 11 + i / 7) % 13 == 0;
        let seen: Vec<Seen> = (0..w * h)
            .map(|i| match (known(i), i % 5 == 0) {
                (true, _) => Seen::Known,
                (false, true) => Seen::Changing,
                (false, false) => Seen::Hidden,
            })
            .collect();
        let colours: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                if known(i) {
                    [i as f32, 0.5, 1.0]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let plate = BackgroundPlate {
            width: w,
            height: h,
            colours,
            seen,
        };
        for r in [0u32, 1, 2, 4] {
            let filled = plate.clone().filled(r);
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    let i = (y * w as i64 + x) as usize;
                    // The nearest originally known pixel: least squared distance, then least (dy, dx);
                    // none for a changing pixel.
                    let want = (0..h as i64)
                        .flat_map(|v| (0..w as i64).map(move |u| (v, u)))
                        .filter(|&(v, u)| known((v * w as i64 + u) as u32))
                        .map(|(v, u)| ((v - y).pow(2) + (u - x).pow(2), v - y, u - x, v, u))
                        .filter(|&(d2, ..)| d2 <= (r * r) as i64)
                        .min()
                        .map(|(.., v, u)| plate.colours[(v * w as i64 + u) as usize])
                        .filter(|_| plate.seen[i] != Seen::Changing);
                    assert_eq!(filled.at(i), want, "radius {r} at {x},{y}");
                }
            }
        }
        assert!(plate.clone().filled(4).known_share() > plate.known_share());
    }
}
