//! The procedural body: an SMPL-ordered 24-joint skeleton with adult proportions, a closed surface from
//! marching cubes over a smooth union of capsules and ellipsoids, and smooth skinning weights.
//!
//! Canonical space is SMPL's: metres, T-pose, pelvis at the origin, `+y` up, `+x` towards the body's
//! left, `+z` forwards.

use anerf_core::geometry::Skeleton;
use anerf_core::mesh::{marching_cubes, ScalarGrid, TriMesh};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::SynthError;
use crate::subject::SkinningWeights;

/// Number of joints (SMPL's).
pub const NUM_JOINTS: usize = 24;

/// SMPL joint indices used by the generator (docs/REFERENCE.md §2).
pub mod joint {
    pub const PELVIS: usize = 0;
    pub const L_HIP: usize = 1;
    pub const R_HIP: usize = 2;
    pub const SPINE1: usize = 3;
    pub const L_KNEE: usize = 4;
    pub const R_KNEE: usize = 5;
    pub const SPINE2: usize = 6;
    pub const L_ANKLE: usize = 7;
    pub const R_ANKLE: usize = 8;
    pub const SPINE3: usize = 9;
    pub const L_FOOT: usize = 10;
    pub const R_FOOT: usize = 11;
    pub const NECK: usize = 12;
    pub const L_COLLAR: usize = 13;
    pub const R_COLLAR: usize = 14;
    pub const HEAD: usize = 15;
    pub const L_SHOULDER: usize = 16;
    pub const R_SHOULDER: usize = 17;
    pub const L_ELBOW: usize = 18;
    pub const R_ELBOW: usize = 19;
    pub const L_WRIST: usize = 20;
    pub const R_WRIST: usize = 21;
    pub const L_HAND: usize = 22;
    pub const R_HAND: usize = 23;
}
use joint::*;

/// Proportions of the procedural adult (metres), limb thickness and surface resolution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BodyShape {
    /// Pelvis → hip joint, sideways.
    pub hip_half_width: f32,
    /// Hip → knee.
    pub thigh: f32,
    /// Knee → ankle.
    pub shin: f32,
    /// Ankle → toe joint, forwards.
    pub foot: f32,
    /// Pelvis → neck joint.
    pub spine: f32,
    /// Neck → head joint.
    pub neck: f32,
    /// Body centre → shoulder joint, sideways.
    pub shoulder_half_width: f32,
    /// Shoulder → elbow.
    pub upper_arm: f32,
    /// Elbow → wrist.
    pub forearm: f32,
    /// Wrist → hand (finger) joint.
    pub hand: f32,
    /// Multiplies every limb and torso radius (1 = average adult).
    pub thickness: f32,
    /// Grid spacing of the marching cubes that make the surface (smaller = more vertices).
    pub voxel: f32,
    /// Length scale (metres) over which skinning weights blend between neighbouring parts.
    pub skinning_softness: f32,
}

impl Default for BodyShape {
    fn default() -> Self {
        Self {
            hip_half_width: 0.09,
            thigh: 0.42,
            shin: 0.40,
            foot: 0.13,
            spine: 0.50,
            neck: 0.09,
            shoulder_half_width: 0.18,
            upper_arm: 0.27,
            forearm: 0.25,
            hand: 0.09,
            thickness: 1.0,
            voxel: 0.02,
            skinning_softness: 0.01,
        }
    }
}

impl BodyShape {
    /// Checks that every length is positive and finite, and that the voxel resolves the thinnest parts.
    pub fn validate(&self) -> Result<(), SynthError> {
        let lengths = [
            ("hip_half_width", self.hip_half_width),
            ("thigh", self.thigh),
            ("shin", self.shin),
            ("foot", self.foot),
            ("spine", self.spine),
            ("neck", self.neck),
            ("shoulder_half_width", self.shoulder_half_width),
            ("upper_arm", self.upper_arm),
            ("forearm", self.forearm),
            ("hand", self.hand),
            ("thickness", self.thickness),
            ("voxel", self.voxel),
            ("skinning_softness", self.skinning_softness),
        ];
        for (name, v) in lengths {
            if !(v.is_finite() && v > 0.0 && v < 5.0) {
                return Err(SynthError::invalid(
                    format!("body.{name}"),
                    format!("{v} (expected 0 < value < 5)"),
                ));
            }
        }
        let thinnest = 0.02 * self.thickness;
        if self.voxel > 1.5 * thinnest {
            return Err(SynthError::invalid(
                "body.voxel",
                format!(
                    "{} m cannot resolve fingers {thinnest} m thick (use at most {})",
                    self.voxel,
                    1.5 * thinnest
                ),
            ));
        }
        Ok(())
    }

