//! Training rays (docs/REFERENCE.md §3.3) and evaluation rays (§4.2) of one image.
//!
//! Pixels are addressed by integer coordinates (column `u`, row `v`), and rays go through them in the
//! camera's [`PixelConvention`] (the reference: integer positions, no +0.5). Boxes are world space, metres.

use std::sync::Arc;

use anerf_core::geometry::{Aabb, Camera, PixelConvention};
use anerf_core::render::HostRays;
use anerf_core::{FrameId, ViewId};
use glam::Vec2;
use image::{GrayImage, Rgb32FImage, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::error::DataError;
use crate::formats::images::byte_channel;
use crate::prepare::{edge_band, PreparedSubject};

mod background;
mod cache;
mod detail;
mod prefetch;

pub use background::{BackgroundPlate, Backgrounds};
pub use cache::ImageCache;
use detail::DetailPool;
pub use prefetch::{draw_step, DrawError, DrawnStep, Prefetch, StepPlan};

/// What training draws from the band `dilate(mask) − erode(mask)` of a 5×5 kernel around the mask's edge
/// (the reference's `erode_edge`), marked on the full-resolution mask by `prepare` ([`ImageView::edge`]):
/// the pixels a real capture's mask is most often wrong about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaskEdges {
    /// Drawn like every pixel, with the mask's colour and label: for exact masks (synthetic subjects).
    Train,
    /// Drawn like every pixel and marked ([`HostRays::edge`]), so that training weighs them with a robust
    /// loss: where the mask is right the edge is trained almost as with `Train`, where it is wrong its
    /// pull is bounded and the rest of the data decides.
    Robust,
    /// Never drawn (the reference): the mask's errors are not learned, and the edge is not trained either.
    Skip,
    /// Drawn like every pixel against the image over its camera's static background, estimated from the
    /// training frames ([`Backgrounds`]): where the background is known, every ray's target is the image
    /// itself and the render is composited over the background ([`HostRays::backgrounds`]), and a band ray
    /// carries no mask label ([`HostRays::labelled`]), so the colours decide where the body ends, as a
    /// partly covered pixel's colour says how much of it the body covers; except a band pixel outside the
    /// mask whose colour is its background's, which keeps its label 0 ([`shows_background`]). Band
    /// pixels whose background is not known are not drawn; without any backgrounds, as `Robust`. The
    /// default: captures' cameras stand still, and their masks are of unknown quality.
    #[default]
    Backdrop,
}

impl MaskEdges {
    /// Reads the setting as written today (`"skip"`, `"train"`, `"robust"`) or as the boolean
    /// `skip_mask_edges` of earlier versions' configs and checkpoints (`true` skips, `false` trains).
    pub fn deserialize_compatible<'de, D: serde::Deserializer<'de>>(
        d: D,
    ) -> Result<Self, D::Error> {
        struct Either;
        impl serde::de::Visitor<'_> for Either {
            type Value = MaskEdges;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(r#""skip", "train", "robust" or "backdrop""#)
            }
            fn visit_bool<E: serde::de::Error>(self, skip: bool) -> Result<MaskEdges, E> {
                Ok(if skip {
                    MaskEdges::Skip
                } else {
                    MaskEdges::Train
                })
            }
            fn visit_str<E: serde::de::Error>(self, name: &str) -> Result<MaskEdges, E> {
                match name {
                    "skip" => Ok(MaskEdges::Skip),
                    "train" => Ok(MaskEdges::Train),
                    "robust" => Ok(MaskEdges::Robust),
                    "backdrop" => Ok(MaskEdges::Backdrop),
                    _ => Err(E::invalid_value(serde::de::Unexpected::Str(name), &self)),
                }
            }
        }
        d.deserialize_any(Either)
    }
}

