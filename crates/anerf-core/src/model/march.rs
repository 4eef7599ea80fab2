//! Rendering for display and evaluation, without gradients: each ray's surviving samples are shaded front to
//! back in rounds, and a ray stops once its transmittance falls below a threshold (early ray termination, as
//! in Instant-NGP and nerfacc), so the samples behind an opaque surface never reach an MLP. Compositing runs
//! on the host, with [`crate::render::composite`](mod@crate::render::composite)'s conventions.

use glam::Vec3;

use super::animatable::{AnimatableNerf, CanonicalInputs, FrameInputs};
use super::culling::{cull_samples, CorrectionWarp, SampleRays};
use crate::render::{sample_fractions, HostRays};
use crate::tensor::to_host;

/// Samples per ray shaded in the first round: about the depth of the surface shell culling leaves in front
/// of the body. Each later round takes twice as many, or all the rest once a round stops no ray.
const FIRST_ROUND: usize = 8;

/// Colours of a batch of rays, on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct MarchedRays {
    /// `[R·3]` colour on black.
    pub rgb: Vec<f32>,
    /// `[R]` accumulated opacity.
    pub acc: Vec<f32>,
    /// `[R]` expected depth along the ray, metres.
    pub depth: Vec<f32>,
    /// Samples that survived culling, samples that reached the canonical NeRF, and all samples.
    pub surviving_samples: usize,
    pub shaded_samples: usize,
    pub total_samples: usize,
}

/// One ray's running composite.
#[derive(Debug, Clone, Copy, Default)]
struct RayState {
    /// `Σ τ_j` of the samples composited so far (`T = exp(−Σ τ_j)`).
    optical_depth: f32,
    rgb: [f32; 3],
    acc: f32,
    depth: f32,
}

impl AnimatableNerf {
    /// Renders `rays` of one frame (world space, unit directions, no jitter). A ray stops once its
    /// transmittance is below `termination`; what it would still have gathered is less than `termination` in
    /// colour (per channel) and opacity. `termination = 0` shades every surviving sample: the image of
    /// [`Self::render`] up to rounding.
    pub fn march(
        &self,
        rays: &HostRays,
        frame: &FrameInputs,
        canonical: &CanonicalInputs,
        termination: f32,
    ) -> MarchedRays {
        let frame = &self.posed_frame(frame);
        let s = self.config().samples_per_ray;
        let r = rays.len();
        let depths = sample_depths(rays, s);
        let survivors = cull_samples(
            &SampleRays {
                origins: rays.origins.as_flattened(),
                directions: rays.directions.as_flattened(),
                depths: &depths,
                samples: s,
            },
            &frame.global,
            &frame.volume,
            self.config().cull_distance,
            frame.warp.as_ref().map(CorrectionWarp::host),
        );
        // Survivors are ordered by ray, then depth: ray `q`'s are `starts[q]..starts[q + 1]`.
        let mut starts = vec![0usize; r + 1];
        for &i in &survivors.index {
            starts[i as usize / s + 1] += 1;
        }
        for q in 0..r {
            starts[q + 1] += starts[q];
        }
        let mut next = starts[..r].to_vec();
        let mut state = vec![RayState::default(); r];
        let mut active: Vec<usize> = (0..r).filter(|&q| starts[q] < starts[q + 1]).collect();
        let mut round = FIRST_ROUND;
        let mut shaded_samples = 0;
        while !active.is_empty() {
            let mut batch = Vec::new();
            for &q in &active {
                let end = starts[q + 1].min(next[q].saturating_add(round));
                batch.extend(next[q]..end);
                next[q] = end;
            }
            let points: Vec<Vec3> = batch.iter().map(|&j| survivors.points[j]).collect();
            let directions = batch
                .iter()
                .flat_map(|&j| survivors.directions[3 * j..3 * j + 3].iter().copied())
                .collect();
            let (rows, shaded) = self.shade_survivors(&points, directions, frame, canonical);
            shaded_samples += rows.len();
            let (density, rgb) = (to_host(shaded.density), to_host(shaded.rgb));
            // Samples not shaded (empty canonical cells) have zero density and add nothing.
            for (row, &b) in rows.iter().enumerate() {
                let i = survivors.index[batch[b as usize]] as usize;
                let (q, k) = (i / s, i % s);
                let tau = density[row].max(0.0) * interval(&depths[q * s..(q + 1) * s], k);
                let ray = &mut state[q];
                let weight = (1.0 - (-tau).exp()) * (-ray.optical_depth).exp();
                for (c, v) in ray.rgb.iter_mut().zip(&rgb[3 * row..3 * row + 3]) {
                    *c += weight * v;
                }
                ray.acc += weight;
                ray.depth += weight * depths[i];
                ray.optical_depth += tau;
            }
            active.retain(|&q| next[q] < starts[q + 1]);
            let unfinished = active.len();
            active.retain(|&q| (-state[q].optical_depth).exp() >= termination);
            // Where no ray stopped (a translucent field, or no termination), one last round takes the rest.
            round = if active.len() < unfinished {
                round.saturating_mul(2)
            } else {
                usize::MAX
            };
        }
        MarchedRays {
            rgb: state.iter().flat_map(|ray| ray.rgb).collect(),
            acc: state.iter().map(|ray| ray.acc).collect(),
            depth: state.iter().map(|ray| ray.depth).collect(),
            surviving_samples: survivors.index.len(),
            shaded_samples,
            total_samples: r * s,
        }
    }
}

/// `[R·S]` evenly spaced depths from each ray's near to its far bound (metres), as
/// [`crate::render::stratified_depths`] without jitter.
fn sample_depths(rays: &HostRays, samples: usize) -> Vec<f32> {
    let steps = sample_fractions(samples);
    rays.near
        .iter()
        .zip(&rays.far)
        .flat_map(|(&near, &far)| steps.iter().map(move |&t| near + (far - near) * t))
        .collect()
}

/// `δ_k` of sample `k` of a ray with depths `z`: `z_{k+1} − z_k`, the last interval repeated.
fn interval(z: &[f32], k: usize) -> f32 {
    match z.len() {
        0 | 1 => 0.0,
        n if k + 1 < n => z[k + 1] - z[k],
        n => z[n - 1] - z[n - 2],
    }
}