    /// Rest joints in canonical space (metres), SMPL order.
    pub fn rest_joints(&self) -> [Vec3; NUM_JOINTS] {
        let mut j = [Vec3::ZERO; NUM_JOINTS];
        let s = self.spine;
        j[SPINE1] = Vec3::new(0.0, 0.22 * s, -0.01);
        j[SPINE2] = Vec3::new(0.0, 0.48 * s, -0.005);
        j[SPINE3] = Vec3::new(0.0, 0.60 * s, 0.0);
        j[NECK] = Vec3::new(0.0, s, -0.01);
        j[HEAD] = j[NECK] + Vec3::new(0.0, self.neck, 0.015);
        for (side, [hip, knee, ankle, foot, collar, shoulder, elbow, wrist, hand]) in [
            (
                1.0,
                [
                    L_HIP, L_KNEE, L_ANKLE, L_FOOT, L_COLLAR, L_SHOULDER, L_ELBOW, L_WRIST, L_HAND,
                ],
            ),
            (
                -1.0,
                [
                    R_HIP, R_KNEE, R_ANKLE, R_FOOT, R_COLLAR, R_SHOULDER, R_ELBOW, R_WRIST, R_HAND,
                ],
            ),
        ] {
            j[hip] = Vec3::new(side * self.hip_half_width, -0.08, 0.0);
            j[knee] = j[hip] - Vec3::Y * self.thigh;
            j[ankle] = j[knee] - Vec3::Y * self.shin;
            j[foot] = j[ankle] + Vec3::new(0.0, -0.05, self.foot);
            j[collar] = Vec3::new(side * 0.07, 0.86 * s, -0.01);
            j[shoulder] = Vec3::new(side * self.shoulder_half_width, 0.88 * s, -0.01);
            j[elbow] = j[shoulder] + Vec3::X * side * self.upper_arm;
            j[wrist] = j[elbow] + Vec3::X * side * self.forearm;
            j[hand] = j[wrist] + Vec3::X * side * self.hand;
        }
        j
    }
}

/// A solid primitive of the body, in canonical space (metres).
#[derive(Debug, Clone, Copy)]
enum Primitive {
    /// Segment `a → b` swept by a radius going linearly from `ra` to `rb`.
    Capsule {
        a: Vec3,
        b: Vec3,
        ra: f32,
        rb: f32,
    },
    Ellipsoid {
        centre: Vec3,
        radii: Vec3,
    },
}

impl Primitive {
    /// Signed distance (negative inside), exact for capsules of constant radius and a close bound for
    /// tapered capsules and ellipsoids; smooth everywhere except on the segment or the centre.
    fn distance(&self, p: Vec3) -> f32 {
        match *self {
            Primitive::Capsule { a, b, ra, rb } => {
                let ab = b - a;
                let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
                (p - (a + ab * t)).length() - (ra + (rb - ra) * t)
            }
            Primitive::Ellipsoid { centre, radii } => {
                let q = p - centre;
                let k0 = (q / radii).length();
                let k1 = (q / (radii * radii)).length();
                if k1 == 0.0 {
                    -radii.min_element()
                } else {
                    k0 * (k0 - 1.0) / k1
                }
            }
        }
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        match *self {
            Primitive::Capsule { a, b, ra, rb } => {
                let r = Vec3::splat(ra.max(rb));
                (a.min(b) - r, a.max(b) + r)
            }
            Primitive::Ellipsoid { centre, radii } => (centre - radii, centre + radii),
        }
    }
}

/// A primitive and the joint whose transform moves it.
#[derive(Debug, Clone, Copy)]
struct Part {
    joint: usize,
    shape: Primitive,
}

/// Polynomial smooth minimum: equals `min(a, b)` when they differ by more than `k`, rounds the crease
/// within.
fn smooth_min(a: f32, b: f32, k: f32) -> f32 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// The procedural body in canonical space.
#[derive(Debug, Clone)]
pub struct Body {
    pub skeleton: Skeleton,
    /// Closed, outward-oriented surface (metres, canonical space).
    pub mesh: TriMesh,
    /// Unit outward normals of the smooth surface at the vertices (canonical space).
    pub normals: Vec<Vec3>,
    /// Per-vertex weights over the 24 joints, rows summing to 1.
    pub weights: SkinningWeights,
}

