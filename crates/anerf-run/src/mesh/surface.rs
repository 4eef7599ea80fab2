//! Meshes of a trained run: marching cubes on the canonical density, per-vertex blend weights from the
//! canonical blend-weight field `w^can`, vertex colours from the radiance field, and reposing by forward LBS
//! (paper §3.4 "3D shape generation").

use anerf_core::geometry::skinning::{points_tensor, world_to_pose};
use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{forward_lbs_points, Aabb, BoneTransforms, GlobalTransform};
use anerf_core::mesh::{marching_cubes, ScalarGrid, TriMesh};
use anerf_core::model::codes::CodeRows;
use anerf_core::model::{AnimatableNerf, CanonicalInputs, FrameInputs};
use anerf_core::tensor::to_host;
use anerf_data::visual_hull::VisualHull;
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
    /// Dataset frames to extract the reference's posed meshes of ([`posed_mesh`]).
    pub posed_frames: Vec<usize>,
    /// Carve the posed meshes' grids with the training views' visual hull, as the reference does.
    pub carve: bool,
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

/// Marching cubes at iso `level` on raw density over the nodes `voxel` metres apart from `bounds.min`
/// covering `bounds`: only nodes `keep` accepts are evaluated (`density` maps a batch of node positions to
/// their raw σ), the others count as empty, and a one-node empty border closes the surface where the
/// body touches the box.
pub fn density_surface(
    bounds: Aabb,
    voxel: f32,
    level: f32,
    keep: impl Fn(Vec3) -> bool,
    density: impl FnOnce(&[Vec3]) -> Vec<f32>,
) -> Result<TriMesh> {
    let dims = (bounds.size() / voxel).ceil().as_uvec3() + 1;
    let dims = [dims.x as usize, dims.y as usize, dims.z as usize];
    let padded = [dims[0] + 2, dims[1] + 2, dims[2] + 2];
    let mut kept = Vec::new();
    let mut index = Vec::new();
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                let p = bounds.min + Vec3::new(i as f32, j as f32, k as f32) * voxel;
                if keep(p) {
                    kept.push(p);
                    index.push(((i + 1) * padded[1] + j + 1) * padded[2] + k + 1);
                }
            }
        }
    }
    let density = density(&kept);
    // Marching cubes takes "inside" as below the iso value: negate the density.
    let mut values = vec![0.0f32; padded.iter().product()];
    for (&i, d) in index.iter().zip(&density) {
        values[i] = -d;
    }
    let grid = ScalarGrid::new(
        bounds.min - Vec3::splat(voxel),
        Vec3::splat(voxel),
        padded,
        values,
    )
    .context("density grid")?;
    let mesh = marching_cubes(&grid, -level);
    if mesh.faces.is_empty() {
        anyhow::bail!(
            "no surface at density level {level}: the model has no density above it in the box"
        );
    }
    Ok(mesh)
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
    // Only nodes near the body reach the network; the rest stay empty.
    let mesh = density_surface(
        canonical.bounds,
        job.voxel,
        job.level,
        |p| canonical_volume.distance_at(p) < MESH_CULL_DISTANCE,
        |nodes| {
            batched(nodes, chunk, device, |p| {
                model.canonical_density(p, canonical)
            })
        },
    )?;
    let k = model.blend.num_joints();
    let weights = batched(&mesh.vertices, chunk, device, |p| {
        model.canonical_weights(p, canonical)
    });
    let normals = mesh.vertex_normals();
    let mut colors = Vec::with_capacity(mesh.vertices.len());
    for (pts, nrm) in mesh
        .vertices
        .chunks(chunk.max(1))
        .zip(normals.chunks(chunk.max(1)))
    {
        let view: Vec<Vec3> = nrm.iter().map(|n| -*n).collect();
        let rgb = model.nerf.forward(
            points_tensor(pts, device),
            points_tensor(&view, device),
            &CodeRows::One(appearance),
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
    Ok(forward_lbs_points(vertices, weights, bones)?
        .into_iter()
        .map(|p| global.pose_to_world(p))
        .collect())
}

/// A frame's posed body as mesh extraction needs it.
pub struct PosedFrame<'a> {
    pub inputs: &'a FrameInputs,
    /// The frame's pose-space volume on the host (its distance channel culls grid nodes).
    pub volume: &'a BlendWeightVolume,
    /// World-space box around the posed body (metres).
    pub bounds: Aabb,
}

