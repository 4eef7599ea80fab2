//! Training images kept read between steps. A step of the `fast` preset with refined fits reads 16 images
//! (4 frames × 4 views), and reading one (decoding its image and mask PNGs, projecting the frame's box,
//! finding the pixel pools) took about 1.9 ms at 512²: a tenth of a refined step's CPU on 2 cores. A subject's
//! training images are few enough to keep: 400 at 512² take about 0.6 GB as 8-bit pixels with their pools.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use anerf_core::{FrameId, ViewId};

use super::{MaskEdges, ReadImage, SamplerError};

/// How much [`ImageCache::for_training`] keeps, bytes: every training image of a subject like the realistic
/// one (about 0.6 GB); of a larger subject (an image takes about 1.65 MB at 512², four times that at 1024²),
/// the first ones drawn, and the others are read each time they are drawn.
pub const TRAINING_IMAGE_BUDGET: usize = 2 << 30;

/// Which image was read, and how its band was treated (the pools depend on it).
type Key = (FrameId, ViewId, MaskEdges);

/// Images read once and kept, up to a budget of bytes, first come first kept (a training run draws its
/// frames uniformly, so which ones stay does not matter). The images and pools are the ones a fresh read
/// gives, so a draw through the cache is the draw without it. One cache serves one set of backgrounds (the
/// pools of [`MaskEdges::Backdrop`] depend on them): a [`super::Prefetch`] owns its own.
pub struct ImageCache {
    budget: usize,
    kept: Mutex<Kept>,
}

#[derive(Default)]
struct Kept {
    images: HashMap<Key, Arc<ReadImage>>,
    bytes: usize,
}

impl ImageCache {
    /// A cache that keeps up to `budget` bytes.
    pub fn new(budget: usize) -> Self {
        Self {
            budget,
            kept: Mutex::default(),
        }
    }

    /// A cache that keeps nothing: every image is read when it is drawn.
    pub fn none() -> Self {
        Self::new(0)
    }

    /// The cache of a training run's ray draws ([`TRAINING_IMAGE_BUDGET`]).
    pub fn for_training() -> Self {
        Self::new(TRAINING_IMAGE_BUDGET)
    }

    /// How many images and bytes it holds.
    pub fn held(&self) -> (usize, usize) {
        let kept = self.lock();
        (kept.images.len(), kept.bytes)
    }

    /// The image of `key`, kept or `read` now (and kept while the budget allows).
    pub(super) fn get_or_read(
        &self,
        key: Key,
        read: impl FnOnce() -> Result<ReadImage, SamplerError>,
    ) -> Result<Arc<ReadImage>, SamplerError> {
        if let Some(image) = self.lock().images.get(&key) {
            return Ok(Arc::clone(image));
        }
        let image = Arc::new(read()?);
        let bytes = image.bytes();
        let mut kept = self.lock();
        if kept.bytes + bytes <= self.budget && !kept.images.contains_key(&key) {
            kept.bytes += bytes;
            kept.images.insert(key, Arc::clone(&image));
        }
        Ok(image)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Kept> {
        // A panic while holding the lock leaves the map consistent (inserts are single operations).
        self.kept.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl std::fmt::Debug for ImageCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (images, bytes) = self.held();
        f.debug_struct("ImageCache")
            .field("budget", &self.budget)
            .field("images", &images)
            .field("bytes", &bytes)
            .finish()
    }
}