/// How training rays are drawn.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SamplerOptions {
    /// Rays per step (`N_rand`), split over the step's images ([`RaySampler::sample_step`]).
    pub rays: usize,
    /// Share of rays drawn on the body mask (`body_sample_ratio`); the rest uniformly in the projected box.
    pub body_fraction: f32,
    /// What is drawn from the band around the mask's edge.
    #[serde(
        alias = "skip_mask_edges",
        deserialize_with = "MaskEdges::deserialize_compatible"
    )]
    pub mask_edges: MaskEdges,
    /// Share of rays drawn where the image has detail, in proportion to its target colours' gradient
    /// magnitude (edges of the silhouette and of the texture); the rest split by `body_fraction`. 0 (the
    /// reference, and runs saved before it existed) draws none.
    #[serde(default)]
    pub detail_fraction: f32,
    /// Extra padding of the (already 0.05 m padded) box for near/far (metres).
    pub near_far_padding: f32,
    pub convention: PixelConvention,
}

impl Default for SamplerOptions {
    /// The reference's settings: 1024 rays, half on the body, mask edges skipped, +0.01 m for near/far.
    fn default() -> Self {
        Self {
            rays: 1024,
            body_fraction: 0.5,
            mask_edges: MaskEdges::Skip,
            detail_fraction: 0.0,
            near_far_padding: 0.01,
            convention: PixelConvention::Integer,
        }
    }
}

/// Why rays could not be drawn.
#[derive(Debug, Error)]
pub enum SamplerError {
    #[error("image is {image:?} but the camera is {camera:?} (width, height)")]
    SizeMismatch {
        image: (u32, u32),
        camera: (u32, u32),
    },
    #[error("the mask-edge band has {band} pixels, but the camera has {pixels}")]
    EdgeMismatch { band: usize, pixels: usize },
    #[error(
        "no pixel of the projected body box can be sampled (box behind or outside the camera?)"
    )]
    EmptyBox,
    #[error("after {0} rounds no sampled ray hits the body box")]
    NoHits(usize),
    #[error(transparent)]
    Data(#[from] DataError),
}

/// One image to draw rays from: its camera, the frame's world box (posed vertices ± 0.05 m), the image
/// (channels in `[0, 1]`) and its mask (non-zero = body).
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    pub camera: &'a Camera,
    pub bounds: &'a Aabb,
    pub image: Pixels<'a>,
    pub mask: &'a GrayImage,
    /// The mask-edge band (row-major), as prepared from the full-resolution mask; `None`: computed from
    /// `mask` at this resolution.
    pub edge: Option<&'a [bool]>,
    /// The camera's static background, under [`MaskEdges::Backdrop`].
    pub background: Option<&'a BackgroundPlate>,
}

/// An RGB image's pixels, as channels in `[0, 1]` or as 8-bit values (channel = value / 255).
#[derive(Debug, Clone, Copy)]
pub enum Pixels<'a> {
    Float(&'a Rgb32FImage),
    Byte(&'a RgbImage),
}

impl Pixels<'_> {
    /// Width and height.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            Pixels::Float(image) => image.dimensions(),
            Pixels::Byte(image) => image.dimensions(),
        }
    }

    /// The channels in `[0, 1]` of pixel `i` (row-major).
    pub fn rgb(&self, i: usize) -> [f32; 3] {
        match self {
            Pixels::Float(image) => image.as_raw()[3 * i..3 * i + 3]
                .try_into()
                .expect("3 channels"),
            Pixels::Byte(image) => std::array::from_fn(|c| byte_channel(image.as_raw()[3 * i + c])),
        }
    }
}

impl<'a> From<&'a Rgb32FImage> for Pixels<'a> {
    fn from(image: &'a Rgb32FImage) -> Self {
        Pixels::Float(image)
    }
}

impl<'a> From<&'a RgbImage> for Pixels<'a> {
    fn from(image: &'a RgbImage) -> Self {
        Pixels::Byte(image)
    }
}

/// One image set of a training step: a frame and the views its rays are drawn from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepImages {
    pub frame: FrameId,
    pub views: Vec<ViewId>,
}

/// Draws training rays, deterministically from its seed; its whole state serialises, so a resumed run
/// continues the same stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RaySampler {
    pub options: SamplerOptions,
    rng: ChaCha8Rng,
}

