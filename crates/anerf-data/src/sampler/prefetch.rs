//! Drawing the next training step's rays on a thread of its own while the current step computes. Reading
//! and decoding a step's images takes a tenth to a fifth of a CPU step at 512² (more on a GPU, whose step
//! is shorter) and needs nothing from the model, so it overlaps with the step before. The rays are the
//! ones the sampler draws step after step: each draw starts from the state the previous one left, and a
//! draw started from any other state is thrown away and done again.

use std::sync::Arc;
use std::thread::JoinHandle;

use anerf_core::render::HostRays;
use anerf_core::{FrameId, ViewId};

use super::{Backgrounds, ImageCache, RaySampler, SamplerError, StepImages};
use crate::prepare::PreparedSubject;

/// What a step draws from besides the sampler's state: the training frames and views, how many of each
/// a step takes ([`RaySampler::pick_step`]), and the views' backgrounds where training composites over them.
#[derive(Debug, Clone, PartialEq)]
pub struct StepPlan {
    pub frames: Vec<FrameId>,
    pub views: Vec<ViewId>,
    pub frames_per_step: usize,
    pub views_per_step: usize,
    pub backgrounds: Option<Arc<Backgrounds>>,
}

/// One step's images and rays (one [`HostRays`] a frame), and the sampler as drawing them left it.
#[derive(Debug)]
pub struct DrawnStep {
    pub images: Vec<StepImages>,
    pub rays: Vec<HostRays>,
    pub sampler: RaySampler,
}

/// Why a step's rays could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    #[error(
        "no step can be drawn: {} frames, {} views, {} frames and {} views a step",
        .0.frames.len(), .0.views.len(), .0.frames_per_step, .0.views_per_step
    )]
    Plan(StepPlan),
    #[error("sampling rays of {images:?}: {source}")]
    Sample {
        images: Vec<StepImages>,
        source: SamplerError,
    },
}

/// One step drawn from `sampler`'s state: [`RaySampler::pick_step`], then [`RaySampler::sample_step`]
/// through `cache`.
pub fn draw_step(
    subject: &PreparedSubject,
    mut sampler: RaySampler,
    plan: &StepPlan,
    cache: &ImageCache,
) -> Result<DrawnStep, DrawError> {
    let images = sampler
        .pick_step(
            &plan.frames,
            &plan.views,
            plan.frames_per_step,
            plan.views_per_step,
        )
        .ok_or_else(|| DrawError::Plan(plan.clone()))?;
    match sampler.sample_step(subject, plan.backgrounds.as_deref(), &images, cache) {
        Ok(rays) => Ok(DrawnStep {
            images,
            rays,
            sampler,
        }),
        Err(source) => Err(DrawError::Sample { images, source }),
    }
}

/// Draws steps one ahead on a background thread: [`Self::next`] returns the step that follows a sampler
/// state, exactly as [`draw_step`] would, and starts drawing the one after. The images it reads are kept
/// ([`ImageCache::for_training`]).
pub struct Prefetch {
    subject: Arc<PreparedSubject>,
    plan: StepPlan,
    cache: Arc<ImageCache>,
    /// The draw under way and the sampler state it started from.
    pending: Option<(RaySampler, JoinHandle<Result<DrawnStep, DrawError>>)>,
}

impl Prefetch {
    pub fn new(subject: Arc<PreparedSubject>, plan: StepPlan) -> Self {
        Self {
            subject,
            plan,
            cache: Arc::new(ImageCache::for_training()),
            pending: None,
        }
    }

    /// The step drawn from `sampler`'s state: the pending draw where it started from that state, else a
    /// draw made now. Then starts drawing the step after it.
    pub fn next(&mut self, sampler: &RaySampler) -> Result<DrawnStep, DrawError> {
        let ahead = self.pending.take().and_then(|(start, handle)| {
            let drawn = handle
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (start == *sampler).then_some(drawn)
        });
        let drawn = match ahead {
            Some(drawn) => drawn?,
            None => draw_step(&self.subject, sampler.clone(), &self.plan, &self.cache)?,
        };
        let (subject, plan, cache, start) = (
            Arc::clone(&self.subject),
            self.plan.clone(),
            Arc::clone(&self.cache),
            drawn.sampler.clone(),
        );
        let handle = std::thread::spawn(move || draw_step(&subject, start, &plan, &cache));
        self.pending = Some((drawn.sampler.clone(), handle));
        Ok(drawn)
    }
}

impl Drop for Prefetch {
    /// Waits for a draw under way, so that no thread outlives the training that started it.
    fn drop(&mut self) {
        if let Some((_, handle)) = self.pending.take() {
            let _ = handle.join();
        }
    }
}
