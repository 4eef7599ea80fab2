//! The composed model: canonical NeRF, neural blend weight fields and latent codes, and the renderer that
//! turns a ray batch of one frame into colours (paper §3, docs/REFERENCE.md §3.2).

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use glam::Vec3;

use super::blend::BlendWeightField;
use super::codes::CodeRows;
use super::culling::{
    cull_on_device, cull_samples, CorrectionWarp, Culling, DeviceSurvivors, SampleRays,
};
use super::nerf::CanonicalNerf;
use super::occupancy::OccupancyGrid;
use super::pose_refinement::PoseRefinement;
use super::{ConsistencyLoss, ModelConfig, ViewDirection};
use crate::geometry::skinning::{points_tensor, world_to_pose_directions, BoneMatrices};
use crate::geometry::VolumeTensor;
use crate::geometry::{Aabb, GlobalTransform, PoseBasis};
use crate::render::{
    blend_consistency, blend_consistency_parts, composite, stratified_depths, ConsistencyParts,
    RayBatch,
};
use crate::tensor::{materialised, to_host};

/// How many frames and joints the model is built for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelSizes {
    /// Training frames: appearance codes ℓ and blend codes ψ (plus the canonical ψ).
    pub training_frames: usize,
    /// Joints `K` of the skeleton.
    pub joints: usize,
}

/// Which blend-weight code a frame uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameCode {
    /// Training frame `f` (row `f + 1` of the stage-1 field).
    Training(usize),
    /// Novel-pose frame `j` (row `j` of the stage-2 field).
    Novel(usize),
}

/// Everything the renderer needs about one frame, on the device.
#[derive(Debug, Clone)]
pub struct FrameInputs {
    /// Bone transforms `A_k` (canonical → pose space).
    pub bones: BoneMatrices,
    /// World ↔ pose space.
    pub global: GlobalTransform,
    /// Pose-space blend-weight volume of the frame (`w^s` and distance to the body).
    pub volume: VolumeTensor,
    pub code: FrameCode,
    /// Row of the appearance codes ℓ.
    pub appearance: usize,
    /// The frame's given fit for corrected bones, where the model refines training frames' fits
    /// ([`AnimatableNerf::pose`]); `None` renders with `bones` as given.
    pub basis: Option<PoseBasis>,
    /// Set by [`AnimatableNerf::posed_frame`] once `bones` carry a refinement's correction: how the
    /// correction moved the body, so that culling keeps the samples near the body where it now is.
    pub warp: Option<CorrectionWarp>,
}

/// The canonical body: its blend-weight volume and its box (T-pose vertices ± padding, metres).
#[derive(Debug, Clone)]
pub struct CanonicalInputs {
    pub volume: VolumeTensor,
    pub bounds: Aabb,
}

/// Render results of one ray batch.
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// `[R, 3]` colour on black.
    pub rgb: Tensor<2>,
    /// `[R]` accumulated opacity.
    pub acc: Tensor<1>,
    /// `[R]` expected depth, metres.
    pub depth: Tensor<1>,
    /// `[R, S]` the samples' opacities `α` (culled samples 0), for the hard-surface prior.
    pub alpha: Tensor<2>,
    /// Observation and canonical blend weights on the surviving samples (when asked for).
    pub consistency: Option<ConsistencyTerms>,
    /// Samples that survived culling (they reach the blend-weight field), samples among them in occupied
    /// canonical cells (they reach the canonical NeRF; all of them without an occupancy grid), and all
    /// samples, for statistics.
    pub surviving_samples: usize,
    pub occupied_samples: usize,
    pub total_samples: usize,
}

/// Inputs of the blend-weight consistency loss.
#[derive(Debug, Clone)]
pub struct ConsistencyTerms {
    /// `[M, K]` `w_i(x)` of the frame.
    pub observed: Tensor<2>,
    /// `[M, K]` `w^can(x')` at the warped points.
    pub canonical: Tensor<2>,
    /// `[M, 1]` 1 where the sample counts: raw density > 0 inside the canonical box, plus the densest sample.
    pub mask: Tensor<2>,
    /// `[M, 1]` the samples' raw density (detached), which the mask was made from (the shards of a
    /// data-parallel step decide the batch's selection from it).
    pub density: Tensor<2>,
    /// `[M', K]` the frame field's residual `F` at the samples (neural field only), for its penalty.
    pub residual: Option<Tensor<2>>,
}

