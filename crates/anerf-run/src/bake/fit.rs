//! Fine-tuning a baked avatar against the run's training images: each step renders one training view of
//! one training frame (cropped to the body's box) through the splat rasteriser, posed with the bones the
//! NeRF was trained with, and moves the Gaussians by Adam on an L1 colour loss plus a silhouette loss
//! outside the mask-edge band;
//! every so often the least opaque Gaussians are pruned and those whose means moved most are split, within
//! the budget (3D Gaussian Splatting's densification, on the means' gradients in canonical space).

use anerf_core::gaussians::{render, GaussianCloud, SplatView};
use anerf_core::geometry::{BoneMatrices, Camera, GlobalTransform, PixelConvention};
use anerf_core::tensor::{from_rows, to_host};
use anerf_data::formats::images::channel_byte;
use anyhow::Result;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;
use glam::{Quat, Vec3};
use image::{GrayImage, Rgb32FImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::adam::RowAdam;
use super::store::BakedAvatar;
use anerf_train::progress::StageProgress;

/// Weight of the silhouette term `mean((alpha − mask)²)` over the pixels outside the mask-edge band, beside
/// the L1 colour term: as strong as the colour term, because on black a faint halo costs the colour term
/// nothing (docs/QUALITY.md, "The bake's silhouette").
const MASK_WEIGHT: f32 = 1.0;
/// Learning rates: means (metres, decaying a hundredfold over the fit), log-scales, quaternions, opacity
/// logits, colour coefficients (3D Gaussian Splatting's, for a body-sized scene).
const LR_MEANS: f64 = 2e-4;
const LR_OTHERS: [f64; 4] = [5e-3, 1e-3, 2.5e-2, 2.5e-3];
/// Densify every this many steps, through the first half of the fit.
const DENSIFY_EVERY: usize = 100;
/// A densification splits at most this fraction of the Gaussians.
const SPLIT_FRACTION: f32 = 0.05;
/// Gaussians less opaque than this, or wider than this many metres, are pruned.
const PRUNE_OPACITY: f32 = 0.005;
const PRUNE_SCALE: f32 = 0.2;
/// A split child's scales are its parent's over this.
const SPLIT_SHRINK: f32 = 1.6;
/// Pixels around the body's projected box that a training crop keeps.
const CROP_MARGIN: f32 = 4.0;

/// One training image: a crop around the body, its camera moved to the crop, and the pose it shows.
///
/// A fit holds every training crop for its whole length, so the pixels stay at the prepared cache's 8 bits
/// a channel and the labels are bytes: [`Shot::BYTES_PER_PIXEL`] a pixel instead of 20 as floats. Each step
/// widens its one crop to floats.
#[derive(Debug, Clone)]
pub struct Shot {
    pub camera: Camera,
    pub global: GlobalTransform,
    pub bones: anerf_core::geometry::BoneTransforms,
    /// The crop on black (background set to 0), row-major RGB, `255 ×` the colour in `[0, 1]`.
    colour: Vec<[u8; 3]>,
    /// The crop's mask, true on the body.
    mask: Vec<bool>,
    /// True where the silhouette term counts: outside the mask-edge band `dilate − erode`, where a mask is
    /// either wrong (a capture's) or conservative (it marks every pixel the body touches, and would pull a
    /// partly covered pixel to full opacity).
    labelled: Vec<bool>,
}

impl Shot {
    /// Bytes a crop holds per pixel: three colour channels, the mask and the label.
    pub const BYTES_PER_PIXEL: u64 = 5;

    /// The crop of `image`, `mask` and its mask-edge band `band` (row-major; seen by `camera`) around the
    /// corners of the body's world box `corners`, with `CROP_MARGIN` pixels around them. The colours are
    /// rounded to 8 bits, as the prepared cache stores them (so a cached image is kept exactly).
    pub fn crop(
        camera: &Camera,
        corners: &[Vec3],
        image: &Rgb32FImage,
        (mask, band): (&GrayImage, &[bool]),
        global: GlobalTransform,
        bones: anerf_core::geometry::BoneTransforms,
    ) -> Self {
        let (w, h) = (camera.width, camera.height);
        let projected: Option<Vec<glam::Vec2>> = corners
            .iter()
            .map(|&c| camera.project(c, PixelConvention::Integer))
            .collect();
        let (x0, y0, x1, y1) = match projected {
            Some(points) => {
                let lo = points.iter().fold(glam::Vec2::INFINITY, |a, &p| a.min(p));
                let hi = points
                    .iter()
                    .fold(glam::Vec2::NEG_INFINITY, |a, &p| a.max(p));
                let clip = |v: f32, n: u32| v.clamp(0.0, n as f32 - 1.0) as u32;
                (
                    clip((lo.x - CROP_MARGIN).floor(), w),
                    clip((lo.y - CROP_MARGIN).floor(), h),
                    clip((hi.x + CROP_MARGIN).ceil(), w),
                    clip((hi.y + CROP_MARGIN).ceil(), h),
                )
            }
            None => (0, 0, w - 1, h - 1),
        };
        let (cw, ch) = (x1 - x0 + 1, y1 - y0 + 1);
        let pixels = (cw * ch) as usize;
        let mut colour = Vec::with_capacity(pixels);
        let mut body = Vec::with_capacity(pixels);
        let mut labelled = Vec::with_capacity(pixels);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let on_body = mask.get_pixel(x, y)[0] != 0;
                colour.push(if on_body {
                    image.get_pixel(x, y).0.map(channel_byte)
                } else {
                    [0; 3]
                });
                body.push(on_body);
                labelled.push(!band[(y * w + x) as usize]);
            }
        }
        let mut cropped = camera.clone();
        cropped.intrinsics.z_axis.x -= x0 as f32;
        cropped.intrinsics.z_axis.y -= y0 as f32;
        cropped.width = cw;
        cropped.height = ch;
        Self {
            camera: cropped,
            global,
            bones,
            colour,
            mask: body,
            labelled,
        }
    }

    /// Pixels in the crop.
    pub fn pixels(&self) -> usize {
        self.mask.len()
    }

    /// The shot's loss for a render of it, premultiplied colour `rgb` `[P, 3]` on black and opacity `alpha`
    /// `[P, 1]`: the L1 colour error against the target plus [`MASK_WEIGHT`] times the mean of
    /// `(alpha − mask)²` over the labelled pixels; and the colour's mean squared error (for the fit's PSNR).
    pub fn loss(&self, rgb: Tensor<2>, alpha: Tensor<2>) -> (Tensor<1>, f32) {
        let device = rgb.device();
        let pixels = self.pixels();
        let target: Vec<f32> = self
            .colour
            .iter()
            .flatten()
            .map(|&c| f32::from(c) / 255.0)
            .collect();
        let floats = |bits: &[bool]| bits.iter().map(|&b| f32::from(b)).collect::<Vec<_>>();
        let target = from_rows(&target, pixels, 3, &device);
        let mask = from_rows(&floats(&self.mask), pixels, 1, &device);
        let labelled = from_rows(&floats(&self.labelled), pixels, 1, &device);
        let count = (self.labelled.iter().filter(|&&l| l).count() as f32).max(1.0);
        let error = rgb - target;
        let mse: f32 = error.clone().detach().powi_scalar(2).mean().into_scalar();
        let silhouette = ((alpha - mask).powi_scalar(2) * labelled).sum() / count;
        (error.abs().mean() + silhouette * MASK_WEIGHT, mse)
    }
}

