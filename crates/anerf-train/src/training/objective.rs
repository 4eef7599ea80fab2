//! The stage-1 objective in three parts: the sums of its terms over one shard's rays and samples
//! ([`TermSums`], from the model's render), the counts of the whole batch they are divided by ([`Totals`]:
//! the shard's own on one device, exchanged between the shards of a data-parallel step), and the terms'
//! weights ([`Objective`]). Every term is a mean over the batch's rays or samples, so the shards' losses
//! average to the batch's. `anerf bench` times its step with the same objective ([`TermSums::of_points`]).
//! Stage 2's terms come from the model too ([`Stage2Terms`]) and are weighed here ([`Stage2Objective`]).

use anerf_core::model::stage2::Stage2Terms;
use anerf_core::model::{ConsistencyLoss, ConsistencyTerms, RenderOutput};
use anerf_core::render::RayBatch;
use anerf_core::tensor::to_host;
use burn::prelude::*;

use super::parallel::Shard;
use crate::config::{MaskEdges, StageConfig};

/// The sums of one shard's terms, with the counts it knows of its own.
pub struct TermSums {
    rays: usize,
    data: RayErrors,
    consistency: Option<ConsistencySums>,
    /// `Σ F²` of the blend-weight residual and its entry count (when penalised).
    residual: Option<(Tensor<1>, usize)>,
}

/// The blend-weight consistency's numerator and what decides its denominator.
struct ConsistencySums {
    /// `Σ` of the per-entry loss over the selected samples × joints.
    sum: Tensor<1>,
    /// `[1]` the samples selected on this shard (density > 0, or the densest where none is).
    selected: Tensor<1>,
    joints: usize,
    /// `[M, 1]` the samples' raw density (detached): which are positive and which is the densest decides
    /// the selection of the whole batch.
    density: Tensor<2>,
}

impl TermSums {
    /// The terms of `out`, rendered from `rays` (with their colours and masks).
    pub fn new(
        out: &RenderOutput,
        rays: &RayBatch,
        cfg: &StageConfig,
        consistency: ConsistencyLoss,
    ) -> Self {
        let target = rays.colors.clone().expect("training rays carry colours");
        let rgb = over_backgrounds(out.rgb.clone(), &out.acc, rays.backgrounds.as_ref());
        let silhouette = rays.foreground.as_ref().map(|m| Silhouette {
            acc: &out.acc,
            label: m,
            labelled: rays.labelled.as_ref(),
        });
        let mut data = RayErrors::new(rgb, target, silhouette, rays.edge.as_ref(), cfg);
        if cfg.hard_surface_weight > 0.0 {
            data.add_hard_surface(&out.alpha, cfg.hard_surface_weight);
        }
        Self::from_parts(data, out.consistency.as_ref(), cfg, consistency)
    }

    /// The terms of shaded points `rgb` `[M, 3]` against colours `target` `[M, 3]`, each point a ray of
    /// its own (no silhouette, no band), with the consistency `terms` of the same points: `anerf bench`'s
    /// step, the model's per-sample work with this objective on top.
    pub fn of_points(
        rgb: Tensor<2>,
        target: Tensor<2>,
        terms: &ConsistencyTerms,
        cfg: &StageConfig,
        consistency: ConsistencyLoss,
    ) -> Self {
        let data = RayErrors::new(rgb, target, None, None, cfg);
        Self::from_parts(data, Some(terms), cfg, consistency)
    }

    fn from_parts(
        data: RayErrors,
        terms: Option<&ConsistencyTerms>,
        cfg: &StageConfig,
        consistency: ConsistencyLoss,
    ) -> Self {
        Self {
            rays: data.rays,
            data,
            consistency: terms.map(|c| {
                let parts = c.loss_parts(consistency);
                ConsistencySums {
                    sum: parts.sum,
                    selected: parts.selected,
                    joints: c.observed.dims()[1],
                    density: c.density.clone(),
                }
            }),
            residual: terms
                .and_then(|c| c.residual.clone())
                .filter(|_| cfg.residual_weight > 0.0)
                .map(|f| {
                    let entries = f.dims().iter().product();
                    (f.powf_scalar(2.0).sum(), entries)
                }),
        }
    }

    /// The counts of a batch of which these are all the terms (one device); the selected count stays on
    /// the device.
    pub fn local_totals(&self) -> Totals {
        Totals {
            rays: self.rays as f32,
            residual: self.residual.as_ref().map_or(0, |r| r.1) as f32,
            consistency: self.consistency.as_ref().map(|c| (1.0, c.selected.clone())),
        }
    }

