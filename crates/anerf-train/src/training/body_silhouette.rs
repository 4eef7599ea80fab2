//! The body silhouette term of pose refinement (`model.pose_refinement.silhouette_weight`): seen by a
//! training camera, the outline of the posed body model should lie on the edge of that camera's mask.
//! The photometric loss corrects a fit only as far as the field it trains agrees with the images; the
//! masks place the body in world space by themselves (docs/POSE-REFINEMENT.md, "The body's silhouette").
//!
//! Per view, the outline is the posed body's vertices whose normal is nearly perpendicular to their line of
//! sight and next to a pixel the body does not cover. Each outline vertex reads the mask's signed distance
//! `s` (pixels, positive on the body) where it projects; its residual is `s` less the median of `s` over
//! its bone's outline vertices in that view (over the whole outline where a bone has few), so that a mask
//! uniformly wider than the body (clothing, a dilated segmentation) costs nothing and a limb off to one
//! side does. The term is `weight` × the mean over views of the mean of `√(1 + r²) − 1` (pixels: quadratic
//! within a pixel, linear beyond, so that a mask's wrong pixels pull by at most a unit each).
//!
//! The term is evaluated on the host; it reaches the corrections through the bones: its gradient with
//! respect to each posed vertex `g_v` (pose space) gives, per bone, the moments `M_k = Σ_v w_vk g_v [y_v; 1]ᵀ`
//! (`y_v` the canonical vertex), and `Σ_k ⟨B_k, M_k⟩` over the corrected bones `B_k` has the term's
//! gradient in the corrections ([`silhouette_loss`]).

use std::sync::Arc;

use anerf_core::geometry::{
    forward_lbs_points, Camera, CanonicalPose, GlobalTransform, PixelConvention, Pose, Skeleton,
};
use anerf_core::mesh::TriMesh;
use anerf_data::mask_distance::MaskDistance;
use anerf_data::prepare::CanonicalBody;
use anerf_eval::mesh_raster::{mesh_coverage, Surface};
use anyhow::{Context, Result};
use burn::prelude::*;
use glam::{Vec2, Vec3};

/// Pixels the mask's signed distance is kept beyond the body's box: an outline this far off still reads
/// a distance.
pub const MASK_MARGIN: usize = 32;
/// An outline vertex's normal makes at most this cosine with its line of sight.
const GRAZING: f32 = 0.3;
/// An outline vertex has a pixel the body does not cover within this many pixels (per axis) of its own.
const OUTLINE_RADIUS: i64 = 2;
/// Fewest outline vertices of a bone in a view for the bone's own median.
const MIN_BONE_VERTICES: usize = 8;

/// One training view of a frame: its camera and its mask's signed distance.
#[derive(Debug, Clone)]
pub struct SilhouetteView {
    pub camera: Camera,
    pub mask: Arc<MaskDistance>,
}

/// The term on one frame: its value, and its gradient as per-bone moments.
#[derive(Debug, Clone, PartialEq)]
pub struct SilhouetteEvidence {
    /// `weight` × the mean over views of the mean robust residual (pixels).
    pub value: f32,
    /// `[K·12]`: per bone `k`, the row-major 3×4 `M_k = Σ_v w_vk g_v [y_v; 1]ᵀ`, with `g_v` the value's
    /// gradient with respect to posed vertex `v` in the given fit's pose space and `y_v` its canonical
    /// (T-pose) position, metres.
    pub moments: Vec<f32>,
}

/// The body model as the term reads it, derived once per run: each vertex's bone of largest weight (its
/// outline's group for the median) and whether the mesh is closed (its coverage then walks half the faces).
#[derive(Debug, Clone)]
pub struct SilhouetteBody {
    pub body: CanonicalBody,
    owners: Vec<usize>,
    surface: Surface,
}

impl SilhouetteBody {
    pub fn new(body: CanonicalBody) -> Self {
        let k = body.weights.num_joints();
        let owners = body
            .weights
            .as_slice()
            .chunks_exact(k)
            .map(|w| {
                (0..k)
                    .max_by(|&a, &b| w[a].total_cmp(&w[b]))
                    .expect("a joint")
            })
            .collect();
        let surface = Surface::of(&TriMesh {
            vertices: body.vertices.clone(),
            faces: body.faces.clone(),
        });
        Self {
            body,
            owners,
            surface,
        }
    }
}