/// The fit's settings.
#[derive(Debug, Clone)]
pub struct FitSettings {
    pub iterations: usize,
    pub budget: usize,
    pub seed: u64,
    pub log_every: usize,
}

/// The avatar's tensors while it is fitted, on the plain (non-autodiff) device, with their optimisers.
struct Fitted {
    /// means, log_scales, rotations, opacity_logits, colours.
    values: [Tensor<2>; 5],
    optims: [RowAdam; 5],
    skin: Tensor<2>,
    /// Summed norms of the means' gradients since the last densification `[N, 1]`.
    moved: Tensor<2>,
}

impl Fitted {
    fn new(avatar: &BakedAvatar, device: &Device) -> Self {
        let cloud = avatar.cloud(device);
        let values = [
            cloud.means.val(),
            cloud.log_scales.val(),
            cloud.rotations.val(),
            cloud.opacity_logits.val(),
            cloud.colours.val(),
        ];
        let lrs = [
            LR_MEANS,
            LR_OTHERS[0],
            LR_OTHERS[1],
            LR_OTHERS[2],
            LR_OTHERS[3],
        ];
        let optims = std::array::from_fn(|i| RowAdam::new(values[i].dims(), lrs[i], device));
        Self {
            moved: Tensor::zeros([avatar.means.len(), 1], device),
            skin: avatar.skin(device),
            values,
            optims,
        }
    }