impl RaySampler {
    pub fn new(seed: u64, options: SamplerOptions) -> Self {
        Self {
            options,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Picks a training frame and `count` distinct views of it: the first image uniformly over
    /// `frames × views`, as the reference's loader does (so one view a step draws the reference's stream),
    /// the others uniformly among the frame's remaining views. `None` without frames, or with fewer views
    /// than `count` (or `count = 0`).
    pub fn pick(
        &mut self,
        frames: &[FrameId],
        views: &[ViewId],
        count: usize,
    ) -> Option<(FrameId, Vec<ViewId>)> {
        if frames.is_empty() || count == 0 || count > views.len() {
            return None;
        }
        let i = self.rng.random_range(0..frames.len() * views.len());
        let mut rest: Vec<ViewId> = views.to_vec();
        let mut picked = vec![rest.remove(i % views.len())];
        for _ in 1..count {
            picked.push(rest.swap_remove(self.rng.random_range(0..rest.len())));
        }
        Some((frames[i / views.len()], picked))
    }

    /// Exactly `n` rays of one image, with target colours (background and outside-box pixels black) and
    /// pixel coordinates.
    pub fn sample(&mut self, view: &ImageView, n: usize) -> Result<HostRays, SamplerError> {
        check_sizes(view)?;
        let computed;
        let band = match view.edge {
            Some(band) => band,
            None => {
                computed = edge_band(view.mask);
                &computed
            }
        };
        let pools = Pools::new(view, band, &self.options)?;
        self.draw(view, band, &pools, n)
    }

    /// `n` rays drawn from `pools` of `view`: the random part of [`Self::sample`].
    fn draw(
        &mut self,
        view: &ImageView,
        band: &[bool],
        pools: &Pools,
        n: usize,
    ) -> Result<HostRays, SamplerError> {
        let w = view.camera.width;
        let on_body: &[u8] = view.mask.as_raw();
        let background = backdrop(view, self.options.mask_edges);
        let behind = |i: usize| background.and_then(|b| b.at(i));
        let hit_box = view.bounds.padded(self.options.near_far_padding);
        let mut out = HostRays::default();
        for _round in 0..ROUNDS {
            let left = n - out.len();
            if left == 0 {
                return Ok(out);
            }
            let n_detail = if pools.detail.is_empty() {
                0
            } else {
                (left as f32 * self.options.detail_fraction) as usize
            };
            let n_body = if pools.body.is_empty() {
                0
            } else {
                ((left - n_detail) as f32 * self.options.body_fraction) as usize
            };
            let picks: Vec<u32> = (0..left)
                .map(|k| {
                    if k < n_detail {
                        return pools.detail.draw(&mut self.rng);
                    }
                    let pool = if k - n_detail < n_body {
                        &pools.body
                    } else {
                        &pools.boxed
                    };
                    pool[self.rng.random_range(0..pool.len())]
                })
                .collect();
            for i in picks {
                let (u, v) = (i % w, i / w);
                let ray = view
                    .camera
                    .pixel_ray(u as f32, v as f32, self.options.convention);
                if let Some(hit) = hit_box.intersect(&ray) {
                    let i = i as usize;
                    let color = target(view, background, i);
                    push_ray(&mut out, &ray, hit.near, hit.far, color, [u, v]);
                    out.foreground.push(on_body[i] != 0);
                    match (background, behind(i)) {
                        (None, _) => out.edge.push(band[i]),
                        (Some(_), known) => {
                            out.edge.push(band[i] && known.is_none());
                            out.labelled.push(match known {
                                Some(b) if band[i] => on_body[i] == 0 && shows_background(color, b),
                                _ => true,
                            });
                            out.backgrounds.push(known.unwrap_or([0.0; 3]));
                        }
                    }
                }
            }
        }
        if out.len() == n {
            Ok(out)
        } else {
            Err(SamplerError::NoHits(ROUNDS))
        }
    }

    /// Picks a step's images: `frames` distinct training frames (all of them where there are fewer), each
    /// with `views` distinct views, every frame drawn by [`Self::pick`] among the frames not yet picked (so
    /// one frame a step draws the one-frame stream). `None` as `pick` returns it.
    pub fn pick_step(
        &mut self,
        frames: &[FrameId],
        views: &[ViewId],
        frame_count: usize,
        view_count: usize,
    ) -> Option<Vec<StepImages>> {
        if frame_count == 0 {
            return None;
        }
        let mut left = frames.to_vec();
        let mut picked = Vec::new();
        while picked.len() < frame_count && !left.is_empty() {
            let (frame, views) = self.pick(&left, views, view_count)?;
            left.retain(|&f| f != frame);
            picked.push(StepImages { frame, views });
        }
        (!picked.is_empty()).then_some(picked)
    }

    /// Draws one step's `options.rays` rays from `images` ([`Self::pick_step`]): split over the frames as
    /// evenly as whole rays allow (the first take the remainder), each frame's share over its views as
    /// [`Self::sample_prepared`] splits it. The images are read through `cache` (the same rays as without).
    pub fn sample_step(
        &mut self,
        subject: &PreparedSubject,
        backgrounds: Option<&Backgrounds>,
        images: &[StepImages],
        cache: &ImageCache,
    ) -> Result<Vec<HostRays>, SamplerError> {
        let total = self.options.rays;
        let shares: Vec<(FrameId, &[ViewId], usize)> = images
            .iter()
            .enumerate()
            .map(|(k, step)| {
                (
                    step.frame,
                    step.views.as_slice(),
                    share(total, images.len(), k),
                )
            })
            .collect();
        self.sample_frames(subject, backgrounds, &shares, cache)
    }

    /// Reads `views` of one frame of a prepared subject and draws `rays` rays from them, split as evenly
    /// as whole rays allow (the first views take the remainder), concatenated view after view; under
    /// [`MaskEdges::Backdrop`], over the views' `backgrounds`.
    pub fn sample_prepared(
        &mut self,
        subject: &PreparedSubject,
        backgrounds: Option<&Backgrounds>,
        frame: FrameId,
        views: &[ViewId],
        rays: usize,
    ) -> Result<HostRays, SamplerError> {
        let shares = [(frame, views, rays)];
        let mut rays = self.sample_frames(subject, backgrounds, &shares, &ImageCache::none())?;
        Ok(rays.pop().expect("one frame"))
    }

    /// `(frame, views, rays)` shares drawn as [`Self::sample_prepared`] draws each: the images are read (or
    /// taken from `cache`) and their pools found in parallel (nothing random happens there), then the rays are
    /// drawn image after image in order, so the stream is the one a sequential loop draws.
    fn sample_frames(
        &mut self,
        subject: &PreparedSubject,
        backgrounds: Option<&Backgrounds>,
        shares: &[(FrameId, &[ViewId], usize)],
        cache: &ImageCache,
    ) -> Result<Vec<HostRays>, SamplerError> {
        let mut jobs = Vec::new();
        for &(frame, views, rays) in shares {
            let bounds = subject
                .frame(frame)
                .ok_or_else(|| {
                    DataError::invalid(&subject.dir, format!("{frame} was not prepared"))
                })?
                .bounds;
            for (k, &view) in views.iter().enumerate() {
                jobs.push((frame, view, bounds, share(rays, views.len(), k)));
            }
        }
        let options = &self.options;
        let read: Vec<Arc<ReadImage>> = jobs
            .par_iter()
            .map(|&(frame, view, bounds, _)| {
                cache.get_or_read((frame, view, options.mask_edges), || {
                    let background = backgrounds.and_then(|b| b.plate(view));
                    ReadImage::new(subject, frame, view, bounds, options, background)
                })
            })
            .collect::<Result<_, _>>()?;
        let mut drawn = read.iter().zip(&jobs).map(|(image, job)| {
            let view = image.view(subject, backgrounds);
            self.draw(&view, &image.edge, &image.pools, job.3)
        });
        shares
            .iter()
            .map(|(_, views, _)| {
                let mut out = HostRays::default();
                for _ in 0..views.len() {
                    out.append(drawn.next().expect("a job per view")?);
                }
                Ok(out)
            })
            .collect()
    }
}

/// The pixels of one image that rays are drawn from, in pixel order: the box's projection less a skipped
/// mask-edge band (`boxed`), and those of them on the body (`body`) — the reference's
/// `msk = msk · bound_mask; bound_mask[msk == 100] = 0` — and, where the options draw any, those of `boxed`
/// with detail, weighted (`detail`).
struct Pools {
    body: Vec<u32>,
    boxed: Vec<u32>,
    detail: DetailPool,
}

impl Pools {
    fn new(
        view: &ImageView,
        band: &[bool],
        options: &SamplerOptions,
    ) -> Result<Self, SamplerError> {
        let mask_edges = options.mask_edges;
        let bound = box_mask(view.camera, view.bounds);
        // Band pixels that are never drawn: all under `Skip`; under `Backdrop`, those whose background
        // is not known (their colour mixes the body with a backdrop nothing tells, their label is as unsure).
        let skipped = |i: usize| match (mask_edges, view.background) {
            (MaskEdges::Skip, _) => true,
            (MaskEdges::Backdrop, Some(plate)) => plate.at(i).is_none(),
            _ => false,
        };
        let on_body: &[u8] = view.mask.as_raw();
        let (mut body, mut boxed) = (Vec::new(), Vec::new());
        for (i, (&inside, &edge)) in bound.iter().zip(band).enumerate() {
            if inside && !(edge && skipped(i)) {
                boxed.push(i as u32);
                if on_body[i] != 0 {
                    body.push(i as u32);
                }
            }
        }
        if boxed.is_empty() {
            return Err(SamplerError::EmptyBox);
        }
        let detail = if options.detail_fraction > 0.0 {
            let background = backdrop(view, mask_edges);
            let pixels = view.mask.as_raw().len();
            let colours: Vec<[f32; 3]> = (0..pixels).map(|i| target(view, background, i)).collect();
            DetailPool::new(&colours, view.camera.width as usize, boxed.iter().copied())
        } else {
            DetailPool::default()
        };
        Ok(Self {
            body,
            boxed,
            detail,
        })
    }
}

/// The camera's background that training composites over: `view`'s plate under [`MaskEdges::Backdrop`].
fn backdrop<'a>(view: &ImageView<'a>, mask_edges: MaskEdges) -> Option<&'a BackgroundPlate> {
    view.background
        .filter(|_| mask_edges == MaskEdges::Backdrop)
}

