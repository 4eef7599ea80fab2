//! Drawing rays where a training image has detail: in proportion to the magnitude of its target colours'
//! gradient, so that a step's rays land on the edges (the silhouette against the backdrop, the texture's
//! own) whose colours move most when the body or its pose is off by a fraction of a pixel.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The pixels of an image with detail and the running sum of their weights, for drawing a pixel with
/// probability proportional to its weight.
#[derive(Debug, Default)]
pub(super) struct DetailPool {
    pixels: Vec<u32>,
    cumulative: Vec<f64>,
}

/// Weights below this (colour units per pixel, channels in `[0, 1]`) leave the pixel out: flat regions.
const FLAT: f32 = 1.0 / 255.0;

impl DetailPool {
    /// The `candidates` (row-major indices into a `width`-wide image, ascending) weighted by the gradient
    /// magnitude of `target` there: half the central difference along each axis (one-sided at the image's
    /// border), `√(g_u² + g_v²)`, the largest over the three channels.
    pub(super) fn new(
        target: &[[f32; 3]],
        width: usize,
        candidates: impl Iterator<Item = u32>,
    ) -> Self {
        let height = target.len() / width.max(1);
        let mut pool = Self::default();
        let mut total = 0.0f64;
        for i in candidates {
            let (u, v) = (i as usize % width, i as usize / width);
            let at = |u: usize, v: usize| target[v * width + u];
            let (l, r) = (at(u.saturating_sub(1), v), at((u + 1).min(width - 1), v));
            let (t, b) = (at(u, v.saturating_sub(1)), at(u, (v + 1).min(height - 1)));
            let weight = (0..3)
                .map(|c| (0.5 * (r[c] - l[c])).hypot(0.5 * (b[c] - t[c])))
                .fold(0.0f32, f32::max);
            if weight >= FLAT {
                total += f64::from(weight);
                pool.pixels.push(i);
                pool.cumulative.push(total);
            }
        }
        pool
    }

    pub(super) fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    pub(super) fn len(&self) -> usize {
        self.pixels.len()
    }

    /// One pixel, with probability its weight over the pool's total.
    pub(super) fn draw(&self, rng: &mut ChaCha8Rng) -> u32 {
        let total = *self.cumulative.last().expect("a non-empty pool");
        let at = rng.random::<f64>() * total;
        let k = self.cumulative.partition_point(|&c| c <= at);
        self.pixels[k.min(self.pixels.len() - 1)]
    }
}