    fn len(&self) -> usize {
        self.values[0].dims()[0]
    }

    fn cloud(&self, track: bool) -> GaussianCloud {
        let v = |i: usize| {
            let t = self.values[i].clone();
            if track {
                t.autodiff().require_grad()
            } else {
                t
            }
        };
        GaussianCloud::new(v(0), v(1), v(2), v(3), v(4))
    }

    /// One step on `shot`; returns the step's colour MSE.
    fn step(&mut self, shot: &Shot) -> f32 {
        let device = self.skin.device();
        let cloud = self.cloud(true);
        let view = SplatView {
            camera: &shot.camera,
            global: &shot.global,
            convention: PixelConvention::Integer,
        };
        let bones = BoneMatrices::new(&shot.bones, &device);
        let image = render(&cloud, self.skin.clone(), &bones, &view);
        let pixels = shot.pixels();
        let rgb = image.clone().slice([0..pixels, 0..3]);
        let alpha = image.slice([0..pixels, 3..4]);
        let (loss, mse) = shot.loss(rgb, alpha);
        let grads = loss.backward();
        let params = [
            &cloud.means,
            &cloud.log_scales,
            &cloud.rotations,
            &cloud.opacity_logits,
            &cloud.colours,
        ];
        for (i, p) in params.into_iter().enumerate() {
            let Some(g) = p.val().grad(&grads) else {
                continue;
            };
            if i == 0 {
                self.moved = self.moved.clone() + g.clone().powi_scalar(2).sum_dim(1).sqrt();
            }
            self.values[i] = self.optims[i].step(self.values[i].clone(), g);
        }
        mse
    }

    /// Prunes nearly transparent and oversized Gaussians and splits the ones whose means moved most, up to
    /// `budget` in all.
    fn densify(&mut self, budget: usize, rng: &mut ChaCha8Rng) {
        let n = self.len();
        let opacity = to_host(sigmoid(self.values[3].clone()));
        let log_scales = to_host(self.values[1].clone());
        let largest = |i: usize| {
            log_scales[3 * i..3 * i + 3]
                .iter()
                .fold(f32::MIN, |a, &b| a.max(b))
                .exp()
        };
        let kept: Vec<usize> = (0..n)
            .filter(|&i| opacity[i] >= PRUNE_OPACITY && largest(i) <= PRUNE_SCALE)
            .collect();
        let moved = to_host(self.moved.clone());
        let mut candidates = kept.clone();
        candidates.sort_by(|&a, &b| moved[b].total_cmp(&moved[a]));
        let room = budget.saturating_sub(kept.len());
        let split = candidates
            .into_iter()
            .take(((kept.len() as f32 * SPLIT_FRACTION) as usize).min(room))
            .filter(|&i| moved[i] > 0.0)
            .collect::<Vec<_>>();
        let rows: Vec<i64> = kept.iter().chain(&split).map(|&i| i as i64).collect();
        // Both children of a split parent (the kept row and the appended copy) take a point drawn from the
        // parent's Gaussian and smaller scales.
        let rotations = to_host(self.values[2].clone());
        let mut parent_of_row = vec![None; rows.len()];
        let split_set: std::collections::HashSet<usize> = split.iter().copied().collect();
        for (r, &i) in rows.iter().enumerate() {
            if split_set.contains(&(i as usize)) {
                parent_of_row[r] = Some(i as usize);
            }
        }
        let mut offsets = vec![0.0f32; rows.len() * 3];
        let mut shrink = vec![0.0f32; rows.len() * 3];
        for (r, parent) in parent_of_row.iter().enumerate() {
            let Some(i) = *parent else { continue };
            let q = Quat::from_xyzw(
                rotations[4 * i + 1],
                rotations[4 * i + 2],
                rotations[4 * i + 3],
                rotations[4 * i],
            )
            .normalize();
            let s = Vec3::from_slice(&log_scales[3 * i..3 * i + 3]).exp();
            let e = Vec3::new(normal(rng), normal(rng), normal(rng));
            offsets[3 * r..3 * r + 3].copy_from_slice(&(q * (s * e)).to_array());
            shrink[3 * r..3 * r + 3].fill(SPLIT_SHRINK.ln());
        }
        let device = self.skin.device();
        let index = Tensor::<1, Int>::from_ints(rows.as_slice(), &device);
        for (value, optim) in self.values.iter_mut().zip(&mut self.optims) {
            *value = value.clone().select(0, index.clone());
            optim.select(index.clone());
        }
        let m = rows.len();
        self.values[0] = self.values[0].clone() + from_rows(&offsets, m, 3, &device);
        self.values[1] = self.values[1].clone() - from_rows(&shrink, m, 3, &device);
        self.skin = self.skin.clone().select(0, index);
        self.moved = Tensor::zeros([m, 1], &device);
    }
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u: f32 = rng.random_range(f32::EPSILON..1.0);
    let v: f32 = rng.random_range(0.0..1.0);
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}