/// Pixel `i`'s target colour: the image where the mask says body or the `background` is known (the render
/// is composited over it), black elsewhere.
fn target(view: &ImageView, background: Option<&BackgroundPlate>, i: usize) -> [f32; 3] {
    if view.mask.as_raw()[i] != 0 || background.and_then(|b| b.at(i)).is_some() {
        view.image.rgb(i)
    } else {
        [0.0; 3]
    }
}

/// Mean absolute difference per channel (0–1 colour, about 8 of 255 grey levels) under which a pixel's
/// colour counts as its camera's estimated background: above a capture's sensor noise, below what a body
/// covering a tenth of the pixel adds against a background that differs from it by a third.
const BACKGROUND_TOLERANCE: f32 = 0.03;

/// Whether a pixel of colour `seen` shows its `background` alone ([`BACKGROUND_TOLERANCE`]). Under
/// `backdrop` a band pixel outside the mask that does keeps its label 0: two independent witnesses, the
/// mask and the colour, agree that no body covers it, so the silhouette loss may empty it; a pixel the
/// mask missed shows the body's colour and stays unlabelled.
fn shows_background(seen: [f32; 3], background: [f32; 3]) -> bool {
    let diff: f32 = seen
        .iter()
        .zip(background)
        .map(|(a, b)| (a - b).abs())
        .sum();
    diff < 3.0 * BACKGROUND_TOLERANCE
}

