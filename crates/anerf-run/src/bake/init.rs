//! The avatar a bake starts from: one flat Gaussian per vertex of the canonical mesh (evenly thinned to
//! the budget), in the surface's tangent plane, skinned as the NeRF skins the vertex, placed where the
//! NeRF's surface lies along the vertex normal and coloured as the NeRF shows it from there
//! ([`probe_along_normals`]): the iso-surface of raw density lies in the haze outside the visible body,
//! where the radiance field's colour means nothing.

use anerf_core::gaussians::sh;
use anerf_core::geometry::skinning::points_tensor;
use anerf_core::model::{AnimatableNerf, CanonicalInputs};
use anerf_core::render::composite;
use anerf_core::tensor::{from_rows, to_host};
use anerf_eval::gltf_export::top_weights;
use glam::{Quat, Vec3};

use super::store::{AvatarInfo, BakedAvatar};
use crate::mesh::CanonicalMesh;

/// Opacity of a fresh Gaussian (as a logit): mostly opaque, so that the surface is closed from the start.
const START_OPACITY: f32 = 0.9;
/// Standard deviation across the surface relative to the spacing of the Gaussians.
const THICKNESS: f32 = 0.1;

/// How far outside a vertex, along its normal, the probing ray starts (metres); it ends as far inside.
const REACH: f32 = 0.05;
/// Samples along a probing ray.
const PROBE_SAMPLES: usize = 32;
/// A probe that gathers less opacity than this found no surface: the vertex keeps its own place and
/// colour.
const PROBE_HIT: f32 = 0.5;

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
            .forward(p, points_tensor(&dirs, &device), appearance)
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

/// Gaussians on the vertices of `surface` (a canonical mesh with `w^can` and colours), at most `budget`,
/// `spacing` metres apart (the mesh's voxel, widened by the thinning), colour harmonics of `sh_degree`;
/// placed and coloured by `probes` (one per vertex) where they found the surface.
pub fn on_surface(
    surface: &CanonicalMesh,
    probes: &[SurfaceProbe],
    spacing: f32,
    budget: usize,
    sh_degree: usize,
    source: String,
) -> BakedAvatar {
    let vertices = surface.mesh.vertices.len();
    assert_eq!(probes.len(), vertices, "one probe per vertex");
    let stride = vertices.div_ceil(budget.max(1)).max(1);
    let normals = surface.mesh.vertex_normals();
    let chosen: Vec<usize> = (0..vertices).step_by(stride).collect();
    let hit = |v: usize| probes[v].opacity >= PROBE_HIT;
    // Thinning by `stride` vertices spreads them √stride times wider over the surface.
    let tangent = (spacing * (stride as f32).sqrt()).ln();
    let across = (spacing * (stride as f32).sqrt() * THICKNESS).ln();
    let k = surface.num_joints;
    let rows: Vec<f32> = chosen
        .iter()
        .flat_map(|&v| surface.weights[v * k..(v + 1) * k].to_vec())
        .collect();
    let (skin_joints, skin_weights) = top_weights(&rows, k);
    let width = 3 * sh::coefficients(sh_degree);
    let colours = chosen
        .iter()
        .flat_map(|&v| {
            let mut row = vec![0.0; width];
            let colour = if hit(v) {
                probes[v].colour
            } else {
                surface.colors[v]
            };
            for (c, value) in colour.iter().enumerate() {
                row[c] = (value - 0.5) / sh::C0;
            }
            row
        })
        .collect();
    let logit = (START_OPACITY / (1.0 - START_OPACITY)).ln();
    BakedAvatar {
        info: AvatarInfo {
            gaussians: chosen.len(),
            sh_degree,
            joints: k,
            source,
            steps: 0,
            seconds: 0.0,
            training_psnr: 0.0,
        },
        means: chosen
            .iter()
            .map(|&v| {
                let p = if hit(v) {
                    probes[v].point
                } else {
                    surface.mesh.vertices[v]
                };
                p.to_array()
            })
            .collect(),
        log_scales: vec![[tangent, tangent, across]; chosen.len()],
        rotations: chosen
            .iter()
            .map(|&v| {
                let n = normals[v];
                let q = if n.length_squared() > 0.0 {
                    Quat::from_rotation_arc(Vec3::Z, n.normalize())
                } else {
                    Quat::IDENTITY
                };
                [q.w, q.x, q.y, q.z]
            })
            .collect(),
        opacity_logits: vec![logit; chosen.len()],
        colours,
        skin_joints,
        skin_weights,
    }
}