/// What a fit ended with.
#[derive(Debug, Clone)]
pub struct FitReport {
    pub steps: usize,
    pub seconds: f64,
    /// PSNR (dB) of the last tenth of the steps' crops (colour on black).
    pub training_psnr: f64,
}

/// Fits `start` to `shots` (drawn at random) for `settings.iterations` steps; `device` is a plain (not
/// autodiff) device: each step tracks its own copy of the values.
pub fn fit(
    start: &BakedAvatar,
    shots: &[Shot],
    settings: &FitSettings,
    device: &Device,
    progress: &StageProgress,
) -> Result<(BakedAvatar, FitReport)> {
    anyhow::ensure!(!shots.is_empty(), "no training images to fit the avatar to");
    let started = std::time::Instant::now();
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut fitted = Fitted::new(start, device);
    let tail = (settings.iterations / 10).max(1);
    let mut tail_mse = Vec::with_capacity(tail);
    let mut window = 0.0f64;
    for step in 1..=settings.iterations {
        let decay = (step as f64 / settings.iterations as f64).min(1.0);
        fitted.optims[0].set_lr(LR_MEANS * 0.01f64.powf(decay));
        let shot = &shots[rng.random_range(0..shots.len())];
        let mse = fitted.step(shot);
        window += mse as f64;
        if step + tail > settings.iterations {
            tail_mse.push(mse as f64);
        }
        if step % DENSIFY_EVERY == 0 && step <= settings.iterations / 2 {
            fitted.densify(settings.budget, &mut rng);
        }
        if step % settings.log_every.max(1) == 0 {
            let mean = window / settings.log_every.max(1) as f64;
            progress.report(
                step,
                &format!("psnr {:.2} gaussians {}", psnr(mean), fitted.len()),
            );
            window = 0.0;
        }
        progress.set_step(step);
    }
    let mean_tail = tail_mse.iter().sum::<f64>() / tail_mse.len().max(1) as f64;
    let report = FitReport {
        steps: settings.iterations,
        seconds: started.elapsed().as_secs_f64(),
        training_psnr: psnr(mean_tail),
    };
    let mut avatar = start.with_cloud(&fitted.cloud(false));
    let (joints, weights) = top_skin(&fitted.skin, start.info.joints);
    avatar.skin_joints = joints;
    avatar.skin_weights = weights;
    avatar.info.gaussians = avatar.means.len();
    avatar.info.steps = report.steps;
    avatar.info.seconds = report.seconds;
    avatar.info.training_psnr = report.training_psnr;
    Ok((avatar, report))
}

/// The skin's dense rows back to four joints and weights per Gaussian.
fn top_skin(skin: &Tensor<2>, joints: usize) -> (Vec<[u16; 4]>, Vec<[f32; 4]>) {
    anerf_eval::gltf_export::top_weights(&to_host(skin.clone()), joints)
}

