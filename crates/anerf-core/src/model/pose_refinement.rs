//! Per-frame corrections of the training frames' body fits, learned with the rest of stage 1 (pose
//! refinement): each joint's rotation and the global rotation and translation, starting at zero (the given
//! fit), applied where inverse skinning uses the bones ([`crate::geometry::PoseBasis`]), and pulled back
//! toward the given fit and toward smooth motion by [`PoseRefinement::penalty`].
//!
//! The parameters are the corrections divided by [`PoseRefinementConfig`]'s scales, so that Adam, whose
//! steps are about the learning rate whatever the gradient's size, moves rotations by `rotation_scale × lr`
//! radians and translations by `translation_scale × lr` metres a step, with the learning rate the NeRF uses.

use burn::module::Param;
use burn::prelude::*;
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::InvalidValue;
use crate::geometry::kinematics::MAX_CORRECTION_RADIANS;
use crate::geometry::{Pose, PoseCorrection};
use crate::tensor::{from_rows, to_host};

/// Whether and how stage 1 refines the training frames' body fits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseRefinementConfig {
    /// Learn corrections of the training frames' fits (off: the fits are taken as exact).
    pub enabled: bool,
    /// Radians of correction per unit of parameter: Adam moves a rotation by about this times the learning
    /// rate a step (default 1: 5e-4 rad a step at the paper's 5e-4; the `fast` preset's 0.05 gives the same at
    /// its 1e-2). Four times larger steps correct noisy fits no better and make exact ones wander
    /// (docs/POSE-REFINEMENT.md).
    pub rotation_scale: f32,
    /// Metres of correction per unit of parameter (default 0.25: 0.125 mm a step at 5e-4; `fast`: 0.0125).
    pub translation_scale: f32,
    /// Weight of the pull toward the given fit: the mean over joints of `|δ_k|²` plus `|δ_r|²` (radians²)
    /// plus `|δ_t|²` (metres²: a rotation's radian moves a point 1 m from the joint by about a metre).
    pub prior_weight: f32,
    /// Fraction of stage 1's iterations rendered with the given fits before the corrections start to learn
    /// (default 0: from the first step; waiting a fifth of stage 1 cost 0.9–1.3 dB on novel views on the
    /// demo subject, docs/POSE-REFINEMENT.md).
    pub start: f32,
    /// Weight of smooth motion: the mean squared second difference, over consecutive training frames, of the
    /// refined poses' axis-angle and translation values (given + correction, a first-order stand-in for the
    /// composition).
    pub smooth_weight: f32,
    /// Weight of the body silhouette term: the posed body model's outline in each training view of a step's
    /// frame against that view's mask edge (mean robust residual, pixels; 0: off). It places the body by
    /// the masks, which the photometric loss cannot do beyond where its own field agrees
    /// (docs/POSE-REFINEMENT.md, "The body's silhouette"). Runs saved before it existed read 0.
    pub silhouette_weight: f32,
}

impl Default for PoseRefinementConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            rotation_scale: 1.0,
            translation_scale: 0.25,
            prior_weight: 0.1,
            start: 0.0,
            smooth_weight: 0.0,
            silhouette_weight: 0.0,
        }
    }
}

impl PoseRefinementConfig {
    /// Checks every value; the error names the key.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        for (key, value, most) in [
            ("rotation_scale", self.rotation_scale, 100.0),
            ("translation_scale", self.translation_scale, 100.0),
            ("prior_weight", self.prior_weight, 1e6),
            ("smooth_weight", self.smooth_weight, 1e6),
            ("silhouette_weight", self.silhouette_weight, 1e6),
        ] {
            let positive = key.ends_with("scale");
            if !(value.is_finite() && value <= most && (value > 0.0 || !positive && value == 0.0)) {
                let least = if positive {
                    "a positive number"
                } else {
                    "0 or a positive number"
                };
                return Err(InvalidValue::new(
                    format!("model.pose_refinement.{key}"),
                    value,
                    format!("{least} up to {most}"),
                ));
            }
        }
        if !(0.0..1.0).contains(&self.start) {
            return Err(InvalidValue::new(
                "model.pose_refinement.start",
                self.start,
                "a fraction of stage 1 in [0, 1)",
            ));
        }
        Ok(())
    }
}

