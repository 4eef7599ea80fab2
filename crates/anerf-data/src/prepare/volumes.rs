//! Blend-weight volumes (docs/REFERENCE.md §1.3): on a grid of 0.025 m voxels around the body, the skinning
//! weights of the nearest body point and the distance to it, `K + 1` channels per node.

use anerf_core::geometry::Aabb;
use anerf_core::geometry::BlendWeightVolume;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::nearest::MeshIndex;
use crate::subject::SkinningWeights;

/// Which body point a node takes its weights from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NearestMethod {
    /// The nearest point on the surface, weights interpolated barycentrically from its face's vertices
    /// (the reference's `tbw.npy`; continuous across faces).
    #[default]
    Surface,
    /// The nearest vertex and its weights (the reference's per-frame `bweights/`).
    Vertex,
}

/// Grid spacing and padding of a volume (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VolumeGrid {
    pub voxel: f32,
    pub padding: f32,
}

impl Default for VolumeGrid {
    /// The reference's 0.025 m voxels and 0.05 m padding.
    fn default() -> Self {
        Self {
            voxel: 0.025,
            padding: 0.05,
        }
    }
}

impl VolumeGrid {
    /// Bounds and node counts around `points`: the padded box, grown at its max side so that the nodes sit
    /// exactly `voxel` apart (node 0 at the padded min, the last node at or just past the padded max).
    pub fn layout(&self, points: &[Vec3]) -> (Aabb, [usize; 3]) {
        let b = Aabb::from_points(points.iter().copied())
            .expect("a body has vertices")
            .padded(self.padding);
        let size = b.size();
        let dims = [0, 1, 2].map(|a| ((size[a] / self.voxel - 1e-4).ceil().max(1.0) as usize) + 1);
        let max = b.min
            + Vec3::new(
                dims[0] as f32 - 1.0,
                dims[1] as f32 - 1.0,
                dims[2] as f32 - 1.0,
            ) * self.voxel;
        (Aabb { min: b.min, max }, dims)
    }
}

/// Computes the volume around the mesh `vertices`/`faces` (in the volume's frame) with per-vertex
/// `weights`, on all cores.
pub fn compute_volume(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    weights: &SkinningWeights,
    method: NearestMethod,
    grid: VolumeGrid,
) -> BlendWeightVolume {
    let index = match method {
        NearestMethod::Surface => MeshIndex::triangles(vertices, faces),
        NearestMethod::Vertex => MeshIndex::vertices(vertices),
    };
    let (bounds, dims) = grid.layout(vertices);
    let k = weights.num_joints();
    let channels = k + 1;
    let plane = dims[1] * dims[2] * channels;
    let mut data = vec![0.0f32; dims[0] * plane];
    data.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(i, slab)| {
            for j in 0..dims[1] {
                // The previous node's nearest primitive bounds this node's distance: searching only within
                // it prunes most of the hierarchy and gives the same answer.
                let mut previous: Option<usize> = None;
                for l in 0..dims[2] {
                    let p = bounds.min + Vec3::new(i as f32, j as f32, l as f32) * grid.voxel;
                    let out = &mut slab[(j * dims[2] + l) * channels..][..channels];
                    let bound = previous.map_or(f32::INFINITY, |n| index.distance_to(n, p));
                    let c = index
                        .closest_within(p, bound)
                        .or_else(|| index.closest(p))
                        .expect("a body has vertices");
                    previous = Some(c.index);
                    let verts: [usize; 3] = match method {
                        NearestMethod::Surface => faces[c.index].map(|v| v as usize),
                        NearestMethod::Vertex => [c.index; 3],
                    };
                    for (b, v) in c.barycentric.iter().zip(verts) {
                        if *b != 0.0 {
                            for (o, w) in out[..k].iter_mut().zip(weights.row(v)) {
                                *o += b * w;
                            }
                        }
                    }
                    out[k] = c.distance;
                }
            }
        });
    BlendWeightVolume::new(bounds, dims, k, data).expect("computed volumes are well formed")
}