/// PSNR (dB) of a mean squared error of colours in `[0, 1]`.
pub fn psnr(mse: f64) -> f64 {
    -10.0 * mse.max(1e-12).log10()
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_core::geometry::BoneTransforms;
    use image::{ImageBuffer, Luma, Rgb};

    /// The whole of a three-pixel row `image` with `mask` and mask-edge `band`, seen by a camera whose
    /// view of the body's box reaches beyond the image.
    fn crop(image: &Rgb32FImage, mask: &GrayImage, band: &[bool]) -> Shot {
        let camera = Camera::from_rows(
            [[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3],
            [0.0; 5],
            3,
            1,
        )
        .unwrap();
        let corners = [Vec3::new(-10.0, -10.0, 1.0), Vec3::new(10.0, 10.0, 1.0)];
        let bones = BoneTransforms::from_matrices(vec![glam::Mat4::IDENTITY]).unwrap();
        Shot::crop(
            &camera,
            &corners,
            image,
            (mask, band),
            GlobalTransform::default(),
            bones,
        )
    }

    /// A row of three pixels of one colour, all inside the (conservative) mask, the middle one in the
    /// mask-edge band.
    fn shot() -> Shot {
        let image = ImageBuffer::from_pixel(3, 1, Rgb([0.5f32, 0.4, 0.3]));
        crop(
            &image,
            &ImageBuffer::from_pixel(3, 1, Luma([1u8])),
            &[false, true, false],
        )
    }

    /// An 8-bit image (as the prepared cache stores it) is kept exactly, on black: a render of the image
    /// times the mask with the mask's opacity has zero loss, and a render one level off in one channel of
    /// one pixel has the L1 error `1 / (255 · 3P)`.
    #[test]
    fn a_crop_keeps_an_8_bit_image_exactly_on_black() {
        let levels = [[10u8, 20, 30], [40, 50, 60], [70, 80, 255]];
        let image = ImageBuffer::from_fn(3, 1, |x, _| {
            Rgb(levels[x as usize].map(|l| f32::from(l) / 255.0))
        });
        let mask: GrayImage = ImageBuffer::from_fn(3, 1, |x, _| Luma([u8::from(x != 1)]));
        let shot = crop(&image, &mask, &[false; 3]);
        let mut rgb: Vec<f32> = (0..3)
            .flat_map(|x| levels[x].map(|l| if x == 1 { 0.0 } else { f32::from(l) / 255.0 }))
            .collect();
        let device = anerf_device::cpu_device();
        let alpha = || from_rows(&[1.0, 0.0, 1.0], 3, 1, &device);
        let (loss, mse) = shot.loss(from_rows(&rgb, 3, 3, &device), alpha());
        let loss: f32 = loss.into_scalar();
        assert_eq!((loss, mse), (0.0, 0.0));
        rgb[4] = 1.0 / 255.0;
        let (loss, _) = shot.loss(from_rows(&rgb, 3, 3, &device), alpha());
        let loss: f32 = loss.into_scalar();
        let expected = 1.0 / (255.0 * 9.0);
        assert!((loss - expected).abs() < 1e-7, "{loss} against {expected}");
    }

    /// The silhouette term leaves the band pixel's opacity alone and pulls the others toward the mask with
    /// `∂/∂α = 2 · MASK_WEIGHT · (α − 1) / 2 labelled pixels`; the colour term, on black, does not depend on
    /// opacity at all.
    #[test]
    fn the_silhouette_term_leaves_the_mask_edge_band_alone() {
        let shot = shot();
        assert_eq!(shot.labelled, [true, false, true]);
        let device = anerf_device::cpu_device().autodiff();
        let opacity = [0.9, 0.4, 0.7];
        let alpha = from_rows(&opacity, 3, 1, &device).require_grad();
        let (loss, _) = shot.loss(from_rows(&[0.2; 9], 3, 3, &device), alpha.clone());
        let gradient = to_host(alpha.grad(&loss.backward()).unwrap());
        for (i, &a) in opacity.iter().enumerate() {
            let expected = if i == 1 { 0.0 } else { MASK_WEIGHT * (a - 1.0) };
            assert!(
                (gradient[i] - expected).abs() < 1e-6,
                "pixel {i}: {} against {expected}",
                gradient[i]
            );
        }
    }
}