    /// The batch's counts: this shard's own when it is the only one ([`Self::local_totals`]); otherwise
    /// exchanged with the other shards of the step.
    pub(super) fn totals(&self, shard: &Shard<'_>, device: &Device) -> Totals {
        if shard.count == 1 {
            return self.local_totals();
        }
        let residual_entries = self.residual.as_ref().map_or(0, |r| r.1);
        // The shards exchange their rays, positive-density samples and residual entries, and their greatest
        // density: the consistency mask's guard adds the densest sample only where no sample is positive,
        // which must be decided for the whole batch. A shard whose own selection the batch's does not hold
        // contributes zero (its term kept, times zero, so that every replica's graph holds the same
        // parameters, as the all-reduce needs).
        let (own_positive, own_densest) = match &self.consistency {
            Some(c) => {
                let positive = c.density.clone().greater_elem(0.0).float().sum();
                let v = to_host(Tensor::cat(vec![positive, c.density.clone().max()], 0));
                (v[0] as f64, v[1] as f64)
            }
            None => (0.0, f64::NEG_INFINITY),
        };
        let totals = shard.sum(
            0,
            &[self.rays as f64, own_positive, residual_entries as f64],
        );
        let densest = shard.max(1, own_densest);
        // With no positive sample anywhere, the shards holding the batch's densest (one, but for ties).
        let holds_densest = f64::from(u8::from(own_densest == densest));
        let holders = shard.sum(2, &[holds_densest])[0];
        let (weight, selected) = if totals[1] > 0.0 {
            (f64::from(u8::from(own_positive > 0.0)), totals[1])
        } else {
            (holds_densest, holders)
        };
        Totals {
            rays: totals[0] as f32,
            residual: totals[2] as f32,
            consistency: self.consistency.as_ref().map(|_| {
                (
                    weight as f32,
                    Tensor::<1>::from_floats([selected as f32], device),
                )
            }),
        }
    }
}

/// The counts of the whole batch that a shard's sums are divided by.
pub struct Totals {
    rays: f32,
    residual: f32,
    /// The weight of this shard's consistency sum (0 where the batch's selection excludes its samples) and
    /// the batch's selected samples `[1]`.
    consistency: Option<(f32, Tensor<1>)>,
}

/// The weighted means of one shard's terms, each times the shard count: Burn averages the replicas'
/// gradients, and the shards' losses average to the batch's.
pub struct WeighedTerms {
    pub loss: Tensor<1>,
    /// The colour MSE (logged as the training rays' PSNR).
    pub mse: Tensor<1>,
    /// Consistency plus weighted residual penalty (when the model has the blend-weight terms).
    pub blend: Option<Tensor<1>>,
}

impl WeighedTerms {
    /// Every term times `share` plus `rest`'s (`None`: nothing yet): a step's terms summed over its
    /// frames, each weighed by its share of the step's rays.
    pub fn weighed_onto(self, share: f32, rest: Option<Self>) -> Self {
        let (loss, mse, blend) = (
            self.loss * share,
            self.mse * share,
            self.blend.map(|b| b * share),
        );
        match rest {
            None => Self { loss, mse, blend },
            Some(r) => Self {
                loss: r.loss + loss,
                mse: r.mse + mse,
                blend: r.blend.zip(blend).map(|(a, b)| a + b),
            },
        }
    }
}

/// The stage-1 loss's weights: colour and silhouette (with the band's robust loss) from the stage's
/// config, the consistency at weight 1 (the paper), the residual penalty at `residual_weight`.
pub struct Objective<'a> {
    pub cfg: &'a StageConfig,
}

impl Objective<'_> {
    /// `sums` divided by the batch's `totals` and weighed, for one of `shards` shards.
    pub fn weigh(&self, sums: TermSums, totals: Totals, shards: usize) -> WeighedTerms {
        let n = shards as f32;
        let mse = sums.data.colour / totals.rays * n;
        let data = sums.data.loss / totals.rays * n;
        let blend = sums
            .consistency
            .zip(totals.consistency)
            .map(|(c, (weight, selected))| {
                let consistency = c.sum * weight / (selected.clamp_min(1.0) * c.joints as f32) * n;
                match sums.residual {
                    Some((sum, _)) => {
                        consistency + sum / totals.residual * (self.cfg.residual_weight * n)
                    }
                    None => consistency,
                }
            });
        let loss = match &blend {
            Some(b) => data + b.clone(),
            None => data,
        };
        WeighedTerms { loss, mse, blend }
    }
}