/// A training image of a prepared subject, read and with its [`Pools`] found.
struct ReadImage {
    view: ViewId,
    bounds: Aabb,
    image: RgbImage,
    mask: GrayImage,
    edge: Vec<bool>,
    pools: Pools,
}

impl ReadImage {
    fn new(
        subject: &PreparedSubject,
        frame: FrameId,
        view: ViewId,
        bounds: Aabb,
        options: &SamplerOptions,
        background: Option<&BackgroundPlate>,
    ) -> Result<Self, SamplerError> {
        let image = subject.image_rgb8(frame, view)?;
        let (mask, edge) = subject.mask_and_edge(frame, view)?;
        let camera = &subject.cameras[view.0];
        let view_of = ImageView {
            camera,
            bounds: &bounds,
            image: (&image).into(),
            mask: &mask,
            edge: Some(&edge),
            background,
        };
        check_sizes(&view_of)?;
        let pools = Pools::new(&view_of, &edge, options)?;
        Ok(Self {
            view,
            bounds,
            image,
            mask,
            edge,
            pools,
        })
    }

    /// The bytes it holds, roughly: what [`ImageCache`] counts against its budget.
    fn bytes(&self) -> usize {
        self.image.as_raw().len()
            + self.mask.as_raw().len()
            + self.edge.len()
            + 4 * (self.pools.body.len() + self.pools.boxed.len())
            + 12 * self.pools.detail.len()
    }