impl ConsistencyTerms {
    /// The terms of samples with observation and canonical weights `[M, K]` and raw density `[M, 1]`
    /// (zero outside the canonical box), which selects them ([`consistency_mask`]).
    pub fn new(
        observed: Tensor<2>,
        canonical: Tensor<2>,
        density: Tensor<2>,
        residual: Option<Tensor<2>>,
    ) -> Self {
        let density = density.detach();
        Self {
            observed,
            canonical,
            mask: consistency_mask(density.clone()),
            density,
            residual,
        }
    }

    /// `mean(F²)` of the residual (zero without the neural field): the penalty that keeps the learned
    /// correction near zero, i.e. the weights near the body model's, where the images do not ask otherwise.
    pub fn residual_penalty(&self) -> Tensor<1> {
        residual_penalty(self.residual.clone(), &self.observed.device())
    }

    /// The parts of [`Self::loss`] (its numerator and the count of its denominator).
    pub fn loss_parts(&self, kind: ConsistencyLoss) -> ConsistencyParts {
        blend_consistency_parts(
            self.observed.clone(),
            self.canonical.clone(),
            self.mask.clone(),
            kind,
        )
    }

    /// The loss value of kind `kind`.
    pub fn loss(&self, kind: ConsistencyLoss) -> Tensor<1> {
        blend_consistency(
            self.observed.clone(),
            self.canonical.clone(),
            self.mask.clone(),
            kind,
        )
    }
}

/// Samples after warping to canonical space and shading.
#[derive(Debug, Clone)]
pub struct ShadedSamples {
    /// `[M, 1]` raw density (zero outside the canonical box).
    pub density: Tensor<2>,
    /// `[M, 3]` colour.
    pub rgb: Tensor<2>,
    /// `[M, 3]` canonical positions.
    pub canonical_points: Tensor<2>,
    /// `[M, K]` observation-space blend weights.
    pub weights: Tensor<2>,
    /// `[M', K]` the blend-weight residual `F` of the samples that reached the blend-weight field (with
    /// an occupancy grid, more than the `M` shaded ones); `None` without the neural field.
    pub residual: Option<Tensor<2>>,
    /// `[M, 1]` true inside the canonical box.
    pub inside: Tensor<2, Bool>,
}

/// Pose-space samples carried to canonical space.
struct Warped {
    /// `[M, K]` observation-space blend weights.
    weights: Tensor<2>,
    /// `[M, K]` their residual `F` (neural field only).
    residual: Option<Tensor<2>>,
    /// `[M, 3]` canonical positions (metres).
    canonical_points: Tensor<2>,
}

/// Animatable NeRF: a canonical radiance field, one blend-weight field shared by the training frames and
/// the canonical space, and (after stage 2) a field for novel poses.
#[derive(Module, Debug)]
pub struct AnimatableNerf {
    pub nerf: CanonicalNerf,
    pub blend: BlendWeightField,
    pub novel_blend: Option<BlendWeightField>,
    /// Corrections of the training frames' body fits (with `pose_refinement.enabled`).
    pub pose: Option<PoseRefinement>,
    #[module(skip)]
    config: ModelConfig,
    /// Occupied cells of the canonical box, when the config asks for a grid and it has been built.
    #[module(skip)]
    occupancy: Option<OccupancyGrid>,
}

impl AnimatableNerf {
    /// A freshly initialised stage-1 model, every parameter drawn now ([`materialised`]): a seeded device
    /// gives the same model however it is used next.
    pub fn new(config: &ModelConfig, sizes: ModelSizes, device: &Device) -> Self {
        materialised(Self {
            nerf: CanonicalNerf::new(config, sizes.training_frames, device),
            blend: BlendWeightField::new(
                config,
                sizes.training_frames + 1,
                sizes.joints,
                config.residual_init,
                device,
            ),
            novel_blend: None,
            pose: config.pose_refinement.enabled.then(|| {
                PoseRefinement::new(
                    config.pose_refinement,
                    sizes.training_frames,
                    sizes.joints,
                    device,
                )
            }),
            config: config.clone(),
            occupancy: None,
        })
    }

    /// The occupancy grid, once built.
    pub fn occupancy(&self) -> Option<&OccupancyGrid> {
        self.occupancy.as_ref()
    }

