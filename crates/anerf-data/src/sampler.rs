//! Training rays (docs/REFERENCE.md §3.3) and evaluation rays (§4.2) of one image.
//!
//! Pixels are addressed by integer coordinates (column `u`, row `v`), and rays go through them in the
//! camera's [`PixelConvention`] (the reference: integer positions, no +0.5). Boxes are world space, metres.

use anerf_core::geometry::{Aabb, Camera, PixelConvention};
use anerf_core::render::HostRays;
use anerf_core::{FrameId, ViewId};
use glam::Vec2;
use image::{GrayImage, Rgb32FImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::error::DataError;
use crate::prepare::{edge_band, PreparedSubject};

/// What training draws from the band `dilate(mask) − erode(mask)` of a 5×5 kernel around the mask's edge
/// (the reference's `erode_edge`), marked on the full-resolution mask by `prepare` ([`ImageView::edge`]):
/// the pixels a real capture's mask is most often wrong about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaskEdges {
    /// Drawn like every pixel, with the mask's colour and label: for exact masks (synthetic subjects).
    Train,
    /// Drawn like every pixel and marked ([`HostRays::edge`]), so that training weighs them with a robust
    /// loss: where the mask is right the edge is trained almost as with `Train`, where it is wrong its
    /// pull is bounded and the rest of the data decides. The default: masks of unknown quality.
    #[default]
    Robust,
    /// Never drawn (the reference): the mask's errors are not learned, and the edge is not trained either.
    Skip,
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
                f.write_str(r#""skip", "train" or "robust""#)
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
    pub image: &'a Rgb32FImage,
    pub mask: &'a GrayImage,
    /// The mask-edge band (row-major), as prepared from the full-resolution mask; `None`: computed from
    /// `mask` at this resolution.
    pub edge: Option<&'a [bool]>,
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

/// Pixel classes of one training image.
const BACKGROUND: u8 = 0;
const BODY: u8 = 1;
const EDGE: u8 = 100;

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
        let (w, _) = check_sizes(view)?;
        let bound = box_mask(view.camera, view.bounds);
        let mut classes: Vec<u8> = view
            .mask
            .pixels()
            .map(|p| if p[0] != 0 { BODY } else { BACKGROUND })
            .collect();
        let computed;
        let band = match view.edge {
            Some(band) => band,
            None => {
                computed = edge_band(view.mask);
                &computed
            }
        };
        if self.options.mask_edges == MaskEdges::Skip {
            for (c, &edge) in classes.iter_mut().zip(band) {
                if edge {
                    *c = EDGE;
                }
            }
        }
        // msk = msk · bound_mask; bound_mask[msk == 100] = 0 (the reference's order).
        let body: Vec<u32> = (0..classes.len())
            .filter(|&i| bound[i] && classes[i] == BODY)
            .map(|i| i as u32)
            .collect();
        let boxed: Vec<u32> = (0..classes.len())
            .filter(|&i| bound[i] && classes[i] != EDGE)
            .map(|i| i as u32)
            .collect();
        if boxed.is_empty() {
            return Err(SamplerError::EmptyBox);
        }
        let gt = |i: usize| -> [f32; 3] {
            if bound[i] && classes[i] != BACKGROUND {
                view.image.as_raw()[3 * i..3 * i + 3]
                    .try_into()
                    .expect("3 channels")
            } else {
                [0.0; 3]
            }
        };
        let hit_box = view.bounds.padded(self.options.near_far_padding);
        let mut out = HostRays::default();
        for _round in 0..ROUNDS {
            let left = n - out.len();
            if left == 0 {
                return Ok(out);
            }
            let n_body = if body.is_empty() {
                0
            } else {
                (left as f32 * self.options.body_fraction) as usize
            };
            let picks: Vec<u32> = (0..left)
                .map(|k| {
                    let pool = if k < n_body { &body } else { &boxed };
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
                    push_ray(&mut out, &ray, hit.near, hit.far, gt(i), [u, v]);
                    out.foreground.push(bound[i] && classes[i] == BODY);
                    out.edge.push(band[i]);
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
    /// evenly as whole rays allow (the first take the remainder), each frame's share drawn by
    /// [`Self::sample_prepared`].
    pub fn sample_step(
        &mut self,
        subject: &PreparedSubject,
        images: &[StepImages],
    ) -> Result<Vec<HostRays>, SamplerError> {
        let total = self.options.rays;
        images
            .iter()
            .enumerate()
            .map(|(k, step)| {
                let n = total / images.len() + usize::from(k < total % images.len());
                self.sample_prepared(subject, step.frame, &step.views, n)
            })
            .collect()
    }

    /// Reads `views` of one frame of a prepared subject and draws `rays` rays from them, split as evenly
    /// as whole rays allow (the first views take the remainder), concatenated view after view.
    pub fn sample_prepared(
        &mut self,
        subject: &PreparedSubject,
        frame: FrameId,
        views: &[ViewId],
        rays: usize,
    ) -> Result<HostRays, SamplerError> {
        let bounds = subject
            .frame(frame)
            .ok_or_else(|| DataError::invalid(&subject.dir, format!("{frame} was not prepared")))?
            .bounds;
        let mut out = HostRays::default();
        for (k, &view) in views.iter().enumerate() {
            let n = rays / views.len() + usize::from(k < rays % views.len());
            let image = subject.image(frame, view)?;
            let (mask, edge) = subject.mask_and_edge(frame, view)?;
            let rays = self.sample(
                &ImageView {
                    camera: &subject.cameras[view.0],
                    bounds: &bounds,
                    image: &image,
                    mask: &mask,
                    edge: Some(&edge),
                },
                n,
            )?;
            out.append(rays);
        }
        Ok(out)
    }
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
        let lo = quad.iter().fold(Vec2::splat(f32::MAX), |a, p| a.min(*p));
        let hi = quad.iter().fold(Vec2::splat(f32::MIN), |a, p| a.max(*p));
        for y in (lo.y.max(0.0) as i64)..=(hi.y.min((h - 1) as f32) as i64) {
            for x in (lo.x.max(0.0) as i64)..=(hi.x.min((w - 1) as f32) as i64) {
                if inside_convex(&quad, Vec2::new(x as f32, y as f32)) {
                    mask[(y * w + x) as usize] = true;
                }
            }
        }
    }
    mask
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
                image: img,
                mask,
                edge: None,
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