    fn view<'a>(
        &'a self,
        subject: &'a PreparedSubject,
        backgrounds: Option<&'a Backgrounds>,
    ) -> ImageView<'a> {
        ImageView {
            camera: &subject.cameras[self.view.0],
            bounds: &self.bounds,
            image: (&self.image).into(),
            mask: &self.mask,
            edge: Some(&self.edge),
            background: backgrounds.and_then(|b| b.plate(self.view)),
        }
    }
}

/// Part `k` of `total` rays split over `parts` as evenly as whole rays allow, the first parts taking the
/// remainder.
fn share(total: usize, parts: usize, k: usize) -> usize {
    total / parts + usize::from(k < total % parts)
}

/// Resampling rounds before giving up (each round keeps every ray that hits).
const ROUNDS: usize = 64;

fn push_ray(
    out: &mut HostRays,
    ray: &anerf_core::geometry::Ray,
    near: f32,
    far: f32,
    color: [f32; 3],
    pixel: [u32; 2],
) {
    out.origins.push(ray.origin.to_array());
    out.directions.push(ray.direction.to_array());
    out.near.push(near);
    out.far.push(far);
    out.colors.push(color);
    out.pixels.push(pixel);
}

fn check_sizes(view: &ImageView) -> Result<(u32, u32), SamplerError> {
    let cam = (view.camera.width, view.camera.height);
    for dims in [view.image.dimensions(), view.mask.dimensions()] {
        if dims != cam {
            return Err(SamplerError::SizeMismatch {
                image: dims,
                camera: cam,
            });
        }
    }
    let pixels = cam.0 as usize * cam.1 as usize;
    if let Some(band) = view.edge.filter(|b| b.len() != pixels) {
        return Err(SamplerError::EdgeMismatch {
            band: band.len(),
            pixels,
        });
    }
    Ok(cam)
}

/// `bound_mask`: pixels covered by the projection of the box, filled face by face from the rounded
/// projections of its corners, like the reference's `cv2.fillPoly` of the six faces (interior plus the
/// 8-connected outline OpenCV draws).
pub fn box_mask(camera: &Camera, bounds: &Aabb) -> Vec<bool> {
    let (w, h) = (camera.width as i64, camera.height as i64);
    let mut mask = vec![false; (w * h) as usize];
    let corners = bounds.corners();
    // Aabb::corners orders bit 0 = x, bit 1 = y, bit 2 = z; the six faces as quads.
    const FACES: [[usize; 4]; 6] = [
        [0, 2, 6, 4],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 5, 7, 6],
    ];
    let projected: Vec<Option<Vec2>> = corners
        .iter()
        .map(|&c| {
            camera
                .project(c, PixelConvention::Integer)
                .map(|p| p.round())
        })
        .collect();
    for face in FACES {
        let Some(quad) = face
            .iter()
            .map(|&i| projected[i])
            .collect::<Option<Vec<Vec2>>>()
        else {
            continue;
        };
        // cv2.fillPoly also draws each edge as an 8-connected line, which can reach half a pixel outside.
        for k in 0..4 {
            let (a, b) = (quad[k], quad[(k + 1) % 4]);
            let steps = (b - a).abs().max_element() as i64;
            for i in 0..=steps {
                let t = if steps == 0 {
                    0.0
                } else {
                    i as f32 / steps as f32
                };
                let p = (a + (b - a) * t).round();
                if p.x >= 0.0 && p.y >= 0.0 && (p.x as i64) < w && (p.y as i64) < h {
                    mask[(p.y as i64 * w + p.x as i64) as usize] = true;
                }
            }
        }
        fill_quad(&mut mask, w, h, &quad);
    }
    mask
}