    /// Replaces the occupancy grid (one read from a checkpoint).
    pub fn set_occupancy(&mut self, grid: Option<OccupancyGrid>) {
        self.occupancy = grid;
    }

    /// Builds the occupancy grid from the current density (when the config has `occupancy`).
    pub fn rebuild_occupancy(&mut self, canonical: &CanonicalInputs) {
        if let Some(config) = self.config.occupancy {
            let device = self.nerf.appearance.weight.device();
            let grid = OccupancyGrid::build(&config, canonical.bounds, &device, |p| {
                self.canonical_density(p, canonical)
            });
            self.occupancy = Some(grid);
        }
    }

    /// The training loop's hook after step `step` (counted from 1): rebuilds the grid on the config's schedule.
    pub fn update_occupancy(&mut self, canonical: &CanonicalInputs, step: usize) {
        if self.config.occupancy.is_some_and(|c| c.rebuilds_at(step)) {
            self.rebuild_occupancy(canonical);
        }
    }

    /// The device holding the parameters.
    pub fn device(&self) -> Device {
        self.nerf.appearance.weight.device()
    }

    /// The configuration the model was built with.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Adds a fresh stage-2 field for `novel_frames` poses and freezes every stage-1 parameter.
    pub fn with_novel_field(self, novel_frames: usize, device: &Device) -> Self {
        let joints = self.blend.num_joints();
        Self {
            novel_blend: Some(materialised(BlendWeightField::new(
                &self.config,
                novel_frames,
                joints,
                self.config.novel_residual_init,
                device,
            ))),
            ..self.freeze_stage1()
        }
    }

    /// Marks the canonical NeRF and the stage-1 blend field as constants (no gradients).
    pub fn freeze_stage1(self) -> Self {
        Self {
            nerf: self.nerf.no_grad(),
            blend: self.blend.no_grad(),
            pose: self.pose.map(Module::no_grad),
            ..self
        }
    }

    /// The bones `frame` is rendered with: corrected by the refined fit where the model refines it
    /// ([`Self::refined`]), else as given.
    pub fn frame_bones(&self, frame: &FrameInputs) -> BoneMatrices {
        self.posed_frame(frame).bones
    }

    /// `frame` as this model renders it: its bones corrected once by the refined fit ([`Self::refined`],
    /// without the basis, so that rendering it again does not recompute them), else `frame` itself. A
    /// renderer that marches an image in many chunks of rays calls this once per image.
    pub fn posed_frame(&self, frame: &FrameInputs) -> FrameInputs {
        self.refined(frame).unwrap_or_else(|| frame.clone())
    }

    /// `frame` with its bones corrected by the refined fit (and no basis left) when it is a training frame
    /// of a model that refines fits and carries its given fit ([`FrameInputs::basis`]); `None` otherwise.
    fn refined(&self, frame: &FrameInputs) -> Option<FrameInputs> {
        let (Some(pose), Some(basis), FrameCode::Training(f)) =
            (&self.pose, &frame.basis, frame.code)
        else {
            return None;
        };
        let c = pose.frame(f);
        let bones = basis.bones(c.joints, c.rotation, c.translation);
        Some(FrameInputs {
            warp: Some(CorrectionWarp::new(&frame.bones, &bones)),
            bones,
            basis: None,
            ..frame.clone()
        })
    }

    /// The field and row that give frame weights for `code`.
    fn frame_field(&self, code: FrameCode) -> (&BlendWeightField, usize) {
        match code {
            FrameCode::Training(f) => (&self.blend, f + 1),
            FrameCode::Novel(j) => (
                self.novel_blend
                    .as_ref()
                    .expect("novel-pose frames need the stage-2 field (run `anerf animate`)"),
                j,
            ),
        }
    }

    /// Canonical blend weights `w^can` at canonical points `[M, 3]`.
    pub fn canonical_weights(&self, points: Tensor<2>, canonical: &CanonicalInputs) -> Tensor<2> {
        let prior = canonical.volume.sample(points.clone()).weights;
        if !self.config.neural_blend_weights {
            return self.blend.prior_only(prior);
        }
        self.blend.forward(points, 0, prior)
    }

    /// Frame blend weights `w_i` at pose-space points `[M, 3]` with their prior `[M, K]`.
    pub fn frame_weights(&self, points: Tensor<2>, prior: Tensor<2>, code: FrameCode) -> Tensor<2> {
        self.frame_blend(points, prior, code).0
    }

