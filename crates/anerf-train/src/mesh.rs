//! Meshes of a trained run: marching cubes on the canonical density, per-vertex blend weights from the
//! canonical blend-weight field `w^can`, vertex colours from the radiance field, and reposing by forward LBS
//! (paper §3.4 "3D shape generation").

use anerf_core::body::BlendWeightVolume;
use anerf_core::geometry::skinning::points_tensor;
use anerf_core::geometry::{forward_lbs_point, Aabb, BoneTransforms, GlobalTransform};
use anerf_core::mesh::{marching_cubes, ScalarGrid, TriMesh};
use anerf_core::model::{AnimatableNerf, CanonicalInputs, PositionalEncoding};
use anerf_core::tensor::to_host;
use anyhow::{Context, Result};
use burn::prelude::*;
use glam::Vec3;

/// Grid points farther than this from the canonical body (the volume's distance channel, metres) are
/// not evaluated and count as empty (the reference's mesh extraction culls at 0.1 m).
pub const MESH_CULL_DISTANCE: f32 = 0.1;

/// What `anerf mesh` extracts.
#[derive(Debug, Clone)]
pub struct MeshJob {
    /// Voxel size, metres (the paper: 0.005).
    pub voxel: f32,
    /// Iso level on raw density (the reference: 5).
    pub level: f32,
    /// Taubin smoothing iterations (0 = none).
    pub smooth: usize,
    /// Dataset frames to repose the canonical mesh to.
    pub frames: Vec<usize>,
}

/// A canonical mesh with what it needs to be reposed and coloured.
#[derive(Debug, Clone)]
pub struct CanonicalMesh {
    /// Canonical (T-pose) surface, metres.
    pub mesh: TriMesh,
    /// `V × K` blend weights `w^can` at the vertices, rows summing to 1.
    pub weights: Vec<f32>,
    pub num_joints: usize,
    /// Per-vertex colour in `[0, 1]`.
    pub colors: Vec<[f32; 3]>,
}

/// Evaluates `f` on `points` in chunks of `chunk` rows and concatenates the host results.
fn batched(
    points: &[Vec3],
    chunk: usize,
    device: &Device,
    mut f: impl FnMut(Tensor<2>) -> Tensor<2>,
) -> Vec<f32> {
    let mut out = Vec::new();
    for part in points.chunks(chunk.max(1)) {
        out.extend(to_host(f(points_tensor(part, device))));
    }
    out
}

/// Marching cubes at `job.voxel` metres over the canonical box on the raw density at iso `job.level` (the
/// reference uses 5), then `w^can` and colours (appearance code `appearance`, viewed along the inward normal) at the
/// vertices.
pub fn canonical_mesh(
    model: &AnimatableNerf,
    canonical: &CanonicalInputs,
    canonical_volume: &BlendWeightVolume,
    job: &MeshJob,
    appearance: usize,
    chunk: usize,
    device: &Device,
) -> Result<CanonicalMesh> {
    let (voxel, level) = (job.voxel, job.level);
    let bounds: Aabb = canonical.bounds;
    let dims = (bounds.size() / voxel).ceil().as_uvec3() + 1;
    let dims = [dims.x as usize, dims.y as usize, dims.z as usize];
    let node =
        |i: usize, j: usize, k: usize| bounds.min + Vec3::new(i as f32, j as f32, k as f32) * voxel;
    // Only nodes near the body reach the network; the rest stay empty.
    let mut near = Vec::new();
    let mut index = Vec::new();
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                let p = node(i, j, k);
                if canonical_volume.sample(p)[canonical_volume.num_joints] < MESH_CULL_DISTANCE {
                    near.push(p);
                    index.push((i * dims[1] + j) * dims[2] + k);
                }
            }
        }
    }
    let density = batched(&near, chunk, device, |p| {
        model.canonical_density(p, canonical)
    });
    // Marching cubes takes "inside" as below the iso value: negate the density. A one-node empty border
    // keeps the surface closed where the body touches the box.
    let mut values = vec![0.0f32; dims.iter().product()];
    for (&i, d) in index.iter().zip(&density) {
        values[i] = -d;
    }
    let padded = [dims[0] + 2, dims[1] + 2, dims[2] + 2];
    let mut grid_values = vec![0.0f32; padded.iter().product()];
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                grid_values[((i + 1) * padded[1] + j + 1) * padded[2] + k + 1] =
                    values[(i * dims[1] + j) * dims[2] + k];
            }
        }
    }
    let grid = ScalarGrid::new(
        bounds.min - Vec3::splat(voxel),
        Vec3::splat(voxel),
        padded,
        grid_values,
    )
    .context("density grid")?;
    let mesh = marching_cubes(&grid, -level);
    if mesh.faces.is_empty() {
        anyhow::bail!("no surface at density level {level}: the model has no density above it in the canonical box");
    }
    let k = model.blend.num_joints();
    let weights = batched(&mesh.vertices, chunk, device, |p| {
        model.canonical_weights(p, canonical)
    });
    let normals = mesh.vertex_normals();
    let dir_enc = PositionalEncoding {
        frequencies: model.config().dir_frequencies,
    };
    let xyz_enc = PositionalEncoding {
        frequencies: model.config().xyz_frequencies,
    };
    let mut colors = Vec::with_capacity(mesh.vertices.len());
    for (pts, nrm) in mesh
        .vertices
        .chunks(chunk.max(1))
        .zip(normals.chunks(chunk.max(1)))
    {
        let view: Vec<Vec3> = nrm.iter().map(|n| -*n).collect();
        let rgb = model.nerf.forward(
            xyz_enc.encode(points_tensor(pts, device)),
            dir_enc.encode(points_tensor(&view, device)),
            appearance,
        );
        colors.extend(to_host(rgb.rgb).chunks(3).map(|c| [c[0], c[1], c[2]]));
    }
    Ok(CanonicalMesh {
        mesh,
        weights,
        num_joints: k,
        colors,
    })
}

/// Reposes canonical vertices with their blend weights (`V × K`) by forward LBS, then to world space.
pub fn repose(
    vertices: &[Vec3],
    weights: &[f32],
    bones: &BoneTransforms,
    global: &GlobalTransform,
) -> Result<Vec<Vec3>> {
    let k = bones.len();
    vertices
        .iter()
        .zip(weights.chunks(k))
        .enumerate()
        .map(|(i, (v, w))| {
            let posed = forward_lbs_point(*v, w, bones).with_context(|| format!("vertex {i}"))?;
            Ok(global.pose_to_world(posed))
        })
        .collect()
}