/// The term for a frame whose current (refined) pose is `pose`, with pose space that of the given fit's
/// global motion `given` (the corrected bones' space, [`anerf_core::geometry::PoseBasis`]), seen in
/// `views`; pixels sampled where `convention` puts them.
pub fn silhouette_evidence(
    model: &SilhouetteBody,
    skeleton: &Skeleton,
    pose: &Pose,
    given: &GlobalTransform,
    views: &[SilhouetteView],
    convention: PixelConvention,
    weight: f32,
) -> Result<SilhouetteEvidence> {
    let body = &model.body;
    let k = skeleton.num_joints();
    let bones = skeleton
        .bone_transforms(pose, CanonicalPose::TPose)
        .context("the refined pose's bones")?;
    let world: Vec<Vec3> = forward_lbs_points(&body.vertices, body.weights.as_slice(), &bones)
        .context("posing the body model")?
        .into_iter()
        .map(|x| pose.global.pose_to_world(x))
        .collect();
    let posed = TriMesh {
        vertices: world,
        faces: body.faces.clone(),
    };
    let normals = posed.vertex_normals();
    // The value's gradient with respect to each world-space vertex.
    let mut gradient = vec![Vec3::ZERO; posed.vertices.len()];
    let mut value = 0.0;
    for view in views {
        let found = outline_residuals(&posed, model.surface, &normals, view, convention);
        if found.is_empty() {
            continue;
        }
        let centred = centre_by_bone(&found, &model.owners, k);
        let scale = weight / (views.len() * found.len()) as f32;
        for (hit, r) in found.iter().zip(centred) {
            let root = (1.0 + r * r).sqrt();
            value += scale * (root - 1.0);
            gradient[hit.vertex] += hit.direction * (scale * r / root);
        }
    }
    Ok(SilhouetteEvidence {
        value,
        moments: bone_moments(body, given, &gradient),
    })
}

/// Per bone `k`, the row-major 3×4 `M_k = Σ_v w_vk g_v [y_v; 1]ᵀ` (`[K·12]`) of a gradient `gradient` with
/// respect to the posed vertices in world space, taken to the given fit's pose space (`x_world = R_h x_pose
/// + T_h`, `g_pose = R_hᵀ g_world`): `Σ_k ⟨B_k, M_k⟩` then has the gradient `Σ_v g_v · x_v` has, over bone
/// rows `B_k` that pose canonical points into that space.
fn bone_moments(body: &CanonicalBody, given: &GlobalTransform, gradient: &[Vec3]) -> Vec<f32> {
    let k = body.weights.num_joints();
    let back = given.rotation().transpose();
    let mut moments = vec![0.0f32; k * 12];
    for (v, g) in gradient.iter().enumerate() {
        if *g == Vec3::ZERO {
            continue;
        }
        let g = (back * *g).to_array();
        let y = body.vertices[v].extend(1.0).to_array();
        for (j, &w) in body.weights.row(v).iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            let m = &mut moments[j * 12..(j + 1) * 12];
            for (row, gi) in g.iter().enumerate() {
                for (col, yj) in y.iter().enumerate() {
                    m[row * 4 + col] += w * gi * yj;
                }
            }
        }
    }
    moments
}

/// The term as a loss on the device: `value` with the gradient `Σ_k ⟨B_k, M_k⟩` gives the corrected bone
/// rows `bones` (`[K, 12]`, differentiable in the corrections).
pub fn silhouette_loss(evidence: &SilhouetteEvidence, bones: Tensor<2>) -> Tensor<1> {
    let [k, _] = bones.dims();
    let device = bones.device();
    let moments = anerf_core::tensor::from_rows(&evidence.moments, k, 12, &device);
    let surrogate = (bones * moments).sum();
    surrogate.clone() - surrogate.detach() + evidence.value
}

/// An outline vertex in one view: its mask distance, and the world-space direction in which moving the
/// vertex raises that distance, per pixel of it (the projection's Jacobian transposed times the distance's
/// gradient).
struct OutlineHit {
    vertex: usize,
    distance: f32,
    direction: Vec3,
}