    /// Frame blend weights `w_i` `[M, K]` and, with the neural field, its residual `F` `[M, K]`.
    pub fn frame_blend(
        &self,
        points: Tensor<2>,
        prior: Tensor<2>,
        code: FrameCode,
    ) -> (Tensor<2>, Option<Tensor<2>>) {
        let m = points.dims()[0];
        self.frames_blend(points, prior, &[(code, m)])
    }

    /// [`Self::frame_blend`] of several frames' points at once: `codes` gives each consecutive group of
    /// points its frame. The frames must share a field (all training or all novel-pose frames).
    fn frames_blend(
        &self,
        points: Tensor<2>,
        prior: Tensor<2>,
        codes: &[(FrameCode, usize)],
    ) -> (Tensor<2>, Option<Tensor<2>>) {
        let (field, _) = self.frame_field(codes[0].0);
        let rows = codes
            .iter()
            .map(|&(code, n)| {
                let (other, row) = self.frame_field(code);
                assert!(
                    std::ptr::eq(field, other),
                    "one render's frames are all training or all novel-pose frames"
                );
                (row, n)
            })
            .collect();
        if !self.config.neural_blend_weights {
            return (field.prior_only(prior), None);
        }
        let residual = field.residual_of(points, &CodeRows::Groups(rows));
        (
            super::blend::combine(self.config.blend, residual.clone(), prior),
            Some(residual),
        )
    }

    /// Raw canonical density at canonical points `[M, 3]`, zero outside the canonical box.
    pub fn canonical_density(&self, points: Tensor<2>, canonical: &CanonicalInputs) -> Tensor<2> {
        let inside = inside_box(points.clone(), &canonical.bounds);
        self.nerf.density(points).mask_fill(inside.bool_not(), 0.0)
    }

    /// Warps pose-space samples `[M, 3]` (prior weights `[M, K]`, world view directions `[M, 3]`) to canonical
    /// space with the frame's neural blend weights and shades them with the canonical NeRF.
    pub fn shade(
        &self,
        points: Tensor<2>,
        prior: Tensor<2>,
        dirs: Tensor<2>,
        frame: &FrameInputs,
        canonical: &CanonicalInputs,
    ) -> ShadedSamples {
        let warped = self.warp(points.clone(), prior, frame);
        let dirs = self.colour_directions(points, dirs, &warped, frame);
        self.radiance(warped, dirs, &CodeRows::One(frame.appearance), canonical)
    }

    /// The blend-weight consistency's inputs at `shaded` samples: their observation weights against the
    /// canonical weights at their warped positions, selected by their raw density.
    pub fn consistency_terms(
        &self,
        shaded: &ShadedSamples,
        canonical: &CanonicalInputs,
    ) -> ConsistencyTerms {
        ConsistencyTerms::new(
            shaded.weights.clone(),
            self.canonical_weights(shaded.canonical_points.clone(), canonical),
            shaded.density.clone(),
            shaded.residual.clone(),
        )
    }

    /// Observation weights, their residual and canonical positions of pose-space samples `[M, 3]`.
    fn warp(&self, points: Tensor<2>, prior: Tensor<2>, frame: &FrameInputs) -> Warped {
        let (weights, residual) = self.frame_blend(points.clone(), prior, frame.code);
        let canonical_points = frame.bones.inverse(points, weights.clone());
        Warped {
            weights,
            residual,
            canonical_points,
        }
    }

    /// The view directions `[M, 3]` the colour head sees for world-space unit directions `dirs` of the
    /// pose-space samples `points`, in the frame [`ModelConfig::view_direction`] names.
    ///
    /// Canonical: the inverse skinning map `x ↦ rot(M)⁻¹ (x − t(M))` is affine in `x` for fixed weights, so
    /// `rot(M)⁻¹ d_pose = x_can − inverse(x − d_pose)`, normalised (`d_pose = R_hᵀ d`).
    fn colour_directions(
        &self,
        points: Tensor<2>,
        dirs: Tensor<2>,
        warped: &Warped,
        frame: &FrameInputs,
    ) -> Tensor<2> {
        match self.config.view_direction {
            ViewDirection::World => dirs,
            ViewDirection::None => dirs.zeros_like(),
            ViewDirection::Canonical => {
                let pose_dirs = world_to_pose_directions(dirs, &frame.global);
                let weights = warped.weights.clone().detach();
                let back = frame.bones.inverse(points - pose_dirs, weights);
                let d = warped.canonical_points.clone().detach() - back;
                let length = d
                    .clone()
                    .powf_scalar(2.0)
                    .sum_dim(1)
                    .sqrt()
                    .clamp_min(1e-12);
                d / length
            }
        }
    }