/// Builds the body of `shape`.
pub fn build_body(shape: &BodyShape) -> Result<Body, SynthError> {
    shape.validate()?;
    let joints = shape.rest_joints();
    let parts = parts(shape, &joints);
    let blend = 0.025 * shape.thickness;
    let sdf = |p: Vec3| {
        parts
            .iter()
            .map(|part| part.shape.distance(p))
            .reduce(|a, b| smooth_min(a, b, blend))
            .unwrap_or(f32::INFINITY)
    };
    let (lo, hi) = parts
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            let (a, b) = p.shape.bounds();
            (lo.min(a), hi.max(b))
        });
    let margin = Vec3::splat(2.0 * shape.voxel);
    let origin = lo - margin;
    let span = hi + margin - origin;
    let dims = (span / shape.voxel)
        .ceil()
        .as_uvec3()
        .to_array()
        .map(|d| d as usize + 1);
    let grid = ScalarGrid::from_fn(origin, Vec3::splat(shape.voxel), dims, sdf)
        .map_err(|e| SynthError::invalid("body", e.to_string()))?;
    let mesh = marching_cubes(&grid, 0.0);
    let eps = 0.25 * shape.voxel;
    let normals = mesh
        .vertices
        .iter()
        .map(|&p| {
            let d = |o: Vec3| sdf(p + o) - sdf(p - o);
            Vec3::new(d(Vec3::X * eps), d(Vec3::Y * eps), d(Vec3::Z * eps)).normalize_or_zero()
        })
        .collect();
    let weights = skinning_weights(&mesh.vertices, &parts, shape.skinning_softness)?;
    let skeleton = Skeleton::from_parent_table(joints.to_vec(), &Skeleton::SMPL_PARENTS)
        .map_err(|e| SynthError::invalid("body", e.to_string()))?;
    Ok(Body {
        skeleton,
        mesh,
        normals,
        weights,
    })
}

/// Weights of `shape`'s parts at `vertices` (canonical, metres) with blending length `softness`: the
/// weights [`build_body`] gives its own vertices when `softness = shape.skinning_softness`.
pub fn skinning_weights_at(
    shape: &BodyShape,
    vertices: &[Vec3],
    softness: f32,
) -> Result<SkinningWeights, SynthError> {
    skinning_weights(vertices, &parts(shape, &shape.rest_joints()), softness)
}

/// Weights from each joint's distance `d_k` to the surface of its own parts: `softmax(−d_k / softness)`,
/// so a vertex follows the part it lies on and blends smoothly where parts meet (knees, elbows, waist).
fn skinning_weights(
    vertices: &[Vec3],
    parts: &[Part],
    softness: f32,
) -> Result<SkinningWeights, SynthError> {
    let mut data = Vec::with_capacity(vertices.len() * NUM_JOINTS);
    for &p in vertices {
        let mut d = [f32::INFINITY; NUM_JOINTS];
        for part in parts {
            d[part.joint] = d[part.joint].min(part.shape.distance(p).max(0.0));
        }
        let nearest = d.iter().copied().fold(f32::INFINITY, f32::min);
        let e = d.map(|dk| (-(dk - nearest) / softness).exp());
        let sum: f32 = e.iter().sum();
        data.extend(e.iter().map(|v| v / sum));
    }
    SkinningWeights::new(data, NUM_JOINTS).map_err(|e| SynthError::invalid("skinning weights", e))
}

