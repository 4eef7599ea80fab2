//! Distances to a binary mask's edge, in pixels: the exact Euclidean distance transform (Felzenszwalb and
//! Huttenlocher) and, built on it, [`MaskDistance`], a mask's signed distance to its edge sampled with its
//! gradient at sub-pixel positions (the body silhouette term of pose refinement reads it).
//!
//! Pixel `(u, v)` sits at the integer point `(u, v)`; the edge runs half-way between a body pixel and a
//! background pixel next to it.

use glam::Vec2;

/// Per pixel, how far (pixels) the mask's edge lies from its centre: the distance to the nearest pixel
/// centre of the other class, less half a pixel (the edge runs between the two). At least 0.5; infinite
/// when the mask holds one class only.
pub fn edge_distances(mask: &[u8], width: usize, height: usize) -> Vec<f32> {
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

/// A mask's signed distance to its edge (pixels; positive on the body, negative off it, zero on the edge),
/// kept over the body's bounding box widened by a margin: enough for the posed body's outline, a fraction
/// of the image.
#[derive(Debug, Clone)]
pub struct MaskDistance {
    /// The kept window's first column and row in the image.
    origin: (usize, usize),
    width: usize,
    height: usize,
    /// Row-major over the window: [`edge_distances`], negated off the body.
    values: Vec<f32>,
}

impl MaskDistance {
    /// The signed distance of `mask` (`width × height`, row-major, 0 = background) over its body's
    /// bounding box widened by `margin` pixels (clipped to the image); `None` when no pixel is on the
    /// body. Distances are exact within the window: the window holds every body pixel and, unless the body
    /// touches the image's border, background all round it.
    pub fn new(mask: &[u8], width: usize, height: usize, margin: usize) -> Option<Self> {
        assert_eq!(
            mask.len(),
            width * height,
            "a mask of width × height pixels"
        );
        let (mut lo, mut hi) = ((usize::MAX, usize::MAX), (0, 0));
        for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m > 0) {
            let (x, y) = (i % width, i / width);
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        if lo.0 == usize::MAX {
            return None;
        }
        let origin = (lo.0.saturating_sub(margin), lo.1.saturating_sub(margin));
        let end = (
            (hi.0 + margin + 1).min(width),
            (hi.1 + margin + 1).min(height),
        );
        let (w, h) = (end.0 - origin.0, end.1 - origin.1);
        let window: Vec<u8> = (origin.1..end.1)
            .flat_map(|y| {
                mask[y * width + origin.0..y * width + end.0]
                    .iter()
                    .copied()
            })
            .collect();
        let values = edge_distances(&window, w, h)
            .into_iter()
            .zip(&window)
            .map(|(d, &m)| if m > 0 { d } else { -d })
            .collect();
        Some(Self {
            origin,
            width: w,
            height: h,
            values,
        })
    }

    /// The signed distance at image point `p` (pixels) and its gradient, by bilinear interpolation between
    /// the four pixels around it; `None` where those pixels are not all in the window.
    pub fn sample(&self, p: Vec2) -> Option<(f32, Vec2)> {
        let q = p - Vec2::new(self.origin.0 as f32, self.origin.1 as f32);
        let base = q.floor();
        if !(base.x >= 0.0 && base.y >= 0.0) {
            return None;
        }
        let (x, y) = (base.x as usize, base.y as usize);
        if x + 1 >= self.width || y + 1 >= self.height {
            return None;
        }
        let at = |dx: usize, dy: usize| self.values[(y + dy) * self.width + x + dx];
        let (a, b, c, d) = (at(0, 0), at(1, 0), at(0, 1), at(1, 1));
        let f = q - base;
        let top = a + (b - a) * f.x;
        let bottom = c + (d - c) * f.x;
        let value = top + (bottom - top) * f.y;
        let gradient = Vec2::new((b - a) + ((d - c) - (b - a)) * f.y, bottom - top);
        Some((value, gradient))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for density in [0.0, 0.02, 0.3, 0.9] {
            let mask: Vec<u8> = (0..width * height)
                .map(|_| u8::from(rng.random::<f32>() < density))
                .collect();
            let fast = squared_distances(&mask, width, height, |m| m > 0);
            assert_eq!(
                fast,
                brute_force(&mask, width, |m| m > 0),
                "density {density}"
            );
        }
    }

    /// A disc of radius `r` pixels centred at `c`: pixels whose centre lies inside.
    fn disc(width: usize, height: usize, c: Vec2, r: f32) -> Vec<u8> {
        (0..width * height)
            .map(|i| {
                let p = Vec2::new((i % width) as f32, (i / width) as f32);
                u8::from((p - c).length() < r) * 255
            })
            .collect()
    }

    #[test]
    fn the_signed_distance_of_a_disc_is_its_radius_less_the_distance_from_its_centre() {
        let (c, r) = (Vec2::new(30.3, 27.6), 14.2);
        let mask = disc(64, 60, c, r);
        let field = MaskDistance::new(&mask, 64, 60, 6).expect("a body");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut checked = 0;
        for _ in 0..400 {
            let p = c + Vec2::new(rng.random_range(-19.0..19.0), rng.random_range(-19.0..19.0));
            let Some((value, gradient)) = field.sample(p) else {
                continue;
            };
            let truth = r - (p - c).length();
            // The binary mask puts the edge within a pixel of the circle; bilinear steps are a pixel wide.
            assert!(
                (value - truth).abs() < 1.0,
                "at {p}: {value} against {truth}"
            );
            if (p - c).length() > 3.0 {
                let inward = (c - p).normalize();
                assert!(gradient.normalize().dot(inward) > 0.8, "at {p}: {gradient}");
            }
            checked += 1;
        }
        assert!(checked > 300, "{checked} points inside the window");
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_interpolated_value() {
        let mask = disc(40, 40, Vec2::new(19.5, 20.2), 9.0);
        let field = MaskDistance::new(&mask, 40, 40, 5).expect("a body");
        let h = 1e-2;
        for p in [
            Vec2::new(12.3, 17.8),
            Vec2::new(25.6, 24.1),
            Vec2::new(19.4, 10.7),
        ] {
            let (_, g) = field.sample(p).expect("inside the window");
            let dx = (field.sample(p + Vec2::X * h).unwrap().0
                - field.sample(p - Vec2::X * h).unwrap().0)
                / (2.0 * h);
            let dy = (field.sample(p + Vec2::Y * h).unwrap().0
                - field.sample(p - Vec2::Y * h).unwrap().0)
                / (2.0 * h);
            assert!(
                (g - Vec2::new(dx, dy)).length() < 1e-2,
                "at {p}: {g} against ({dx}, {dy})"
            );
        }
    }

    #[test]
    fn the_window_holds_the_body_and_its_margin_and_nothing_beyond() {
        let mut mask = vec![0u8; 50 * 40];
        for y in 10..20 {
            for x in 15..30 {
                mask[y * 50 + x] = 1;
            }
        }
        let field = MaskDistance::new(&mask, 50, 40, 4).expect("a body");
        assert_eq!((field.origin, field.width, field.height), ((11, 6), 23, 18));
        assert!(field.sample(Vec2::new(11.0, 6.0)).is_some());
        assert!(field.sample(Vec2::new(10.9, 12.0)).is_none());
        assert!(field.sample(Vec2::new(33.0, 23.0)).is_none());
        // On the body, half a pixel in from its left edge; off it, two and a half pixels out.
        assert_eq!(field.sample(Vec2::new(15.0, 15.0)).unwrap().0, 0.5);
        assert_eq!(field.sample(Vec2::new(12.0, 15.0)).unwrap().0, -2.5);
        assert!(MaskDistance::new(&vec![0u8; 50 * 40], 50, 40, 4).is_none());
    }
}