    /// The canonical NeRF at warped samples seen along colour-head directions `dirs` `[M, 3]`, with the
    /// appearance codes of rows `appearance`.
    fn radiance(
        &self,
        warped: Warped,
        dirs: Tensor<2>,
        appearance: &CodeRows,
        canonical: &CanonicalInputs,
    ) -> ShadedSamples {
        let canonical_points = warped.canonical_points;
        let inside = inside_box(canonical_points.clone(), &canonical.bounds);
        let radiance = self
            .nerf
            .forward(canonical_points.clone(), dirs, appearance);
        ShadedSamples {
            density: radiance.density.mask_fill(inside.clone().bool_not(), 0.0),
            rgb: radiance.rgb,
            canonical_points,
            weights: warped.weights,
            residual: warped.residual,
            inside,
        }
    }

    /// Shades host samples: pose-space points (metres) with world-space unit view directions `[M·3]`. Their
    /// prior weights are read on the host ([`VolumeTensor::weights_at`]) and the samples uploaded, then
    /// shaded as [`Self::shade_frames`] does.
    pub(super) fn shade_survivors(
        &self,
        points: &[Vec3],
        directions: Vec<f32>,
        frame: &FrameInputs,
        canonical: &CanonicalInputs,
    ) -> (Vec<i64>, ShadedSamples) {
        let device = frame.volume.device();
        let m = points.len();
        let samples = FrameSamples {
            points: points_tensor(points, &device),
            prior: frame.volume.weights_at(points),
            dirs: Tensor::from_data(TensorData::new(directions, [m, 3]), &device),
        };
        let mut shaded = self.shade_frames(vec![samples], &[frame], canonical);
        shaded.pop().expect("one frame")
    }

