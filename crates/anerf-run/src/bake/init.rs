//! The avatar a bake starts from: one flat Gaussian per vertex of the canonical mesh (evenly thinned to
//! the budget), in the surface's tangent plane, skinned as the NeRF skins the vertex, placed where the
//! NeRF's surface lies along the vertex normal and coloured as the NeRF shows it from there
//! ([`crate::mesh::probe`]): the iso-surface of raw density lies in the haze outside the visible body.

use anerf_core::gaussians::sh;
use anerf_eval::gltf_export::top_weights;
use glam::{Quat, Vec3};

use super::store::{AvatarInfo, BakedAvatar};
use crate::mesh::probe::{SurfaceProbe, PROBE_HIT};
use crate::mesh::CanonicalMesh;

/// Opacity of a fresh Gaussian (as a logit): mostly opaque, so that the surface is closed from the start.
const START_OPACITY: f32 = 0.9;
/// Standard deviation across the surface relative to the spacing of the Gaussians.
const THICKNESS: f32 = 0.1;

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