/// The outline vertices of the posed body (`posed` in world space, its `surface`, `normals`) in `view`
/// that project where the mask's distance is known.
fn outline_residuals(
    posed: &TriMesh,
    surface: Surface,
    normals: &[Vec3],
    view: &SilhouetteView,
    convention: PixelConvention,
) -> Vec<OutlineHit> {
    let camera = &view.camera;
    let (w, h) = (camera.width as i64, camera.height as i64);
    let covered = mesh_coverage(&posed.vertices, &posed.faces, surface, camera, convention);
    let empty_near = |p: Vec2| {
        let (u, v) = (p.x.round() as i64, p.y.round() as i64);
        (-OUTLINE_RADIUS..=OUTLINE_RADIUS).any(|dv| {
            (-OUTLINE_RADIUS..=OUTLINE_RADIUS).any(|du| {
                let (x, y) = (u + du, v + dv);
                !(0..w).contains(&x) || !(0..h).contains(&y) || !covered[(y * w + x) as usize]
            })
        })
    };
    let k = camera.intrinsics;
    let (row0, row1, row2) = (k.row(0), k.row(1), k.row(2));
    posed
        .vertices
        .iter()
        .zip(normals)
        .enumerate()
        .filter_map(|(vertex, (&x, &n))| {
            let c = camera.world_to_camera(x);
            let sight = c.normalize_or_zero();
            if c.z <= 0.0 || (camera.rotation * n).dot(sight).abs() > GRAZING {
                return None;
            }
            let p = camera.project(x, convention)?;
            if !empty_near(p) {
                return None;
            }
            let (distance, slope) = view.mask.sample(p)?;
            // p = (K c)_xy / (K c)_z − offset, c = R x + t.
            let hc = k * c;
            let (px, py) = (hc.x / hc.z, hc.y / hc.z);
            let along_camera = ((row0 - row2 * px) * slope.x + (row1 - row2 * py) * slope.y) / hc.z;
            Some(OutlineHit {
                vertex,
                distance,
                direction: camera.rotation.transpose() * along_camera,
            })
        })
        .collect()
}