    /// Shades the samples of several frames (`samples[f]` of `frames[f]`) on the device, each frame's with
    /// its bones and codes, the fields once for all of them: the pose-space points are warped and (with an
    /// occupancy grid) those in empty canonical cells dropped. Per frame, the rows of its samples that reached
    /// the canonical NeRF (all of them without a grid; never none) and their shading.
    fn shade_frames(
        &self,
        samples: Vec<FrameSamples>,
        frames: &[&FrameInputs],
        canonical: &CanonicalInputs,
    ) -> Vec<(Vec<i64>, ShadedSamples)> {
        let counts: Vec<usize> = samples.iter().map(|s| s.points.dims()[0]).collect();
        let codes: Vec<(FrameCode, usize)> =
            frames.iter().map(|f| f.code).zip(counts.clone()).collect();
        let (points, priors, dirs): (Vec<_>, Vec<_>, Vec<_>) = samples
            .into_iter()
            .map(|s| (s.points, s.prior, s.dirs))
            .collect();
        let (weights, residual) =
            self.frames_blend(cat_rows(points.clone()), cat_rows(priors), &codes);
        let canonical_points = cat_rows(
            split_rows(weights.clone(), &counts)
                .into_iter()
                .zip(&points)
                .zip(frames)
                .map(|((w, p), frame)| frame.bones.inverse(p.clone(), w))
                .collect(),
        );
        let (mut points, mut dirs) = (cat_rows(points), cat_rows(dirs));
        // The residual's penalty covers every sample that reached the blend-weight field.
        let residuals = match residual {
            Some(r) => split_rows(r, &counts).into_iter().map(Some).collect(),
            None => vec![None; counts.len()],
        };
        let mut kept = Warped {
            weights,
            residual: None,
            canonical_points,
        };
        // Rows kept per frame: those in occupied canonical cells, or all without a grid.
        let rows: Vec<Vec<i64>> = match &self.occupancy {
            None => counts.iter().map(|&n| (0..n as i64).collect()).collect(),
            Some(grid) => {
                let occupied = grid.occupied_rows(&to_host(kept.canonical_points.clone()));
                let rows = frame_rows(&occupied, &counts);
                let all: Vec<i64> = rows
                    .iter()
                    .zip(offsets(&counts))
                    .flat_map(|(r, start)| r.iter().map(move |&j| j + start as i64))
                    .collect();
                let n = all.len();
                let index =
                    Tensor::<1, Int>::from_data(TensorData::new(all, [n]), &points.device());
                let select = |t: Tensor<2>| t.select(0, index.clone());
                kept = Warped {
                    weights: select(kept.weights),
                    residual: None,
                    canonical_points: select(kept.canonical_points),
                };
                (points, dirs) = (select(points), select(dirs));
                rows
            }
        };
        let kept_counts: Vec<usize> = rows.iter().map(Vec::len).collect();
        let dirs = match self.config.view_direction {
            ViewDirection::Canonical => cat_rows(
                frames
                    .iter()
                    .zip(split_rows(points, &kept_counts))
                    .zip(split_rows(dirs, &kept_counts))
                    .zip(split_rows(kept.weights.clone(), &kept_counts))
                    .zip(split_rows(kept.canonical_points.clone(), &kept_counts))
                    .map(|((((frame, p), d), weights), canonical_points)| {
                        let warped = Warped {
                            weights,
                            residual: None,
                            canonical_points,
                        };
                        self.colour_directions(p, d, &warped, frame)
                    })
                    .collect(),
            ),
            _ => self.colour_directions(points, dirs, &kept, frames[0]),
        };
        let appearance = CodeRows::Groups(
            frames
                .iter()
                .map(|f| f.appearance)
                .zip(kept_counts.iter().copied())
                .collect(),
        );
        let shaded = self.radiance(kept, dirs, &appearance, canonical);
        let part = |t: &Tensor<2>| split_rows(t.clone(), &kept_counts);
        let (density, rgb) = (part(&shaded.density), part(&shaded.rgb));
        let (canonical_points, weights) = (part(&shaded.canonical_points), part(&shaded.weights));
        let inside = split_rows(shaded.inside, &kept_counts);
        rows.into_iter()
            .zip(density)
            .zip(rgb)
            .zip(canonical_points)
            .zip(weights)
            .zip(residuals)
            .zip(inside)
            .map(
                |((((((rows, density), rgb), canonical_points), weights), residual), inside)| {
                    let shaded = ShadedSamples {
                        density,
                        rgb,
                        canonical_points,
                        weights,
                        residual,
                        inside,
                    };
                    (rows, shaded)
                },
            )
            .collect()
    }

    /// The samples of `rays` at `depths` (`[R, S]`) that survive culling where `culling` says, on the device.
    fn survivors(
        &self,
        culling: Culling,
        rays: &RayBatch,
        depths: Tensor<2>,
        frame: &FrameInputs,
    ) -> DeviceSurvivors {
        match culling {
            Culling::Device => cull_on_device(
                rays,
                depths,
                &frame.global,
                &frame.volume,
                self.config.cull_distance,
                frame.warp.as_ref(),
            ),
            Culling::Host => {
                let device = rays.origins.device();
                let survivors = cull_samples(
                    &SampleRays {
                        origins: &to_host(rays.origins.clone()),
                        directions: &to_host(rays.directions.clone()),
                        depths: &to_host(depths.clone()),
                        samples: depths.dims()[1],
                    },
                    &frame.global,
                    &frame.volume,
                    self.config.cull_distance,
                    frame.warp.as_ref().map(CorrectionWarp::host),
                );
                let m = survivors.index.len();
                DeviceSurvivors {
                    index: Tensor::from_data(TensorData::new(survivors.index, [m]), &device),
                    prior: frame.volume.weights_at(&survivors.points),
                    points: points_tensor(&survivors.points, &device),
                    directions: Tensor::from_data(
                        TensorData::new(survivors.directions, [m, 3]),
                        &device,
                    ),
                }
            }
        }
    }

    /// Renders `rays` of one frame ([`Self::render_frames`] of one).
    pub fn render(
        &self,
        rays: &RayBatch,
        frame: &FrameInputs,
        canonical: &CanonicalInputs,
        jitter: Option<Tensor<2>>,
        with_consistency: bool,
    ) -> RenderOutput {
        let part = FrameRays {
            rays,
            frame,
            jitter,
        };
        let mut out = self.render_frames(vec![part], canonical, with_consistency);
        out.pop().expect("one frame")
    }