/// Marks the pixels `(x, y)` of a `w × h` row-major mask at which [`inside_convex`] holds for `quad`
/// (corners at whole pixels), a row at a time: the test's half-planes cut each row to one span, found in
/// exact integer arithmetic, so a row costs four divisions instead of a test per pixel. A quad of zero
/// area (a face seen edge-on) is tested pixel by pixel.
fn fill_quad(mask: &mut [bool], w: i64, h: i64, quad: &[Vec2]) {
    let lo = quad.iter().fold(Vec2::splat(f32::MAX), |a, p| a.min(*p));
    let hi = quad.iter().fold(Vec2::splat(f32::MIN), |a, p| a.max(*p));
    let (x0, x1) = (lo.x.max(0.0) as i64, hi.x.min((w - 1) as f32) as i64);
    let rows = (lo.y.max(0.0) as i64)..=(hi.y.min((h - 1) as f32) as i64);
    // Corners beyond ±2⁴⁰ pixels (a box corner at the camera's plane) are pulled in, which keeps every
    // product below in range.
    let whole = |v: f32| i128::from((v as i64).clamp(-(1 << 40), 1 << 40));
    let corners: Vec<[i128; 2]> = quad.iter().map(|p| [whole(p.x), whole(p.y)]).collect();
    let edges: Vec<([i128; 2], [i128; 2])> = (0..corners.len())
        .map(|k| {
            let (a, b) = (corners[k], corners[(k + 1) % corners.len()]);
            (a, [b[0] - a[0], b[1] - a[1]])
        })
        .collect();
    // Twice the signed area. Every test `d × (p − a)` is an integer and they sum to it, so where it is not
    // zero `inside_convex` holds exactly where each one has the area's sign (or is zero).
    let area: i128 = edges.iter().map(|(a, d)| a[0] * d[1] - a[1] * d[0]).sum();
    if area == 0 {
        for y in rows {
            for x in x0..=x1 {
                if inside_convex(quad, Vec2::new(x as f32, y as f32)) {
                    mask[(y * w + x) as usize] = true;
                }
            }
        }
        return;
    }
    let sign = area.signum();
    for y in rows {
        // Edge `a → a + d` keeps `sign · (d.x (y − a.y) − d.y (x − a.x)) ≥ 0`, i.e. `f − e·x ≥ 0`.
        let (mut from, mut to) = (i128::from(x0), i128::from(x1));
        for &(a, d) in &edges {
            let e = sign * d[1];
            let f = sign * (d[0] * (i128::from(y) - a[1]) + d[1] * a[0]);
            match e.signum() {
                0 if f < 0 => to = from - 1,
                0 => {}
                1 => to = to.min(f.div_euclid(e)),
                _ => from = from.max(-(f.div_euclid(-e))),
            }
        }
        if from <= to {
            let row = (y * w) as usize;
            mask[row + from as usize..=row + to as usize].fill(true);
        }
    }
}

/// Inside or on the boundary of a convex polygon of either orientation.
fn inside_convex(poly: &[Vec2], p: Vec2) -> bool {
    let (mut pos, mut neg) = (false, false);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let cross = (b - a).perp_dot(p - a);
        pos |= cross > 1e-4;
        neg |= cross < -1e-4;
    }
    !(pos && neg)
}