/// Each hit's distance less the median of its bone's hits (`owners`: each vertex's bone of largest
/// weight), or of all hits where its bone has fewer than [`MIN_BONE_VERTICES`].
fn centre_by_bone(hits: &[OutlineHit], owners: &[usize], joints: usize) -> Vec<f32> {
    let median = |mut v: Vec<f32>| {
        v.sort_by(f32::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let all = median(hits.iter().map(|h| h.distance).collect());
    let mut by_bone = vec![Vec::new(); joints];
    for h in hits {
        by_bone[owners[h.vertex]].push(h.distance);
    }
    let centres: Vec<f32> = by_bone
        .into_iter()
        .map(|d| {
            if d.len() >= MIN_BONE_VERTICES {
                median(d)
            } else {
                all
            }
        })
        .collect();
    hits.iter()
        .map(|h| h.distance - centres[owners[h.vertex]])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_core::geometry::{Aabb, PoseBasis, PoseCorrection};
    use anerf_core::tensor::{from_rows, to_host};
    use anerf_data::synthetic::{build_body, BodyShape};
    use anerf_device::cpu_device;
    use burn::optim::{AdamConfig, GradientsParams};
    use glam::Mat3;

    /// The synthetic subjects' body as a prepared subject holds it, and its skeleton.
    fn canonical_body() -> (CanonicalBody, Skeleton) {
        let body = build_body(&BodyShape::default()).unwrap();
        let bounds = Aabb::from_points(body.mesh.vertices.iter().copied()).unwrap();
        let canonical = CanonicalBody {
            vertices: body.mesh.vertices,
            faces: body.mesh.faces,
            weights: body.weights,
            bounds,
        };
        (canonical, body.skeleton)
    }

    /// A pose a few degrees from the rest pose at every joint, turned and placed in front of the cameras.
    fn some_pose(joints: usize) -> Pose {
        Pose {
            joint_rotations: (0..joints)
                .map(|j| {
                    let s = j as f32;
                    Vec3::new((1.3 * s).sin(), (0.7 * s).cos(), (2.1 * s).sin()) * 0.1
                })
                .collect(),
            global: GlobalTransform {
                rh: Vec3::new(0.1, -0.3, 0.05),
                th: Vec3::new(0.05, -0.1, 0.2),
            },
        }
    }

    fn posed_world(body: &CanonicalBody, skeleton: &Skeleton, pose: &Pose) -> Vec<Vec3> {
        let bones = skeleton
            .bone_transforms(pose, CanonicalPose::TPose)
            .unwrap();
        forward_lbs_points(&body.vertices, body.weights.as_slice(), &bones)
            .unwrap()
            .into_iter()
            .map(|x| pose.global.pose_to_world(x))
            .collect()
    }

    /// The corrections as leaf tensors (joints `[K, 3]`, rotation and translation `[1, 3]`) from `values`
    /// (`3K + 6`).
    fn leaves(values: &[f32], k: usize, device: &Device) -> [Tensor<2>; 3] {
        [
            from_rows(&values[..3 * k], k, 3, device).require_grad(),
            from_rows(&values[3 * k..3 * k + 3], 1, 3, device).require_grad(),
            from_rows(&values[3 * k + 3..], 1, 3, device).require_grad(),
        ]
    }

    fn correction(values: &[f32], k: usize) -> PoseCorrection {
        let v = |i: usize| Vec3::new(values[i], values[i + 1], values[i + 2]);
        PoseCorrection {
            joints: (0..k).map(|j| v(3 * j)).collect(),
            rotation: v(3 * k),
            translation: v(3 * k + 3),
        }
    }

    /// With any gradient `g_v` on the posed vertices, `Σ_k ⟨B_k, M_k⟩` over the device's corrected bones has
    /// the gradient in the corrections that central differences give `Σ_v g_v · x_v` with the vertices posed
    /// on the host by the corrected pose ([`PoseCorrection::apply`]), away from zero corrections.
    #[test]
    fn the_moments_carry_the_vertices_gradient_to_the_corrections() {
        let (body, skeleton) = canonical_body();
        let k = skeleton.num_joints();
        let given = some_pose(k);
        let gradient: Vec<Vec3> = (0..body.vertices.len())
            .map(|v| {
                let s = v as f32;
                Vec3::new((0.37 * s).sin(), (0.11 * s).cos(), (0.53 * s).sin())
            })
            .collect();
        let moments = bone_moments(&body, &given.global, &gradient);
        let at: Vec<f32> = (0..3 * k + 6)
            .map(|i| 0.04 * ((i as f32) * 0.9).sin())
            .collect();
        let device = cpu_device().autodiff();
        let basis = PoseBasis::new(&skeleton, &given, CanonicalPose::TPose, &device);
        let [j, r, t] = leaves(&at, k, &device);
        let bones = basis.bones(j.clone(), r.clone(), t.clone()).rows();
        let loss = silhouette_loss(
            &SilhouetteEvidence {
                value: 0.0,
                moments,
            },
            bones,
        );
        let grads = loss.backward();
        let analytic: Vec<f32> = [j, r, t]
            .iter()
            .flat_map(|x| to_host(x.grad(&grads).expect("a leaf")))
            .collect();
        let host = |values: &[f32]| -> f64 {
            let pose = correction(values, k).apply(&given);
            posed_world(&body, &skeleton, &pose)
                .iter()
                .zip(&gradient)
                .map(|(x, g)| x.as_dvec3().dot(g.as_dvec3()))
                .sum()
        };
        let h = 1e-2;
        for i in [
            0,
            4,
            3 * 5 + 2,
            3 * 18,
            3 * 21 + 1,
            3 * k,
            3 * k + 2,
            3 * k + 3,
            3 * k + 5,
        ] {
            let nudged = |d: f32| {
                let mut v = at.clone();
                v[i] += d;
                host(&v)
            };
            let fd = (nudged(h) - nudged(-h)) / (2.0 * h as f64);
            let a = analytic[i] as f64;
            assert!(
                (fd - a).abs() < 2e-2 * fd.abs().max(a.abs()) + 1e-2,
                "correction {i}: central difference {fd}, from the moments {a}"
            );
        }
    }

    /// Four cameras 3 m around the body, 160² pixels (about 2 cm a pixel at the body), looking at `centre`
    /// with the world's y axis up.
    fn ring(centre: Vec3) -> Vec<Camera> {
        (0..4)
            .map(|i| {
                let a = std::f32::consts::FRAC_PI_2 * i as f32 + 0.3;
                let eye = centre + Vec3::new(a.cos(), 0.1, a.sin()) * 3.0;
                let forward = (centre - eye).normalize();
                let right = forward.cross(Vec3::Y).normalize();
                let rotation = Mat3::from_cols(right, forward.cross(right), forward).transpose();
                Camera {
                    intrinsics: Mat3::from_cols(
                        Vec3::new(150.0, 0.0, 0.0),
                        Vec3::new(0.0, 150.0, 0.0),
                        Vec3::new(79.5, 79.5, 1.0),
                    ),
                    rotation,
                    translation: -(rotation * eye),
                    distortion: Default::default(),
                    width: 160,
                    height: 160,
                }
            })
            .collect()
    }

    /// Masks of the body posed by the true pose, and a given fit off it by a known correction: descending
    /// the term alone from the given fit (Adam on the corrections, through the device's bones) brings the
    /// posed vertices at least three times closer to the truth, and a mask uniformly wider than the body
    /// (dilated by two pixels) still halves the error.
    #[test]
    fn descending_the_term_recovers_a_known_correction() {
        let (body, skeleton) = canonical_body();
        let k = skeleton.num_joints();
        let truth = some_pose(k);
        let world = posed_world(&body, &skeleton, &truth);
        let centre = world.iter().copied().sum::<Vec3>() / world.len() as f32;
        let cameras = ring(centre);
        // The known error of the given fit: the elbows, a knee, the root's turn and place.
        let mut known = vec![0.0f32; 3 * k + 6];
        for (joint, axis) in [(18, 0), (19, 1), (4, 2)] {
            known[3 * joint + axis] = 0.12;
        }
        known[3 * k..].copy_from_slice(&[0.03, -0.04, 0.02, 0.03, -0.02, 0.025]);
        // given = truth corrected by the inverse error, approximately: truth with −error applied.
        let minus: Vec<f32> = known.iter().map(|v| -v).collect();
        let given = correction(&minus, k).apply(&truth);
        let error_of = |pose: &Pose| {
            posed_world(&body, &skeleton, pose)
                .iter()
                .zip(&world)
                .map(|(a, b)| (*a - *b).length())
                .sum::<f32>()
                / world.len() as f32
        };
        let start = error_of(&given);
        let model = SilhouetteBody::new(body.clone());
        assert_eq!(model.surface, Surface::Closed);
        for (dilation, most) in [(0, 1.0 / 3.0), (2, 0.5)] {
            let views: Vec<SilhouetteView> = cameras
                .iter()
                .map(|camera| {
                    let covered = mesh_coverage(
                        &world,
                        &body.faces,
                        Surface::Open,
                        camera,
                        PixelConvention::Integer,
                    );
                    let (w, h) = (camera.width as usize, camera.height as usize);
                    let mask: Vec<u8> = (0..w * h)
                        .map(|i| {
                            let (x, y) = ((i % w) as i64, (i / w) as i64);
                            let near = (-dilation..=dilation).any(|dy| {
                                (-dilation..=dilation).any(|dx| {
                                    let (u, v) = (x + dx, y + dy);
                                    (0..w as i64).contains(&u)
                                        && (0..h as i64).contains(&v)
                                        && covered[v as usize * w + u as usize]
                                })
                            });
                            u8::from(near)
                        })
                        .collect();
                    SilhouetteView {
                        camera: camera.clone(),
                        mask: Arc::new(MaskDistance::new(&mask, w, h, MASK_MARGIN).unwrap()),
                    }
                })
                .collect();
            let device = cpu_device().autodiff();
            let basis = PoseBasis::new(&skeleton, &given, CanonicalPose::TPose, &device);
            let mut values = vec![0.0f32; 3 * k + 6];
            let mut optim = AdamConfig::new().init();
            let mut params = Corrections::new(&values, k, &device);
            for _ in 0..150 {
                let pose = correction(&values, k).apply(&given);
                let evidence = silhouette_evidence(
                    &model,
                    &skeleton,
                    &pose,
                    &given.global,
                    &views,
                    PixelConvention::Integer,
                    1.0,
                )
                .unwrap();
                let bones = basis
                    .bones(
                        params.joints.val(),
                        params.rotation.val(),
                        params.translation.val(),
                    )
                    .rows();
                let grads = GradientsParams::from_grads(
                    silhouette_loss(&evidence, bones).backward(),
                    &params,
                );
                params = optim.step(3e-3, params, grads);
                values = params.values();
            }
            let end = error_of(&correction(&values, k).apply(&given));
            assert!(
                end < most * start,
                "dilated by {dilation} px: {:.2} cm of mean vertex error left of {:.2}",
                end * 100.0,
                start * 100.0
            );
        }
    }

    /// The corrections as one module for the optimiser.
    #[derive(burn::module::Module, Debug)]
    struct Corrections {
        joints: burn::module::Param<Tensor<2>>,
        rotation: burn::module::Param<Tensor<2>>,
        translation: burn::module::Param<Tensor<2>>,
    }

    impl Corrections {
        fn new(values: &[f32], k: usize, device: &Device) -> Self {
            let [joints, rotation, translation] =
                leaves(values, k, device).map(burn::module::Param::from_tensor);
            Self {
                joints,
                rotation,
                translation,
            }
        }

        fn values(&self) -> Vec<f32> {
            [&self.joints, &self.rotation, &self.translation]
                .iter()
                .flat_map(|p| to_host(p.val()))
                .collect()
        }
    }
}