/// Stage 2's loss weights: both consistency directions at weight 1 (the authors'), the new field's residual
/// penalty at `residual_weight`.
pub struct Stage2Objective<'a> {
    pub cfg: &'a StageConfig,
}

impl Stage2Objective<'_> {
    pub fn weigh(&self, terms: Stage2Terms) -> Tensor<1> {
        let consistency = terms.consistency();
        if self.cfg.residual_weight > 0.0 {
            consistency + terms.residual * self.cfg.residual_weight
        } else {
            consistency
        }
    }
}

/// `C + (1 − acc)·B`: the rays' colours on black `rgb` `[R, 3]` over the colours behind them `backgrounds`
/// `[R, 3]` (unchanged without), given their opacity `acc` `[R]`.
fn over_backgrounds(rgb: Tensor<2>, acc: &Tensor<1>, backgrounds: Option<&Tensor<2>>) -> Tensor<2> {
    match backgrounds {
        Some(b) => {
            let n = acc.dims()[0];
            rgb + b.clone() * (acc.clone().neg() + 1.0).reshape([n, 1])
        }
        None => rgb,
    }
}

/// The rays' rendered opacity `acc` `[R]` against their mask labels `[R]`, on the rays `labelled` marks
/// (all where absent).
struct Silhouette<'a> {
    acc: &'a Tensor<1>,
    label: &'a Tensor<1>,
    labelled: Option<&'a Tensor<1>>,
}

/// The data terms of a shard's rays, as sums over its rays.
struct RayErrors {
    rays: usize,
    /// `Σ_r mean_c (rgb − target)²`: the colour loss.
    colour: Tensor<1>,
    /// `Σ_r ρ_r(e_r)`: `e_r` is the ray's colour error plus `mask_weight · (acc − m)²`; `ρ_r` is the
    /// identity, or for band rays under `mask_edges = "robust"` the pseudo-Huber `2c²(√(1 + e/c²) − 1)` of
    /// scale `c = edge_scale`: `e` for small errors, `2c·√e` for large ones, so that a band ray whose
    /// labels the rest of the data contradicts pulls with a bounded force.
    loss: Tensor<1>,
}

impl RayErrors {
    /// `rgb`, `target`: `[R, 3]`; `silhouette`: the rays' opacity against their labels, where known;
    /// `edge`: `[R]` 1 on band rays, where known.
    fn new(
        rgb: Tensor<2>,
        target: Tensor<2>,
        silhouette: Option<Silhouette>,
        edge: Option<&Tensor<1>>,
        cfg: &StageConfig,
    ) -> Self {
        let n = rgb.dims()[0];
        let colour = (rgb - target).powf_scalar(2.0).sum_dim(1).reshape([n]) / 3.0;
        let per_ray = match (silhouette, cfg.mask_weight > 0.0) {
            (Some(s), true) => {
                let miss = (s.acc.clone() - s.label.clone()).powf_scalar(2.0) * cfg.mask_weight;
                let miss = match s.labelled {
                    Some(labelled) => miss * labelled.clone(),
                    None => miss,
                };
                colour.clone() + miss
            }
            _ => colour.clone(),
        };
        let loss = match (edge, cfg.mask_edges) {
            (Some(edge), MaskEdges::Robust | MaskEdges::Backdrop) => {
                let c2 = cfg.edge_scale * cfg.edge_scale;
                let robust = ((per_ray.clone() / c2 + 1.0).sqrt() - 1.0) * (2.0 * c2);
                per_ray.clone() + (robust - per_ray) * edge.clone()
            }
            _ => per_ray,
        };
        Self {
            rays: n,
            colour: colour.sum(),
            loss: loss.sum(),
        }
    }