/// Largest translation correction accepted, metres: a fit this far off is not a fit error to refine.
pub const MAX_CORRECTION_METRES: f32 = 0.15;

/// The corrections of every training frame's fit.
#[derive(Module, Debug)]
pub struct PoseRefinement {
    /// `[F, 3K]` joint corrections / `rotation_scale`.
    pub joints: Param<Tensor<2>>,
    /// `[F, 6]` global rotation / `rotation_scale`, then translation / `translation_scale`.
    pub root: Param<Tensor<2>>,
    #[module(skip)]
    config: PoseRefinementConfig,
}

/// One frame's corrections as tensors, ready for [`crate::geometry::PoseBasis::bones`].
pub struct FrameCorrection {
    /// `[K, 3]` radians.
    pub joints: Tensor<2>,
    /// `[1, 3]` radians.
    pub rotation: Tensor<2>,
    /// `[1, 3]` metres, world space.
    pub translation: Tensor<2>,
}

/// Why [`PoseRefinement::check`] stopped a fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Diverged {
    /// Training-frame position.
    pub frame: usize,
    pub what: String,
}

impl PoseRefinement {
    /// Zero corrections for `frames` training frames of `joints` joints.
    pub fn new(
        config: PoseRefinementConfig,
        frames: usize,
        joints: usize,
        device: &Device,
    ) -> Self {
        Self {
            joints: Param::from_tensor(Tensor::zeros([frames, 3 * joints], device)),
            root: Param::from_tensor(Tensor::zeros([frames, 6], device)),
            config,
        }
    }

    pub fn num_frames(&self) -> usize {
        self.joints.dims()[0]
    }

    fn num_joints(&self) -> usize {
        self.joints.dims()[1] / 3
    }

    /// Training frame `f`'s corrections.
    pub fn frame(&self, f: usize) -> FrameCorrection {
        let k = self.num_joints();
        let root = self.root.val().narrow(0, f, 1);
        FrameCorrection {
            joints: self.joints.val().narrow(0, f, 1).reshape([k, 3]) * self.config.rotation_scale,
            rotation: root.clone().narrow(1, 0, 3) * self.config.rotation_scale,
            translation: root.narrow(1, 3, 3) * self.config.translation_scale,
        }
    }

    /// Every frame's corrections, on the host.
    pub fn corrections(&self) -> Vec<PoseCorrection> {
        let (joints, root) = (to_host(self.joints.val()), to_host(self.root.val()));
        joints
            .chunks_exact(3 * self.num_joints())
            .zip(root.chunks_exact(6))
            .map(|(j, g)| self.on_host(j, g))
            .collect()
    }

    /// Training frame `f`'s correction, on the host.
    pub fn correction(&self, f: usize) -> PoseCorrection {
        let joints = to_host(self.joints.val().narrow(0, f, 1));
        let root = to_host(self.root.val().narrow(0, f, 1));
        self.on_host(&joints, &root)
    }

    /// A frame's correction from its parameter rows (`3K` joint values, 6 global ones).
    fn on_host(&self, joints: &[f32], root: &[f32]) -> PoseCorrection {
        let (r, t) = (self.config.rotation_scale, self.config.translation_scale);
        let vec = |v: &[f32], s: f32| Vec3::new(v[0], v[1], v[2]) * s;
        PoseCorrection {
            joints: joints.chunks_exact(3).map(|v| vec(v, r)).collect(),
            rotation: vec(&root[..3], r),
            translation: vec(&root[3..], t),
        }
    }