    /// Renders the rays of several frames, one output per frame, as [`Self::render`] renders each alone, but
    /// with one call of each field for all of them: a training step of several frames then pays the fields'
    /// fixed costs (a hash table's dense gradient, every layer's operations) once, not once per frame. The
    /// frames must all be training frames or all novel-pose frames (one blend-weight field). Each part's
    /// `jitter` (`[R, S]` uniform in `[0, 1)`) perturbs its depths when training; `with_consistency` also
    /// returns the inputs of the blend-weight consistency loss.
    ///
    /// Samples whose distance to the body (the frame volume's last channel) is at least `cull_distance` never
    /// reach an MLP: on CPU backends culling and the survivors' prior weights are computed on the host
    /// ([`cull_samples`], [`VolumeTensor::weights_at`]) and the survivors uploaded; on GPU backends both run
    /// on the device ([`cull_on_device`]). The survivors are shaded and scattered back; culled samples
    /// have zero density.
    /// The sample closest to the body is always kept, so no frame's MLP batch is empty. With an occupancy grid
    /// ([`Self::rebuild_occupancy`]), survivors whose warped position falls in an empty canonical cell skip the
    /// canonical NeRF (and the canonical blend weights) too: one more read-back of their canonical positions.
    pub fn render_frames(
        &self,
        parts: Vec<FrameRays<'_>>,
        canonical: &CanonicalInputs,
        with_consistency: bool,
    ) -> Vec<RenderOutput> {
        let s = self.config.samples_per_ray;
        let frames: Vec<FrameInputs> = parts.iter().map(|p| self.posed_frame(p.frame)).collect();
        let (rays, depths): (Vec<&RayBatch>, Vec<Tensor<2>>) = parts
            .into_iter()
            .map(|p| {
                let depths =
                    stratified_depths(p.rays.near.clone(), p.rays.far.clone(), s, p.jitter);
                (p.rays, depths)
            })
            .unzip();
        let culling = Culling::for_device(&rays[0].origins.device());
        // Per frame, its survivors' flat indices `ray · S + sample`, and the survivors to shade.
        let (indices, samples): (Vec<Tensor<1, Int>>, Vec<FrameSamples>) = rays
            .iter()
            .zip(&depths)
            .zip(&frames)
            .map(|((rays, depths), frame)| {
                let survivors = self.survivors(culling, rays, depths.clone(), frame);
                let samples = FrameSamples {
                    points: survivors.points,
                    prior: survivors.prior,
                    dirs: survivors.directions,
                };
                (survivors.index, samples)
            })
            .unzip();
        let frame_refs: Vec<&FrameInputs> = frames.iter().collect();
        let shaded = self.shade_frames(samples, &frame_refs, canonical);
        let canonical_weights = with_consistency.then(|| {
            let points = shaded
                .iter()
                .map(|(_, s)| s.canonical_points.clone())
                .collect();
            let counts: Vec<usize> = shaded.iter().map(|(rows, _)| rows.len()).collect();
            split_rows(self.canonical_weights(cat_rows(points), canonical), &counts)
        });
        let mut canonical_weights = canonical_weights.map(Vec::into_iter);
        shaded
            .into_iter()
            .zip(indices)
            .zip(rays)
            .zip(depths)
            .map(|((((rows, shaded), survivors), rays), depths)| {
                let device = rays.origins.device();
                let (r, surviving, occupied) = (rays.len(), survivors.dims()[0], rows.len());
                let n = r * s;
                let index = if occupied == surviving {
                    survivors
                } else {
                    let rows =
                        Tensor::<1, Int>::from_data(TensorData::new(rows, [occupied]), &device);
                    survivors.select(0, rows)
                };
                let consistency = canonical_weights.as_mut().map(|c| {
                    ConsistencyTerms::new(
                        shaded.weights.clone(),
                        c.next().expect("canonical weights of every frame"),
                        shaded.density.clone(),
                        shaded.residual.clone(),
                    )
                });
                let density = Tensor::<2>::zeros([n, 1], &device).select_assign(
                    0,
                    index.clone(),
                    shaded.density,
                    IndexingUpdateOp::Add,
                );
                let rgb = Tensor::<2>::zeros([n, 3], &device).select_assign(
                    0,
                    index,
                    shaded.rgb,
                    IndexingUpdateOp::Add,
                );
                let out = composite(density.reshape([r, s]), rgb.reshape([r, s, 3]), depths);
                RenderOutput {
                    rgb: out.rgb,
                    acc: out.acc,
                    depth: out.depth,
                    alpha: out.alpha,
                    consistency,
                    surviving_samples: surviving,
                    occupied_samples: occupied,
                    total_samples: n,
                }
            })
            .collect()
    }
}

