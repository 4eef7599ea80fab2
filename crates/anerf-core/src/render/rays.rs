//! Batches of camera rays, the renderer's input.

use burn::prelude::*;

use crate::geometry::{Aabb, Ray};
use crate::ids::{FrameId, ViewId};
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

    /// The rays `range` as a new batch (for rendering in chunks).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Self {
        let part = |v: &[[f32; 3]]| {
            if v.is_empty() {
                Vec::new()
            } else {
                v[range.clone()].to_vec()
            }
        };
        Self {
            origins: self.origins[range.clone()].to_vec(),
            directions: self.directions[range.clone()].to_vec(),
            near: self.near[range.clone()].to_vec(),
            far: self.far[range.clone()].to_vec(),
            colors: part(&self.colors),
            pixels: if self.pixels.is_empty() {
                Vec::new()
            } else {
                self.pixels[range.clone()].to_vec()
            },
            foreground: if self.foreground.is_empty() {
                Vec::new()
            } else {
                self.foreground[range].to_vec()
            },
        }
    }
}

/// Rays of one image on a device: the unit of work of [`crate`]'s renderer.
#[derive(Debug, Clone)]
pub struct RayBatch {
    pub frame: FrameId,
    pub view: ViewId,
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
}

impl RayBatch {
    /// Uploads `rays` of `frame` seen from `view`.
    pub fn new(rays: &HostRays, frame: FrameId, view: ViewId, device: &Device) -> Self {
        let n = rays.len();
        Self {
            frame,
            view,
            origins: from_rows(rays.origins.as_flattened(), n, 3, device),
            directions: from_rows(rays.directions.as_flattened(), n, 3, device),
            near: Tensor::from_floats(rays.near.as_slice(), device),
            far: Tensor::from_floats(rays.far.as_slice(), device),
            colors: (!rays.colors.is_empty())
                .then(|| from_rows(rays.colors.as_flattened(), n, 3, device)),
            foreground: (!rays.foreground.is_empty()).then(|| {
                let values: Vec<f32> = rays.foreground.iter().map(|&f| f as u8 as f32).collect();
                Tensor::from_floats(values.as_slice(), device)
            }),
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
