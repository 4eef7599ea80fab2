//! The exported avatar's mesh as a real-time engine shows it: the canonical surface with its NeRF colours
//! and the four largest canonical blend weights of each vertex (what `anerf export` writes into the glb),
//! posed by linear blend skinning and rasterised without lighting (`anerf eval --mesh`).

use anerf_core::geometry::{BoneTransforms, Camera, GlobalTransform, PixelConvention};
use anerf_core::mesh::TriMesh;
use anerf_core::model::AnimatableNerf;
use anerf_eval::gltf_export::top_weights;
use anerf_eval::mesh_raster::rasterize_mesh;
use anyhow::Result;

use super::{canonical_surface, repose, MeshJob};
use anerf_train::experiment::Experiment;

/// The glb's mesh on the host.
#[derive(Debug, Clone)]
pub struct SkinnedSurface {
    /// Canonical (T-pose) surface, metres.
    pub mesh: TriMesh,
    /// Per-vertex colour in `[0, 1]`, as the glb stores it (before its conversion to linear).
    pub colours: Vec<[f32; 3]>,
    /// `V × K` blend weights: each vertex's four largest `w^can`, renormalised, zeros elsewhere.
    pub weights: Vec<f32>,
}

impl SkinnedSurface {
    /// The run's canonical surface at `job`'s voxel, level and smoothing, skinned as the export skins it.
    pub fn extract(model: &AnimatableNerf, exp: &Experiment, job: &MeshJob) -> Result<Self> {
        let cm = canonical_surface(model, exp, job)?;
        let k = cm.num_joints;
        let (joints, weights) = top_weights(&cm.weights, k);
        let mut dense = vec![0.0f32; cm.mesh.vertices.len() * k];
        for (row, (j, w)) in dense.chunks_exact_mut(k).zip(joints.iter().zip(&weights)) {
            for (&joint, &weight) in j.iter().zip(w) {
                row[joint as usize] += weight;
            }
        }
        Ok(Self {
            mesh: cm.mesh,
            colours: cm.colors,
            weights: dense,
        })
    }

    /// The mesh posed by `bones` (canonical → pose space) and `global` (pose space → world) seen by
    /// `camera`: `[H·W]` row-major colour on black and coverage.
    pub fn pixels(
        &self,
        bones: &BoneTransforms,
        global: &GlobalTransform,
        camera: &Camera,
    ) -> Result<Vec<[f32; 4]>> {
        let posed = repose(&self.mesh.vertices, &self.weights, bones, global)?;
        Ok(rasterize_mesh(
            &posed,
            &self.mesh.faces,
            &self.colours,
            camera,
            PixelConvention::Integer,
        ))
    }
}
