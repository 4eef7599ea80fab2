//! Clothing: a rendered surface that differs from the body the method is given, as a real person differs
//! from the SMPL fit of them. The garment is the body's surface pushed out along its normals (folds up to
//! `offset` over torso, arms and legs; none on head, forearms, hands and feet) and skinned with sharp
//! weights, while the subject's files hold the bare body with diffused weights.

use anerf_core::mesh::TriMesh;
use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::body::{joint::*, skinning_weights_at, Body, BodyShape, NUM_JOINTS};
use super::SynthError;
use crate::subject::SkinningWeights;

/// How the rendered garment differs from the given body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothingSpec {
    /// Largest distance of the garment from the skin (metres).
    pub offset: f32,
    /// Wavelength of the garment's folds along the body (metres).
    pub fold_wavelength: f32,
    /// Blending length (metres) of the diffused weights written to `lbs/weights.npy`; the garment moves
    /// with the body's own `skinning_softness`.
    pub prior_softness: f32,
}

impl ClothingSpec {
    /// Up to 2 cm of cloth in 25 cm folds; given weights blended over 6 cm.
    pub fn loose() -> Self {
        Self {
            offset: 0.02,
            fold_wavelength: 0.25,
            prior_softness: 0.06,
        }
    }

    /// Checks every length (metres).
    pub fn validate(&self) -> Result<(), SynthError> {
        SynthError::check_ranges(&[
            ("clothing.offset", self.offset, 0.0, 0.1),
            ("clothing.fold_wavelength", self.fold_wavelength, 0.02, 5.0),
            ("clothing.prior_softness", self.prior_softness, 0.001, 1.0),
        ])
    }
}

/// Joints whose parts the garment covers (torso, thighs, shins, collars, upper arms).
const COVERED: [usize; 12] = [
    PELVIS, SPINE1, SPINE2, SPINE3, L_HIP, R_HIP, L_KNEE, R_KNEE, L_COLLAR, R_COLLAR, L_SHOULDER,
    R_SHOULDER,
];

/// Distance of the garment from the skin at canonical vertex `p` whose weights are `w` (metres): the
/// covered joints' share of the weights times a fold pattern between 0.4 and 1 of `spec.offset`.
pub fn garment_offset(spec: &ClothingSpec, p: Vec3, w: &[f32]) -> f32 {
    let mut covered = [false; NUM_JOINTS];
    for k in COVERED {
        covered[k] = true;
    }
    let coverage: f32 = w
        .iter()
        .zip(covered)
        .filter(|(_, c)| *c)
        .map(|(w, _)| w)
        .sum();
    let k = std::f32::consts::TAU / spec.fold_wavelength;
    let fold = 0.7 + 0.3 * (k * p.y).sin() * (0.5 * k * (p.x + p.z) + 1.0).cos();
    spec.offset * coverage.clamp(0.0, 1.0) * fold
}

/// The garment over `body` (same vertices, faces and weights order) and the diffused weights of the bare
/// body that the method is given.
pub fn dress(
    body: &Body,
    shape: &BodyShape,
    spec: &ClothingSpec,
) -> Result<(Body, SkinningWeights), SynthError> {
    spec.validate()?;
    let vertices: Vec<Vec3> = body
        .mesh
        .vertices
        .iter()
        .zip(&body.normals)
        .enumerate()
        .map(|(v, (&p, &n))| p + n * garment_offset(spec, p, body.weights.row(v)))
        .collect();
    let mesh = TriMesh {
        vertices,
        faces: body.mesh.faces.clone(),
    };
    let normals = mesh.vertex_normals();
    let garment = Body {
        skeleton: body.skeleton.clone(),
        mesh,
        normals,
        weights: body.weights.clone(),
    };
    let prior = skinning_weights_at(shape, &body.mesh.vertices, spec.prior_softness)?;
    Ok((garment, prior))
}