/// The reference's posed mesh of a frame (docs/REFERENCE.md §5), in world space (metres): nodes `job.voxel` apart
/// over the frame's world box, kept when nearer than [`MESH_CULL_DISTANCE`] to the posed body and, with
/// `hull`, inside every training view's silhouette; a node's raw density is the canonical NeRF's at the
/// node warped back to canonical space with the frame's blend weights.
pub fn posed_mesh(
    model: &AnimatableNerf,
    canonical: &CanonicalInputs,
    body: &PosedFrame,
    hull: Option<&VisualHull>,
    job: &MeshJob,
    chunk: usize,
) -> Result<TriMesh> {
    let (frame, frame_volume) = (body.inputs, body.volume);
    let global = frame.global;
    let device = model.device();
    density_surface(
        body.bounds,
        job.voxel,
        job.level,
        |x| {
            frame_volume.distance_at(global.world_to_pose(x)) < MESH_CULL_DISTANCE
                && hull.is_none_or(|h| h.contains(x))
        },
        |nodes| {
            batched(nodes, chunk, &device, |x| {
                let p = world_to_pose(x, &global);
                let prior = frame.volume.sample(p.clone()).weights;
                let weights = model.frame_weights(p.clone(), prior, frame.code);
                model.canonical_density(model.frame_bones(frame).inverse(p, weights), canonical)
            })
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ball of radius 0.3 m whose density falls linearly through the iso level at its surface, carved by
    /// the half-space `x < 0`: the surface is a closed half ball — the flat cap is where carving cut it —
    /// with the half ball's area and volume.
    #[test]
    fn carving_closes_the_surface_along_the_cut() {
        let (r, voxel, level) = (0.3f32, 0.01f32, 5.0f32);
        let bounds = Aabb {
            min: Vec3::splat(-0.4),
            max: Vec3::splat(0.4),
        };
        let density = |nodes: &[Vec3]| -> Vec<f32> {
            nodes
                .iter()
                .map(|p| level + 100.0 * (r - p.length()))
                .collect()
        };
        let whole = density_surface(bounds, voxel, level, |_| true, density).unwrap();
        let half = density_surface(bounds, voxel, level, |p| p.x < 0.0, density).unwrap();
        assert!(whole.edge_report().is_watertight() && half.edge_report().is_watertight());
        assert_eq!(
            (whole.euler_characteristic(), half.euler_characteristic()),
            (2, 2)
        );
        let pi = std::f64::consts::PI;
        let r = r as f64;
        let rel = |got: f64, want: f64| (got - want).abs() / want;
        assert!(
            rel(whole.area(), 4.0 * pi * r * r) < 0.02,
            "{}",
            whole.area()
        );
        assert!(rel(whole.signed_volume().abs(), 4.0 / 3.0 * pi * r.powi(3)) < 0.02);
        // Half the sphere plus the cap (cut within a voxel of x = 0).
        let cap = pi * r * r;
        assert!(
            rel(half.area(), 2.0 * pi * r * r + cap) < 0.05,
            "{}",
            half.area()
        );
        assert!(rel(half.signed_volume().abs(), 2.0 / 3.0 * pi * r.powi(3)) < 0.05);
        let max_x = half.vertices.iter().map(|v| v.x).fold(f32::MIN, f32::max);
        assert!(max_x <= voxel + 1e-6, "{max_x}");
    }
}