    /// The first frame whose correction is not finite or beyond the bounds ([`MAX_CORRECTION_RADIANS`] for
    /// a rotation, [`MAX_CORRECTION_METRES`] for the translation): a refinement that diverged.
    pub fn check(&self) -> Result<(), Diverged> {
        for (frame, c) in self.corrections().iter().enumerate() {
            let worst = c
                .joints
                .iter()
                .chain([&c.rotation])
                .map(|v| v.length())
                .fold(0.0f32, |a, b| {
                    if b.is_nan() || a.is_nan() {
                        f32::NAN
                    } else {
                        a.max(b)
                    }
                });
            let shift = c.translation.length();
            if !(worst <= MAX_CORRECTION_RADIANS && shift <= MAX_CORRECTION_METRES) {
                return Err(Diverged {
                    frame,
                    what: format!(
                        "its correction reached {:.1}° of rotation and {:.1} cm of translation (at most \
                         {:.0}° and {:.0} cm are allowed)",
                        worst.to_degrees(),
                        shift * 100.0,
                        MAX_CORRECTION_RADIANS.to_degrees(),
                        MAX_CORRECTION_METRES * 100.0
                    ),
                });
            }
        }
        Ok(())
    }

    /// The regulariser of training frame `f`: `prior_weight` × its squared correction, plus
    /// `smooth_weight` × the squared second difference of the refined poses of frames `f − 1, f, f + 1`
    /// where `given` holds the three given fits (training-frame order; `None` at either end).
    pub fn penalty(&self, f: usize, given: Option<[&Pose; 3]>) -> Tensor<1> {
        let c = self.frame(f);
        let k = self.num_joints() as f32;
        let squared = |t: Tensor<2>| t.powi_scalar(2).sum();
        let prior = squared(c.joints) / k + squared(c.rotation) + squared(c.translation);
        let mut total = prior * self.config.prior_weight;
        if let (Some(given), true) = (given, self.config.smooth_weight > 0.0) {
            let device = self.joints.device();
            let refined = |i: usize| {
                let c = self.frame(f + i - 1);
                let values: Vec<f32> = given[i]
                    .joint_rotations
                    .iter()
                    .chain([&given[i].global.rh, &given[i].global.th])
                    .flat_map(|v| v.to_array())
                    .collect();
                let n = values.len();
                from_rows(&values, 1, n, &device)
                    + Tensor::cat(
                        vec![c.joints.reshape([1, n - 6]), c.rotation, c.translation],
                        1,
                    )
            };
            let second = refined(0) - refined(1) * 2.0 + refined(2);
            let n = second.dims()[1] as f32;
            total = total + squared(second) * (self.config.smooth_weight / n);
        }
        total
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::lbs::tests::TestRng;
    use crate::geometry::GlobalTransform;
    use anerf_device::cpu_device;

    const FRAMES: usize = 4;
    const JOINTS: usize = 3;

    fn config() -> PoseRefinementConfig {
        PoseRefinementConfig {
            enabled: true,
            rotation_scale: 2.0,
            translation_scale: 0.5,
            prior_weight: 0.3,
            start: 0.0,
            smooth_weight: 0.7,
            silhouette_weight: 0.0,
        }
    }

    /// A refinement whose parameters are `joints` (`F × 3K`) and `root` (`F × 6`).
    fn refinement(joints: &[f32], root: &[f32], device: &Device) -> PoseRefinement {
        let mut r = PoseRefinement::new(config(), FRAMES, JOINTS, device);
        r.joints = Param::from_tensor(from_rows(joints, FRAMES, 3 * JOINTS, device).require_grad());
        r.root = Param::from_tensor(from_rows(root, FRAMES, 6, device).require_grad());
        r
    }

    /// The penalty of frame 1 written out on the host in f64, from the formula in the docs.
    fn host_penalty(joints: &[f32], root: &[f32], given: &[Pose]) -> f64 {
        let c = config();
        let (rs, ts) = (c.rotation_scale as f64, c.translation_scale as f64);
        let row = |f: usize| -> Vec<f64> {
            let j = &joints[f * 3 * JOINTS..(f + 1) * 3 * JOINTS];
            let g = &root[f * 6..(f + 1) * 6];
            j.iter()
                .chain(&g[..3])
                .map(|&v| v as f64 * rs)
                .chain(g[3..].iter().map(|&v| v as f64 * ts))
                .collect()
        };
        let mine = row(1);
        let sq = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
        let prior = sq(&mine[..3 * JOINTS]) / JOINTS as f64 + sq(&mine[3 * JOINTS..]);
        let refined = |f: usize| -> Vec<f64> {
            let p = &given[f];
            p.joint_rotations
                .iter()
                .chain([&p.global.rh, &p.global.th])
                .flat_map(|v| v.to_array())
                .zip(row(f))
                .map(|(g, d)| g as f64 + d)
                .collect()
        };
        let (a, b, d) = (refined(0), refined(1), refined(2));
        let second: Vec<f64> = (0..a.len()).map(|i| a[i] - 2.0 * b[i] + d[i]).collect();
        c.prior_weight as f64 * prior + c.smooth_weight as f64 * sq(&second) / a.len() as f64
    }

    /// The penalty equals its formula computed on the host, and its gradient equals central differences
    /// of that formula, for every parameter of every frame (frame 3, outside the stencil, gets none).
    #[test]
    fn the_penalty_and_its_gradient_match_the_formula() {
        let device = cpu_device().autodiff();
        let mut rng = TestRng(17);
        let joints: Vec<f32> = (0..FRAMES * 3 * JOINTS)
            .map(|_| rng.range(-0.05, 0.05))
            .collect();
        let root: Vec<f32> = (0..FRAMES * 6).map(|_| rng.range(-0.05, 0.05)).collect();
        let given: Vec<Pose> = (0..3)
            .map(|_| Pose {
                joint_rotations: (0..JOINTS).map(|_| rng.vec3(0.5)).collect(),
                global: GlobalTransform {
                    rh: rng.vec3(1.0),
                    th: rng.vec3(1.0),
                },
            })
            .collect();
        let r = refinement(&joints, &root, &device);
        let value = r.penalty(1, Some([&given[0], &given[1], &given[2]]));
        let expected = host_penalty(&joints, &root, &given);
        let got = to_host(value.clone())[0] as f64;
        assert!(
            (got - expected).abs() < 1e-5 * expected,
            "{got} vs {expected}"
        );
        let grads = value.backward();
        let analytic = [
            to_host(r.joints.val().grad(&grads).unwrap()),
            to_host(r.root.val().grad(&grads).unwrap()),
        ];
        let h = 1e-4;
        for (which, params) in [(0, &joints), (1, &root)] {
            for i in 0..params.len() {
                let nudged = |d: f32| {
                    let mut p = params.clone();
                    p[i] += d;
                    match which {
                        0 => host_penalty(&p, &root, &given),
                        _ => host_penalty(&joints, &p, &given),
                    }
                };
                let fd = (nudged(h) - nudged(-h)) / (2.0 * h as f64);
                let a = analytic[which][i] as f64;
                assert!(
                    (fd - a).abs() < 1e-3 * fd.abs() + 1e-4,
                    "parameter {which}/{i}: central difference {fd}, autodiff {a}"
                );
            }
        }
        let rows = 3 * JOINTS;
        assert!(analytic[0][3 * rows..].iter().all(|&g| g == 0.0));
        assert!(analytic[0][rows..2 * rows].iter().any(|&g| g != 0.0));
    }

    /// Corrections beyond their bounds, or not finite, stop the fit naming the frame.
    #[test]
    fn a_diverged_correction_is_named() {
        let device = cpu_device().autodiff();
        let mut root = vec![0.0; FRAMES * 6];
        let joints = vec![0.0; FRAMES * 3 * JOINTS];
        assert_eq!(refinement(&joints, &root, &device).check(), Ok(()));
        root[2 * 6 + 3] = 0.2 / config().translation_scale + 0.01;
        let err = refinement(&joints, &root, &device).check().unwrap_err();
        assert_eq!(err.frame, 2);
        assert!(err.what.contains("cm of translation"), "{}", err.what);
        let mut joints = joints;
        joints[3 * JOINTS + 4] = f32::NAN;
        let err = refinement(&joints, &vec![0.0; FRAMES * 6], &device)
            .check()
            .unwrap_err();
        assert_eq!(err.frame, 1);
    }
}