/// The primitives of every joint. Every joint owns at least one part, so every joint moves some skin.
fn parts(shape: &BodyShape, j: &[Vec3; NUM_JOINTS]) -> Vec<Part> {
    let t = shape.thickness;
    let capsule = |joint, a: Vec3, b: Vec3, ra: f32, rb: f32| Part {
        joint,
        shape: Primitive::Capsule {
            a,
            b,
            ra: ra * t,
            rb: rb * t,
        },
    };
    let ellipsoid = |joint, centre: Vec3, radii: Vec3| Part {
        joint,
        shape: Primitive::Ellipsoid {
            centre,
            radii: radii * t,
        },
    };
    let mut parts = vec![
        ellipsoid(
            PELVIS,
            j[PELVIS] + Vec3::new(0.0, -0.03, -0.005),
            Vec3::new(0.155, 0.11, 0.11),
        ),
        ellipsoid(
            SPINE1,
            j[SPINE1] + Vec3::new(0.0, 0.02, 0.005),
            Vec3::new(0.145, 0.10, 0.10),
        ),
        ellipsoid(SPINE2, j[SPINE2], Vec3::new(0.155, 0.12, 0.105)),
        ellipsoid(
            SPINE3,
            j[SPINE3] + Vec3::new(0.0, 0.05, 0.0),
            Vec3::new(0.17, 0.12, 0.105),
        ),
        capsule(NECK, j[NECK] - Vec3::Y * 0.04, j[HEAD], 0.052, 0.048),
        ellipsoid(
            HEAD,
            j[HEAD] + Vec3::new(0.0, 0.10, 0.015),
            Vec3::new(0.085, 0.115, 0.10),
        ),
    ];
    for (side, [hip, knee, ankle, foot, collar, shoulder, elbow, wrist, hand]) in [
        (
            1.0,
            [
                L_HIP, L_KNEE, L_ANKLE, L_FOOT, L_COLLAR, L_SHOULDER, L_ELBOW, L_WRIST, L_HAND,
            ],
        ),
        (
            -1.0,
            [
                R_HIP, R_KNEE, R_ANKLE, R_FOOT, R_COLLAR, R_SHOULDER, R_ELBOW, R_WRIST, R_HAND,
            ],
        ),
    ] {
        let out = Vec3::X * side;
        parts.extend([
            capsule(hip, j[hip], j[knee], 0.08, 0.055),
            capsule(knee, j[knee], j[ankle], 0.053, 0.038),
            capsule(
                ankle,
                j[ankle] + Vec3::new(0.0, -0.045, -0.03),
                j[foot],
                0.036,
                0.033,
            ),
            capsule(foot, j[foot], j[foot] + Vec3::Z * 0.06, 0.031, 0.027),
            capsule(collar, j[collar], j[shoulder], 0.055, 0.05),
            capsule(shoulder, j[shoulder], j[elbow], 0.05, 0.04),
            capsule(elbow, j[elbow], j[wrist], 0.04, 0.03),
            ellipsoid(wrist, j[wrist] + out * 0.045, Vec3::new(0.05, 0.022, 0.042)),
            capsule(hand, j[hand], j[hand] + out * 0.055, 0.02, 0.017),
        ]);
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn body_is_a_closed_adult_with_normalised_weights() {
        let body = build_body(&BodyShape::default()).unwrap();
        let report = body.mesh.edge_report();
        assert!(report.is_watertight(), "{report:?}");
        assert_eq!(
            body.mesh.euler_characteristic(),
            2,
            "one sphere-like surface"
        );
        let n = body.mesh.vertices.len();
        assert!((2000..12000).contains(&n), "{n} vertices");
        let (lo, hi) = body
            .mesh
            .vertices
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let height = hi.y - lo.y;
        assert!((1.65..1.9).contains(&height), "height {height}");
        assert!(
            (1.5..2.0).contains(&(hi.x - lo.x)),
            "arm span {}",
            hi.x - lo.x
        );
        // An adult's volume is ≈ 0.06–0.08 m³.
        let volume = body.mesh.signed_volume();
        assert!((0.045..0.1).contains(&volume), "volume {volume}");
        assert_eq!(body.weights.num_vertices(), n);
        // Normals point away from the body's vertical axis on the torso.
        for (v, nrm) in body.mesh.vertices.iter().zip(&body.normals) {
            assert!((nrm.length() - 1.0).abs() < 1e-3);
            if v.y.abs() < 0.3 && v.x.abs() < 0.1 && v.z.abs() > 0.05 {
                assert!(nrm.z * v.z > 0.0, "normal {nrm} at {v}");
            }
        }
    }

    #[test]
    fn weights_follow_the_nearest_part() {
        let body = build_body(&BodyShape::default()).unwrap();
        let j = BodyShape::default().rest_joints();
        for (v, p) in body.mesh.vertices.iter().enumerate() {
            let row = body.weights.row(v);
            let best = (0..NUM_JOINTS)
                .max_by(|&a, &b| row[a].total_cmp(&row[b]))
                .unwrap();
            // Mid-forearm and mid-shin vertices belong to the elbow and knee joints.
            let mid_forearm = (j[L_ELBOW] + j[L_WRIST]) * 0.5;
            if (p.x - mid_forearm.x).abs() < 0.03 && (p.y - mid_forearm.y).abs() < 0.1 {
                assert_eq!(best, L_ELBOW, "{p}");
                assert!(row[L_ELBOW] > 0.9, "{p}: {row:?}");
            }
            let mid_shin = (j[R_KNEE] + j[R_ANKLE]) * 0.5;
            if (p.y - mid_shin.y).abs() < 0.03 && (p.x - mid_shin.x).abs() < 0.1 {
                assert_eq!(best, R_KNEE, "{p}");
            }
        }
    }

    #[test]
    fn bad_shapes_are_rejected() {
        let err = build_body(&BodyShape {
            thigh: -0.1,
            ..Default::default()
        })
        .unwrap_err();
        assert!(err.to_string().contains("body.thigh"), "{err}");
        let err = build_body(&BodyShape {
            voxel: 0.05,
            ..Default::default()
        })
        .unwrap_err();
        assert!(err.to_string().contains("body.voxel"), "{err}");
    }
}