/// Every ray of one image that hits the box enlarged by `near_far_padding` (`mask_at_box`), for
/// evaluation and rendering, and the ground truth the metrics compare against.
#[derive(Debug, Clone)]
pub struct ImageRays {
    /// Rays in row-major pixel order, with `pixels` and (when an image was given) `colors`.
    pub rays: HostRays,
    pub width: u32,
    pub height: u32,
    /// The image with background (mask 0, not eroded) and pixels outside the projected 0.05 m box set to
    /// black; `None` without an image.
    pub ground_truth: Option<Rgb32FImage>,
}

/// All rays of an image whose pixel ray hits `bounds.padded(near_far_padding)` (docs/REFERENCE.md §4.2).
pub fn image_rays(
    camera: &Camera,
    bounds: &Aabb,
    image: Option<(&Rgb32FImage, &GrayImage)>,
    options: &SamplerOptions,
) -> Result<ImageRays, SamplerError> {
    let (w, h) = (camera.width, camera.height);
    let ground_truth = match image {
        Some((img, mask)) => {
            check_sizes(&ImageView {
                camera,
                bounds,
                image: img.into(),
                mask,
                edge: None,
                background: None,
            })?;
            let bound = box_mask(camera, bounds);
            let mut gt = img.clone();
            for (i, (px, m)) in gt.pixels_mut().zip(mask.pixels()).enumerate() {
                if m[0] == 0 || !bound[i] {
                    px.0 = [0.0; 3];
                }
            }
            Some(gt)
        }
        None => None,
    };
    let hit_box = bounds.padded(options.near_far_padding);
    let mut rays = HostRays::default();
    for v in 0..h {
        for u in 0..w {
            let ray = camera.pixel_ray(u as f32, v as f32, options.convention);
            if let Some(hit) = hit_box.intersect(&ray) {
                let color = ground_truth
                    .as_ref()
                    .map_or([0.0; 3], |g| g.get_pixel(u, v).0);
                push_ray(&mut rays, &ray, hit.near, hit.far, color, [u, v]);
            }
        }
    }
    if ground_truth.is_none() {
        rays.colors.clear();
    }
    Ok(ImageRays {
        rays,
        width: w,
        height: h,
        ground_truth,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The span fill marks exactly the pixels the per-pixel test accepts, for quads of every kind the
    /// rounding of a projected face can give: convex either way round, partly or wholly off the image,
    /// self-intersecting, collinear or a single point.
    #[test]
    fn the_span_fill_equals_the_per_pixel_test() {
        let (w, h) = (37i64, 29i64);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut corner = |spread: i32| {
            Vec2::new(
                rng.random_range(-spread..w as i32 + spread) as f32,
                rng.random_range(-spread..h as i32 + spread) as f32,
            )
        };
        let mut quads: Vec<Vec<Vec2>> = (0..3000)
            .map(|k| (0..4).map(|_| corner(k % 40)).collect())
            .collect();
        for k in 0..200 {
            // Collinear corners (a face seen edge-on) and repeated ones.
            let (a, b) = (corner(10), corner(10));
            let t = [0.0, 0.5, 1.0, 2.0].map(|t| (a + (b - a) * t).round());
            quads.push(if k % 2 == 0 {
                t.to_vec()
            } else {
                vec![a, a, a, a]
            });
        }
        let mut filled = 0;
        for quad in &quads {
            let mut spans = vec![false; (w * h) as usize];
            fill_quad(&mut spans, w, h, quad);
            // The earlier fill: the test at every pixel of the quad's bounding box.
            let lo = quad.iter().fold(Vec2::splat(f32::MAX), |a, p| a.min(*p));
            let hi = quad.iter().fold(Vec2::splat(f32::MIN), |a, p| a.max(*p));
            let pixels: Vec<bool> = (0..w * h)
                .map(|i| {
                    let p = Vec2::new((i % w) as f32, (i / w) as f32);
                    p.cmpge(lo).all() && p.cmple(hi).all() && inside_convex(quad, p)
                })
                .collect();
            let differ = spans.iter().zip(&pixels).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{differ} pixels differ for quad {quad:?}");
            filled += usize::from(pixels.iter().any(|&p| p));
        }
        assert!(filled > 1000, "only {filled} quads cover a pixel");
    }
}
