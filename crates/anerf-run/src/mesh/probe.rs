//! What the NeRF shows of its canonical surface: the iso-surface of raw density (`--level`) lies in the
//! haze outside the visible body, where the radiance field's colour means little (on the demo subject the
//! colours there average 0.05), so each vertex sends a ray along its inward normal through the canonical
//! NeRF and takes where it stops and the colour it sees. The bake places its Gaussians by it; every
//! canonical mesh (`anerf mesh`, the glb of `anerf export`, `eval --mesh`) takes its colours from it.

use anerf_core::geometry::skinning::points_tensor;
use anerf_core::model::codes::CodeRows;
use anerf_core::model::{AnimatableNerf, CanonicalInputs};
use anerf_core::render::composite;
use anerf_core::tensor::{from_rows, to_host};
use glam::Vec3;

/// How far outside a vertex, along its normal, the probing ray starts (metres); it ends as far inside.
const REACH: f32 = 0.05;
/// Samples along a probing ray.
const PROBE_SAMPLES: usize = 32;
/// A probe that gathers less opacity than this found no surface: the vertex keeps its own place and
/// colour.
pub const PROBE_HIT: f32 = 0.5;

/// What the NeRF shows along one vertex normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceProbe {
    /// Expected point the ray stops at (canonical space, metres).
    pub point: Vec3,
    /// Colour it sees there (normalised by the opacity).
    pub colour: [f32; 3],
    /// Opacity gathered along the ray.
    pub opacity: f32,
}

/// Volume-renders, with the canonical NeRF (appearance code `appearance`), a ray looking at each vertex
/// along its inward normal, from [`REACH`] outside to [`REACH`] inside, `chunk` samples at a time.
pub fn probe_along_normals(
    model: &AnimatableNerf,
    canonical: &CanonicalInputs,
    vertices: &[Vec3],
    normals: &[Vec3],
    appearance: usize,
    chunk: usize,
) -> Vec<SurfaceProbe> {
    let device = model.device();
    let s = PROBE_SAMPLES;
    let depths: Vec<f32> = (0..s)
        .map(|k| 2.0 * REACH * k as f32 / (s - 1) as f32)
        .collect();
    let rays_per_chunk = (chunk / s).max(1);
    let mut probes = Vec::with_capacity(vertices.len());
    for (vs, ns) in vertices
        .chunks(rays_per_chunk)
        .zip(normals.chunks(rays_per_chunk))
    {
        let r = vs.len();
        let inward: Vec<Vec3> = ns.iter().map(|n| -n.normalize_or_zero()).collect();
        let mut points = Vec::with_capacity(r * s);
        let mut dirs = Vec::with_capacity(r * s);
        for (v, d) in vs.iter().zip(&inward) {
            for &t in &depths {
                points.push(*v - *d * REACH + *d * t);
                dirs.push(*d);
            }
        }
        let p = points_tensor(&points, &device);
        let density = model
            .canonical_density(p.clone(), canonical)
            .reshape([r, s]);
        let rgb = model
            .nerf
            .forward(p, points_tensor(&dirs, &device), &CodeRows::One(appearance))
            .rgb
            .reshape([r, s, 3]);
        let row: Vec<f32> = (0..r).flat_map(|_| depths.iter().copied()).collect();
        let out = composite(density, rgb, from_rows(&row, r, s, &device));
        let (rgb, acc, depth) = (to_host(out.rgb), to_host(out.acc), to_host(out.depth));
        for i in 0..r {
            let a = acc[i];
            let normalise = |x: f32| if a > 0.0 { x / a } else { 0.0 };
            probes.push(SurfaceProbe {
                point: vs[i] - inward[i] * REACH + inward[i] * normalise(depth[i]),
                colour: [0, 1, 2].map(|c| normalise(rgb[3 * i + c]).clamp(0.0, 1.0)),
                opacity: a,
            });
        }
    }
    probes
}
