//! Segmentation-like errors of the masks' edges (`anerf synth --mask-noise`): the silhouette's edge moved
//! out in some places and in at others by up to `px` pixels, smoothly along the contour with a little
//! per-pixel jaggedness, as a segmentation network's masks are wrong. Pixels whose centre lies `px` or
//! more from the true edge never change.

use std::f32::consts::TAU;

use glam::Vec2;

use super::rng::SplitMix64;
use super::SynthError;
use crate::mask_distance::edge_distances;

/// Keeps the noise's random streams apart from every other use of the subject's seed.
const SALT: u64 = 0x6d61_736b_6e6f_6973; // "masknois"
/// Largest edge error the generator accepts (pixels).
const MAX_PX: f32 = 10.0;
/// Plane waves summed into the smooth part of the edge offset.
const WAVES: usize = 4;
/// Gain of the normalised wave sum: its standard deviation is then about 0.7 (× `px`), so the offset
/// reaches the clamp at `±px` along part of the contour.
const GAIN: f32 = 2.0;
/// Half-width of the per-pixel jitter (pixels) that makes the edge jagged at the pixel scale without
/// scattering specks away from it.
const JITTER_PX: f32 = 0.75;

/// Checks `mask_noise` (pixels, a real number in `0 ..= 10`).
pub(super) fn validate(px: f32) -> Result<(), SynthError> {
    SynthError::check_ranges(&[("mask_noise", px, 0.0, MAX_PX)])
}

/// A binary mask (`width × height`, row-major, 0 = background, anything else = body) whose edge is
/// moved by the smooth random offset of item `index` (a frame's camera) of the subject of `seed`, up to
/// `px` pixels. Pixels added to the body become 255.
pub(super) fn perturb(
    mask: &mut [u8],
    width: usize,
    height: usize,
    px: f32,
    seed: u64,
    index: u64,
) {
    let edge = edge_distances(mask, width, height);
    let offsets = EdgeOffsets::new(px, width, height, SplitMix64::keyed(seed, SALT, index));
    for (i, (m, e)) in mask.iter_mut().zip(edge).enumerate() {
        if e >= px {
            continue;
        }
        let s = offsets.at(i % width, i / width, i);
        // Positive offsets push the edge outwards over background, negative ones inwards over the body.
        *m = match *m > 0 {
            true if e < -s => 0,
            false if e < s => 255,
            _ => *m,
        };
    }
}

/// The offset of the edge over the image (pixels, positive outwards): a sum of plane waves of random
/// direction, wavelength and phase, plus per-pixel jitter, clamped to `±px`.
struct EdgeOffsets {
    px: f32,
    waves: Vec<Wave>,
    /// Seeds the per-pixel jitter, drawn by pixel index so that any subset of pixels can be asked.
    jitter_key: u64,
}

/// `amplitude · sin(k · p + phase)` at pixel centre `p` (pixels); the amplitudes of the waves sum to
/// [`GAIN`].
struct Wave {
    /// Wave vector (radians per pixel).
    k: Vec2,
    phase: f32,
    amplitude: f32,
}

impl EdgeOffsets {
    /// Wavelengths between 1/12 and 1/3 of the image's larger side, a few bends along a limb's contour,
    /// and at least `4 px`: the offset's sign then rarely flips within its own reach, which would leave
    /// islands beside thin limbs eroded away.
    fn new(px: f32, width: usize, height: usize, mut rng: SplitMix64) -> Self {
        let size = width.max(height) as f32;
        let shortest = (size / 12.0).max(4.0 * px);
        let mut waves: Vec<Wave> = (0..WAVES)
            .map(|_| {
                let wavelength = rng.range(shortest, (size / 3.0).max(2.0 * shortest));
                Wave {
                    k: Vec2::from_angle(rng.range(0.0, TAU)) * (TAU / wavelength),
                    phase: rng.range(0.0, TAU),
                    amplitude: rng.range(0.5, 1.0),
                }
            })
            .collect();
        let total: f32 = waves.iter().map(|w| w.amplitude).sum();
        for w in &mut waves {
            w.amplitude *= GAIN / total;
        }
        Self {
            px,
            waves,
            jitter_key: rng.next_u64(),
        }
    }

    /// The offset (pixels) at pixel `(x, y)`, whose row-major index is `index`.
    fn at(&self, x: usize, y: usize, index: usize) -> f32 {
        let p = Vec2::new(x as f32, y as f32);
        let smooth: f32 = self
            .waves
            .iter()
            .map(|w| w.amplitude * (w.k.dot(p) + w.phase).sin())
            .sum();
        let jitter =
            SplitMix64::keyed(self.jitter_key, 0, index as u64).range(-JITTER_PX, JITTER_PX);
        (self.px * smooth + jitter).clamp(-self.px, self.px)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_disc_grows_and_shrinks_only_near_its_edge() {
        let (width, height, px) = (48, 40, 3.0);
        let inside = |i: usize| {
            let (x, y) = ((i % width) as f32 - 24.0, (i / width) as f32 - 20.0);
            x * x + y * y < 12.0 * 12.0
        };
        let truth: Vec<u8> = (0..width * height)
            .map(|i| if inside(i) { 255 } else { 0 })
            .collect();
        let mut noisy = truth.clone();
        perturb(&mut noisy, width, height, px, 9, 0);
        let (mut added, mut removed) = (0, 0);
        for (i, (&t, &n)) in truth.iter().zip(&noisy).enumerate() {
            let radius = ((i % width) as f32 - 24.0).hypot((i / width) as f32 - 20.0);
            if t != n {
                assert!(
                    (radius - 12.0).abs() < px + 1.0,
                    "pixel {i} at radius {radius}"
                );
                added += usize::from(n > 0);
                removed += usize::from(t > 0);
            }
        }
        assert!(
            added > 10 && removed > 10,
            "{added} added, {removed} removed"
        );
        let mut zero = truth.clone();
        perturb(&mut zero, width, height, 0.0, 9, 0);
        assert_eq!(zero, truth);
    }
}
