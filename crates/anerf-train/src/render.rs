//! Rendering whole images of a frame from a camera with a trained model.

use anerf_core::geometry::{Aabb, Camera};
use anerf_core::model::{AnimatableNerf, CanonicalInputs, FrameInputs};
use anerf_core::{FrameId, ViewId};
use anerf_data::{image_rays, ImageRays, SamplerOptions};
use anerf_eval::{ImageSize, PixelMask, RgbImageExt};
use anyhow::{Context, Result};
use image::{GrayImage, Rgb32FImage};

use crate::config::EvalConfig;
use crate::experiment::Experiment;

/// A rendered image with what the protocol compares it against.
pub struct RenderedImage {
    /// Prediction on black, black outside `mask`.
    pub prediction: Rgb32FImage,
    /// Ground truth with background and out-of-box pixels black (when the view has an image).
    pub ground_truth: Option<Rgb32FImage>,
    /// Pixels whose ray hits the padded body box (`mask_at_box`).
    pub mask: PixelMask,
    /// Row-major rendered opacity per pixel (0 outside `mask`).
    pub opacity: Vec<f32>,
    /// The dataset mask's foreground pixels (when the view has an image): the true silhouette.
    pub silhouette: Option<PixelMask>,
    /// Rays rendered (pixels inside `mask`).
    pub rays: usize,
    /// Samples that survived culling, those shaded before their ray stopped (early termination, empty
    /// canonical cells), and all samples along the rendered rays.
    pub surviving_samples: usize,
    pub shaded_samples: usize,
    pub total_samples: usize,
}

/// What one image shows: a body (model inputs and world box) seen by a camera, with the dataset's image
/// and mask when the camera is a dataset view.
pub struct Shot<'a> {
    pub inputs: &'a FrameInputs,
    /// World-space box of the posed body (metres): rays are sampled where they cross it.
    pub bounds: Aabb,
    pub camera: &'a Camera,
    pub ground_truth: Option<(&'a Rgb32FImage, &'a GrayImage)>,
}

/// Renders frame `frame` as seen by camera `camera` (a dataset view when `view` is given, whose image then
/// serves as ground truth), with the experiment's `[eval]` settings.
pub fn render_view(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    frame: FrameId,
    camera: &Camera,
    view: Option<ViewId>,
) -> Result<RenderedImage> {
    let bounds = exp.frame_bounds(frame)?;
    let images = match view {
        Some(v) => Some((exp.prepared.image(frame, v)?, exp.prepared.mask(frame, v)?)),
        None => None,
    };
    let inputs = exp.frame_inputs(frame)?;
    let shot = Shot {
        inputs: &inputs,
        bounds,
        camera,
        ground_truth: images.as_ref().map(|(i, m)| (i, m)),
    };
    render_shot(model, exp.canonical(), &shot, &exp.config.eval)
        .with_context(|| format!("rendering {frame}"))
}

/// The true silhouette of a dataset mask: its non-zero pixels.
pub fn silhouette(mask: &GrayImage) -> PixelMask {
    let size = ImageSize::new(mask.width(), mask.height());
    PixelMask::new(size, mask.pixels().map(|m| m[0] != 0).collect()).expect("sized from the mask")
}

/// Renders `shot`, `settings.chunk` rays at a time, each ray stopping at transmittance
/// `settings.termination` ([`AnimatableNerf::march`]).
pub fn render_shot(
    model: &AnimatableNerf,
    canonical: &CanonicalInputs,
    shot: &Shot,
    settings: &EvalConfig,
) -> Result<RenderedImage> {
    let rays = image_rays(
        shot.camera,
        &shot.bounds,
        shot.ground_truth,
        &SamplerOptions::default(),
    )
    .context("casting the image's rays")?;
    let mut shaded = Vec::with_capacity(rays.rays.len());
    let (mut surviving_samples, mut shaded_samples, mut total_samples) = (0, 0, 0);
    let inputs = model.posed_frame(shot.inputs);
    for start in (0..rays.rays.len()).step_by(settings.chunk.max(1)) {
        let part = rays
            .rays
            .slice(start..(start + settings.chunk).min(rays.rays.len()));
        let out = model.march(&part, &inputs, canonical, settings.termination);
        surviving_samples += out.surviving_samples;
        shaded_samples += out.shaded_samples;
        total_samples += out.total_samples;
        shaded.extend(
            out.rgb
                .chunks_exact(3)
                .zip(&out.acc)
                .map(|(rgb, &acc)| [rgb[0], rgb[1], rgb[2], acc]),
        );
    }
    Ok(RenderedImage {
        surviving_samples,
        shaded_samples,
        total_samples,
        ..RenderedImage::from_rays(rays, shot.ground_truth.map(|(_, m)| m), &shaded)
    })
}

impl RenderedImage {
    /// The image whose rays `rays` (the pixels whose ray meets the body's box) were rendered as `shaded`
    /// (colour on black and opacity, one per ray, in the rays' order), black and transparent elsewhere;
    /// `dataset_mask` gives the true silhouette. No sample counts (a renderer that marches sets them).
    pub fn from_rays(
        rays: ImageRays,
        dataset_mask: Option<&GrayImage>,
        shaded: &[[f32; 4]],
    ) -> Self {
        assert_eq!(shaded.len(), rays.rays.len(), "one colour per ray");
        let size = ImageSize::new(rays.width, rays.height);
        let mut prediction = Rgb32FImage::black(size);
        let mut hit = vec![false; size.pixels()];
        let mut opacity = vec![0.0; size.pixels()];
        for (p, &[u, v]) in shaded.iter().zip(&rays.rays.pixels) {
            prediction.set_pixel(u, v, [p[0], p[1], p[2]]);
            let i = (v * size.width + u) as usize;
            hit[i] = true;
            opacity[i] = p[3];
        }
        Self {
            prediction,
            ground_truth: rays.ground_truth,
            mask: PixelMask::new(size, hit).expect("sized from the image"),
            opacity,
            silhouette: dataset_mask.map(silhouette),
            rays: rays.rays.len(),
            surviving_samples: 0,
            shaded_samples: 0,
            total_samples: 0,
        }
    }
}
