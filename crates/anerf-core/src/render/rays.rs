//! Batches of camera rays, the renderer's input.

use burn::prelude::*;

use crate::geometry::{Aabb, Ray};
use crate::ids::FrameId;
use crate::tensor::from_rows;

/// Rays of one image (one frame seen from one view) on the host, before upload.
///
/// All rays hit the frame's box: `near < far` (metres along the unit world-space direction).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HostRays {
    pub origins: Vec<[f32; 3]>,
    pub directions: Vec<[f32; 3]>,
    pub near: Vec<f32>,
    pub far: Vec<f32>,
    /// Target colour in `[0, 1]` per ray (empty when rendering without ground truth).
    pub colors: Vec<[f32; 3]>,
    /// Pixel `(column, row)` of each ray in its image, for writing renders back.
    pub pixels: Vec<[u32; 2]>,
    /// Per ray: its pixel is foreground in the mask (empty when rendering without ground truth).
    pub foreground: Vec<bool>,
    /// Per ray: its pixel lies in the band around the mask's edge, where masks are least sure (empty when
    /// unknown).
    pub edge: Vec<bool>,
    /// Per ray: the colour behind the body, which the render is composited over before it meets the
    /// target (empty: black for every ray).
    pub backgrounds: Vec<[f32; 3]>,
    /// Per ray: whether the mask's label trains the ray's opacity (empty: every ray's does).
    pub labelled: Vec<bool>,
}

impl HostRays {
    /// Intersects `rays` with `bounds` and keeps the hits; returns the rays and the indices that hit.
    pub fn from_rays(rays: &[Ray], bounds: &Aabb) -> (Self, Vec<usize>) {
        let mut out = Self::default();
        let mut kept = Vec::new();
        for (i, ray) in rays.iter().enumerate() {
            if let Some(hit) = bounds.intersect(ray) {
                out.origins.push(ray.origin.to_array());
                out.directions.push(ray.direction.to_array());
                out.near.push(hit.near);
                out.far.push(hit.far);
                kept.push(i);
            }
        }
        (out, kept)
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.near.len()
    }

    /// True when there are no rays.
    pub fn is_empty(&self) -> bool {
        self.near.is_empty()
    }

    /// Appends `other`'s rays after these (rays of several images in one batch). Both must know the same
    /// per-ray fields (colours, pixels, labels), or the fields stop lining up with the rays.
    pub fn append(&mut self, other: HostRays) {
        self.origins.extend(other.origins);
        self.directions.extend(other.directions);
        self.near.extend(other.near);
        self.far.extend(other.far);
        self.colors.extend(other.colors);
        self.pixels.extend(other.pixels);
        self.foreground.extend(other.foreground);
        self.edge.extend(other.edge);
        self.backgrounds.extend(other.backgrounds);
        self.labelled.extend(other.labelled);
    }

    /// The rays `range` as a new batch (for rendering in chunks).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Self {
        Self {
            origins: self.origins[range.clone()].to_vec(),
            directions: self.directions[range.clone()].to_vec(),
            near: self.near[range.clone()].to_vec(),
            far: self.far[range.clone()].to_vec(),
            colors: known_part(&self.colors, range.clone()),
            pixels: known_part(&self.pixels, range.clone()),
            foreground: known_part(&self.foreground, range.clone()),
            edge: known_part(&self.edge, range.clone()),
            backgrounds: known_part(&self.backgrounds, range.clone()),
            labelled: known_part(&self.labelled, range),
        }
    }
}

/// Rays of one frame (from one or several of its images) on a device: the unit of work of [`crate`]'s
/// renderer.
#[derive(Debug, Clone)]
pub struct RayBatch {
    pub frame: FrameId,
    /// `[R, 3]` world-space origins (metres).
    pub origins: Tensor<2>,
    /// `[R, 3]` world-space unit directions.
    pub directions: Tensor<2>,
    /// `[R]` entry and exit depths (metres).
    pub near: Tensor<1>,
    pub far: Tensor<1>,
    /// `[R, 3]` target colours, when known.
    pub colors: Option<Tensor<2>>,
    /// `[R]` 1 where the ray's pixel is foreground in the mask, 0 elsewhere, when known.
    pub foreground: Option<Tensor<1>>,
    /// `[R]` 1 where the ray's pixel lies in the band around the mask's edge, 0 elsewhere, when known.
    pub edge: Option<Tensor<1>>,
    /// `[R, 3]` the colour behind the body per ray, when not black.
    pub backgrounds: Option<Tensor<2>>,
    /// `[R]` 1 where the mask's label trains the ray's opacity, 0 where it does not, when not every ray's does.
    pub labelled: Option<Tensor<1>>,
}

impl RayBatch {
    /// Uploads `rays` of `frame`.
    pub fn new(rays: &HostRays, frame: FrameId, device: &Device) -> Self {
        let n = rays.len();
        Self {
            frame,
            origins: from_rows(rays.origins.as_flattened(), n, 3, device),
            directions: from_rows(rays.directions.as_flattened(), n, 3, device),
            near: Tensor::from_floats(rays.near.as_slice(), device),
            far: Tensor::from_floats(rays.far.as_slice(), device),
            colors: (!rays.colors.is_empty())
                .then(|| from_rows(rays.colors.as_flattened(), n, 3, device)),
            foreground: indicator(&rays.foreground, device),
            edge: indicator(&rays.edge, device),
            backgrounds: (!rays.backgrounds.is_empty())
                .then(|| from_rows(rays.backgrounds.as_flattened(), n, 3, device)),
            labelled: indicator(&rays.labelled, device),
        }
    }

    /// Number of rays `R`.
    pub fn len(&self) -> usize {
        self.near.dims()[0]
    }

    /// True when the batch holds no rays.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// `values[range]` of a per-ray field, or nothing when the field is not known (empty).
fn known_part<T: Clone>(values: &[T], range: std::ops::Range<usize>) -> Vec<T> {
    if values.is_empty() {
        Vec::new()
    } else {
        values[range].to_vec()
    }
}

/// `[R]` 1 where a flag is set, 0 elsewhere; `None` when the flags are not known.
fn indicator(flags: &[bool], device: &Device) -> Option<Tensor<1>> {
    (!flags.is_empty()).then(|| {
        let values: Vec<f32> = flags.iter().map(|&f| f32::from(u8::from(f))).collect();
        Tensor::from_floats(values.as_slice(), device)
    })
}
