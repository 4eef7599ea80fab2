//! Segmentation-like errors of the masks' edges (`anerf synth --mask-noise`): the silhouette's edge moved
//! out in some places and in at others by up to `px` pixels, smoothly along the contour with a little
//! per-pixel jaggedness, as a segmentation network's masks are wrong. Pixels whose centre lies `px` or
//! more from the true edge never change.

use std::f32::consts::TAU;

use glam::Vec2;

use super::rng::SplitMix64;
use super::SynthError;

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

/// Per pixel, how far (pixels) the mask's edge lies from its centre: the distance to the nearest pixel
/// centre of the other class, less half a pixel (the edge runs between the two). At least 0.5; infinite
/// when the mask holds one class only.
fn edge_distances(mask: &[u8], width: usize, height: usize) -> Vec<f32> {
    let to_body = squared_distances(mask, width, height, |m| m > 0);
    let to_background = squared_distances(mask, width, height, |m| m == 0);
    mask.iter()
        .zip(to_body.iter().zip(&to_background))
        .map(|(&m, (&b, &g))| if m > 0 { g } else { b }.sqrt() - 0.5)
        .collect()
}

/// Exact squared Euclidean distance (pixels²) from each pixel to the nearest pixel whose value is a
/// `site` (infinite without any): Felzenszwalb and Huttenlocher's transform, rows then columns.
fn squared_distances(
    mask: &[u8],
    width: usize,
    height: usize,
    site: impl Fn(u8) -> bool,
) -> Vec<f32> {
    let mut rows: Vec<f32> = mask
        .iter()
        .map(|&m| if site(m) { 0.0 } else { f32::INFINITY })
        .collect();
    let mut line = vec![0.0; width.max(height)];
    for row in rows.chunks_mut(width) {
        lower_envelope(row, &mut line[..width]);
        row.copy_from_slice(&line[..width]);
    }
    let mut column = vec![0.0; height];
    for x in 0..width {
        for (y, c) in column.iter_mut().enumerate() {
            *c = rows[y * width + x];
        }
        lower_envelope(&column, &mut line[..height]);
        for (y, d) in line[..height].iter().enumerate() {
            rows[y * width + x] = *d;
        }
    }
    rows
}

/// One-dimensional squared distance transform: `out[x] = min_q (x − q)² + f[q]` over the finite `f[q]`
/// (infinite when none is), from the lower envelope of the parabolas rooted at those `q`.
fn lower_envelope(f: &[f32], out: &mut [f32]) {
    let parabola = |q: usize| f[q] + (q * q) as f32;
    // The envelope's parabolas (their roots) and where each starts to be the lowest.
    let mut roots: Vec<usize> = Vec::new();
    let mut starts: Vec<f32> = Vec::new();
    for q in (0..f.len()).filter(|&q| f[q].is_finite()) {
        let mut start = f32::NEG_INFINITY;
        while let (Some(&p), Some(&from)) = (roots.last(), starts.last()) {
            start = (parabola(q) - parabola(p)) / (2.0 * (q - p) as f32);
            if start > from {
                break;
            }
            roots.pop();
            starts.pop();
            start = f32::NEG_INFINITY;
        }
        roots.push(q);
        starts.push(start);
    }
    let mut k = 0;
    for (x, o) in out.iter_mut().enumerate() {
        if roots.is_empty() {
            *o = f32::INFINITY;
            continue;
        }
        while k + 1 < starts.len() && starts[k + 1] < x as f32 {
            k += 1;
        }
        let q = roots[k];
        *o = (x as f32 - q as f32).powi(2) + f[q];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over every pixel pair.
    fn brute_force(mask: &[u8], width: usize, site: impl Fn(u8) -> bool) -> Vec<f32> {
        let xy = |i: usize| ((i % width) as f32, (i / width) as f32);
        (0..mask.len())
            .map(|i| {
                (0..mask.len())
                    .filter(|&j| site(mask[j]))
                    .map(|j| {
                        let ((a, b), (c, d)) = (xy(i), xy(j));
                        (a - c).powi(2) + (b - d).powi(2)
                    })
                    .fold(f32::INFINITY, f32::min)
            })
            .collect()
    }

    #[test]
    fn the_distance_transform_is_exact() {
        let (width, height) = (23, 17);
        let mut rng = SplitMix64::new(3);
        for density in [0.0, 0.02, 0.3, 0.9] {
            let mask: Vec<u8> = (0..width * height)
                .map(|_| u8::from(rng.range(0.0, 1.0) < density))
                .collect();
            let fast = squared_distances(&mask, width, height, |m| m > 0);
            assert_eq!(
                fast,
                brute_force(&mask, width, |m| m > 0),
                "density {density}"
            );
        }
    }

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