/// One frame's rays in a render of several frames ([`AnimatableNerf::render_frames`]).
pub struct FrameRays<'a> {
    pub rays: &'a RayBatch,
    pub frame: &'a FrameInputs,
    /// `[R, S]` uniform in `[0, 1)`: the depths' jitter when training.
    pub jitter: Option<Tensor<2>>,
}

/// One frame's samples to shade: pose-space points `[M, 3]` (metres), their prior weights `[M, K]` and
/// world-space unit view directions `[M, 3]`.
struct FrameSamples {
    points: Tensor<2>,
    prior: Tensor<2>,
    dirs: Tensor<2>,
}

/// The parts' rows one after the other (the part itself when there is one).
fn cat_rows<const D: usize, K: burn::tensor::kind::Basic>(
    mut parts: Vec<Tensor<D, K>>,
) -> Tensor<D, K> {
    if parts.len() == 1 {
        return parts.pop().expect("one part");
    }
    Tensor::cat(parts, 0)
}

/// `t` cut into consecutive parts of `counts` rows (`t` itself when there is one part).
fn split_rows<const D: usize, K: burn::tensor::kind::Basic>(
    t: Tensor<D, K>,
    counts: &[usize],
) -> Vec<Tensor<D, K>> {
    if counts.len() == 1 {
        return vec![t];
    }
    offsets(counts)
        .zip(counts)
        .map(|(start, &n)| t.clone().narrow(0, start, n))
        .collect()
}

/// The first row of each part of `counts` rows.
fn offsets(counts: &[usize]) -> impl Iterator<Item = usize> + '_ {
    counts.iter().scan(0, |start, &n| {
        let first = *start;
        *start += n;
        Some(first)
    })
}

/// `occupied` (ascending rows of the concatenated parts of `counts` rows) as each part's own rows; a part
/// with none keeps its first row, so that no frame's batch is empty.
fn frame_rows(occupied: &[i64], counts: &[usize]) -> Vec<Vec<i64>> {
    let mut rows = vec![Vec::new(); counts.len()];
    let ends: Vec<usize> = offsets(counts).zip(counts).map(|(s, n)| s + n).collect();
    let mut part = 0;
    for &j in occupied {
        while j as usize >= ends[part] {
            part += 1;
        }
        rows[part].push(j - (ends[part] - counts[part]) as i64);
    }
    for r in &mut rows {
        if r.is_empty() {
            r.push(0);
        }
    }
    rows
}

/// `mean(F²)` of a residual `[M, K]`; zero for none.
pub fn residual_penalty(residual: Option<Tensor<2>>, device: &Device) -> Tensor<1> {
    match residual {
        Some(f) => f.powf_scalar(2.0).mean(),
        None => Tensor::zeros([1], device),
    }
}

/// `[M, 1]` bool: the point lies inside `bounds` (inclusive).
pub fn inside_box(points: Tensor<2>, bounds: &Aabb) -> Tensor<2, Bool> {
    let device = points.device();
    let min = Tensor::<2>::from_floats([bounds.min.to_array()], &device);
    let max = Tensor::<2>::from_floats([bounds.max.to_array()], &device);
    let lower = (points.clone() - min).min_dim(1).greater_equal_elem(0.0);
    let upper = (max - points).min_dim(1).greater_equal_elem(0.0);
    lower.bool_and(upper)
}

/// `[M, 1]` float mask: raw density > 0 (the reference's `train_th = 0`), plus the densest sample.
pub fn consistency_mask(density: Tensor<2>) -> Tensor<2> {
    let density = density.detach();
    let [m, _] = density.dims();
    let device = density.device();
    let positive = density.clone().greater_elem(0.0);
    let densest = density.argmax(0).repeat_dim(0, m);
    let is_densest = Tensor::<1, Int>::arange(0..m as i64, &device)
        .reshape([m, 1])
        .equal(densest);
    positive.bool_or(is_densest).float()
}