    /// Adds `weight · Σ_r Σ_k α_rk (1 − α_rk)` for the rays' sample opacities `alpha` `[R, S]`.
    fn add_hard_surface(&mut self, alpha: &Tensor<2>, weight: f32) {
        let binary = alpha.clone() * (alpha.clone().neg() + 1.0);
        self.loss = self.loss.clone() + binary.sum() * weight;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{self, Settings};
    use anerf_core::render::HostRays;
    use anerf_core::tensor::from_rows;
    use anerf_core::FrameId;
    use anerf_device::cpu_device;
    use anerf_testing::{assert_close, Tolerance};

    /// The data loss against its definition, worked here in f64: each ray's error `e` is its mean squared
    /// colour error plus `mask_weight · (acc − m)²`; under `robust` a band ray's loss is the pseudo-Huber
    /// `2c²(√(1 + e/c²) − 1)` of it, so its opacity's gradient is `2 · mask_weight · (acc − m) / √(1 + e/c²)`;
    /// under `train` the band flags change nothing; under `backdrop` a band ray whose background is known
    /// carries no label (`labelled` 0, `edge` 0) and one whose background is not is weighed as under
    /// `robust`.
    #[test]
    fn band_rays_weigh_their_error_by_the_pseudo_huber_under_robust() {
        let rgb = [
            [0.5, 0.0, 1.0],
            [0.25, 0.25, 0.25],
            [0.9, 0.8, 0.7],
            [0.1, 0.1, 0.1],
        ];
        let target = [
            [0.0, 0.0, 0.0],
            [0.25, 0.75, 0.25],
            [0.0, 0.0, 0.0],
            [0.1, 0.2, 0.1],
        ];
        let acc = [0.2f32, 0.9, 1.0, 0.05];
        let foreground = [false, true, false, false];
        let band = [false, true, true, true];
        let device = cpu_device().autodiff();
        for edges in ["robust", "train", "backdrop"] {
            // Under `backdrop`, ray 1's background is known and rays 2 and 3's are not.
            let (edge, labelled) = match edges {
                "backdrop" => ([false, false, true, true], vec![true, false, true, true]),
                _ => (band, Vec::new()),
            };
            let host = HostRays {
                near: vec![1.0; 4],
                far: vec![2.0; 4],
                origins: vec![[0.0; 3]; 4],
                directions: vec![[0.0, 0.0, 1.0]; 4],
                colors: target.to_vec(),
                pixels: vec![[0, 0]; 4],
                foreground: foreground.to_vec(),
                edge: edge.to_vec(),
                backgrounds: Vec::new(),
                labelled: labelled.clone(),
            };
            let set = [
                "train.mask_weight=0.1".to_string(),
                "train.edge_scale=0.2".to_string(),
                format!("train.mask_edges={edges}"),
            ];
            let cfg = config::assemble(config::demo_table(), &Settings::default(), &set)
                .unwrap()
                .train;
            let rays = RayBatch::new(&host, FrameId(0), &device);
            let opacity = Tensor::<1>::from_floats(acc, &device).require_grad();
            let errors = RayErrors::new(
                from_rows(rgb.as_flattened(), 4, 3, &device),
                rays.colors.clone().unwrap(),
                Some(Silhouette {
                    acc: &opacity,
                    label: rays.foreground.as_ref().unwrap(),
                    labelled: rays.labelled.as_ref(),
                }),
                rays.edge.as_ref(),
                &cfg,
            );
            let (c, w) = (0.2f64, 0.1f64);
            let (mut colour, mut loss) = (0.0, 0.0);
            let mut gradient = Vec::new();
            for r in 0..4 {
                let squared: f64 = (0..3)
                    .map(|k| (rgb[r][k] as f64 - target[r][k] as f64).powi(2))
                    .sum::<f64>()
                    / 3.0;
                let trained = labelled.get(r).copied().unwrap_or(true);
                let miss = f64::from(u8::from(trained))
                    * (acc[r] as f64 - f64::from(u8::from(foreground[r])));
                let e = squared + w * miss * miss;
                colour += squared;
                let slope = if edges != "train" && edge[r] {
                    loss += 2.0 * c * c * ((1.0 + e / (c * c)).sqrt() - 1.0);
                    1.0 / (1.0 + e / (c * c)).sqrt()
                } else {
                    loss += e;
                    1.0
                };
                gradient.push((slope * 2.0 * w * miss) as f32);
            }
            let got = to_host(errors.colour)[0];
            assert!(
                (got as f64 - colour).abs() < 1e-5,
                "{edges}: colour {got} vs {colour}"
            );
            let got = to_host(errors.loss.clone())[0];
            assert!(
                (got as f64 - loss).abs() < 1e-5,
                "{edges}: loss {got} vs {loss}"
            );
            let grads = errors.loss.backward();
            assert_close(
                &format!("{edges}: opacity gradient"),
                &to_host(opacity.grad(&grads).unwrap()),
                &gradient,
                Tolerance::Relative(1e-4),
            );
        }
    }

    /// `C + (1 − acc)·B` per ray and channel, and its gradient in the opacity, `−Σ_c g_c B_c`.
    #[test]
    fn renders_are_composited_over_the_rays_backgrounds() {
        let device = cpu_device().autodiff();
        let rgb = [[0.2f32, 0.1, 0.0], [0.5, 0.5, 0.5], [0.0, 0.0, 0.0]];
        let acc = [0.25f32, 1.0, 0.0];
        let b = [[0.4f32, 0.8, 0.2], [0.9, 0.9, 0.9], [0.3, 0.6, 0.1]];
        let g = [[1.0f32, -2.0, 0.5], [0.3, 0.3, 0.3], [-1.0, 1.0, 2.0]];
        let opacity = Tensor::<1>::from_floats(acc, &device).require_grad();
        let backgrounds = from_rows(b.as_flattened(), 3, 3, &device);
        let out = over_backgrounds(
            from_rows(rgb.as_flattened(), 3, 3, &device),
            &opacity,
            Some(&backgrounds),
        );
        let want: Vec<f32> = (0..9)
            .map(|i| rgb[i / 3][i % 3] + (1.0 - acc[i / 3]) * b[i / 3][i % 3])
            .collect();
        assert_close(
            "composited",
            &to_host(out.clone()),
            &want,
            Tolerance::Absolute(1e-6),
        );
        let grads = (out * from_rows(g.as_flattened(), 3, 3, &device))
            .sum()
            .backward();
        let want: Vec<f32> = (0..3)
            .map(|r| -(0..3).map(|c| g[r][c] * b[r][c]).sum::<f32>())
            .collect();
        assert_close(
            "opacity gradient",
            &to_host(opacity.grad(&grads).unwrap()),
            &want,
            Tolerance::Absolute(1e-6),
        );
        let plain = from_rows(rgb.as_flattened(), 3, 3, &device);
        assert_eq!(
            to_host(over_backgrounds(plain.clone(), &opacity, None)),
            to_host(plain)
        );
    }

    /// The hard-surface prior against its definition in f64: `weight · Σ_r Σ_k α_rk (1 − α_rk)` with
    /// `α = 1 − exp(−σ δ)` of each composited sample, and its gradient in the densities,
    /// `weight · (1 − 2α)(1 − α) δ` (zero where the ReLU clips σ).
    #[test]
    fn the_hard_surface_prior_is_each_samples_binary_variance() {
        let device = cpu_device().autodiff();
        let sigma = [[0.5f32, 4.0, -1.0, 30.0], [0.0, 12.0, 2.5, 0.2]];
        let depths = [[1.0f32, 1.1, 1.3, 1.35], [2.0, 2.05, 2.2, 2.4]];
        let density = from_rows(sigma.as_flattened(), 2, 4, &device).require_grad();
        let out = anerf_core::render::composite(
            density.clone(),
            Tensor::zeros([2, 4, 3], &device),
            from_rows(depths.as_flattened(), 2, 4, &device),
        );
        let cfg = config::assemble(
            config::demo_table(),
            &Settings::default(),
            &["train.hard_surface_weight=0.3".to_string()],
        )
        .unwrap()
        .train;
        let mut errors = RayErrors::new(
            out.rgb.clone(),
            Tensor::zeros([2, 3], &device),
            None,
            None,
            &cfg,
        );
        errors.add_hard_surface(&out.alpha, cfg.hard_surface_weight);
        let (mut expected, mut gradient) = (0.0f64, Vec::new());
        for r in 0..2 {
            for k in 0..4 {
                // The last interval repeats the one before it.
                let delta = depths[r][k.min(2) + 1] as f64 - depths[r][k.min(2)] as f64;
                let s = (sigma[r][k] as f64).max(0.0);
                let alpha = 1.0 - (-s * delta).exp();
                expected += 0.3 * alpha * (1.0 - alpha);
                let active = if sigma[r][k] > 0.0 { 1.0 } else { 0.0 };
                gradient.push(0.3 * (1.0 - 2.0 * alpha) * (1.0 - alpha) * delta * active);
            }
        }
        let loss = errors.loss;
        assert_close(
            "prior",
            &to_host(loss.clone()),
            &[expected as f32],
            Tolerance::Relative(1e-5),
        );
        let grads = loss.backward();
        let got = to_host(density.grad(&grads).expect("the densities get a gradient"));
        let gradient: Vec<f32> = gradient.into_iter().map(|g| g as f32).collect();
        assert_close(
            "density gradient",
            &got,
            &gradient,
            Tolerance::Absolute(1e-6),
        );
    }
}
