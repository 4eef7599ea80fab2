//! The rasteriser on the CPU, on plain slices: splats binned into 16 × 16 pixel tiles and sorted front to
//! back per tile, each pixel composited front to back with 3D Gaussian Splatting's rules (alpha capped at
//! [`ALPHA_MAX`], splats under [`ALPHA_MIN`] skipped, a pixel stops before its transmittance falls under
//! [`T_MIN`]), and the backward pass that walks each pixel's splats back to front. Bands of 16 rows run
//! in parallel.

use rayon::prelude::*;

use super::{
    RasterSpec, ALPHA_MAX, ALPHA_MIN, EXTENT_MARGIN, EXTENT_SCALE, PIXEL_WIDTH, SPLAT_WIDTH, TILE,
    T_MIN,
};

/// One splat, unpacked from its [`SPLAT_WIDTH`] values.
#[derive(Debug, Clone, Copy)]
struct Splat {
    /// Pixels; pixel `(x, y)` is evaluated at the point `(x, y)`.
    mean: [f32; 2],
    /// `(a, b, c)` of the inverse 2-D covariance `[[a, b], [b, c]]` (pixels⁻²).
    conic: [f32; 3],
    colour: [f32; 3],
    opacity: f32,
}

impl Splat {
    fn read(splats: &[f32], index: usize) -> Self {
        let s = &splats[index * SPLAT_WIDTH..(index + 1) * SPLAT_WIDTH];
        Self {
            mean: [s[0], s[1]],
            conic: [s[2], s[3], s[4]],
            colour: [s[5], s[6], s[7]],
            opacity: s[8],
        }
    }

    /// The Gaussian's exponent at pixel `(px, py)`, and the offsets `(dx, dy)` from its mean.
    fn power(&self, px: f32, py: f32) -> (f32, f32, f32) {
        let (dx, dy) = (px - self.mean[0], py - self.mean[1]);
        let [a, b, c] = self.conic;
        (-0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy, dx, dy)
    }

    /// Its share of the point `(px, py)` under 3DGS's rules: `None` where the exponent is positive or the
    /// alpha falls under [`ALPHA_MIN`].
    fn at(&self, px: f32, py: f32) -> Option<Share> {
        let (power, dx, dy) = self.power(px, py);
        if power > 0.0 {
            return None;
        }
        let gaussian = power.exp();
        let raw = self.opacity * gaussian;
        let alpha = raw.min(ALPHA_MAX);
        (alpha >= ALPHA_MIN).then_some(Share {
            alpha,
            gaussian,
            uncapped: raw < ALPHA_MAX,
            dx,
            dy,
        })
    }

    /// The half-widths in pixels (x, y) of the box outside which its alpha stays under [`ALPHA_MIN`]
    /// (slightly widened, so that binning never drops a pixel the per-pixel test would keep); `None` for a
    /// splat that touches no pixel (too transparent, not positive definite, not finite).
    fn extent(&self) -> Option<(f32, f32)> {
        let [a, b, c] = self.conic;
        let det = a * c - b * b;
        let finite = self.mean.iter().chain(&self.conic).all(|v| v.is_finite());
        if !(finite && self.opacity >= ALPHA_MIN && a > 0.0 && det > 0.0) {
            return None;
        }
        // o · exp(−q/2) ≥ 1/255  ⇔  q ≤ 2 ln(255 o), with q = dᵀ M d; the ellipse's box is
        // sqrt(r² Σ_xx) by sqrt(r² Σ_yy) with Σ = M⁻¹.
        let r2 = 2.0 * (self.opacity / ALPHA_MIN).ln();
        let widen = |e: f32| e * EXTENT_SCALE + EXTENT_MARGIN;
        Some((widen((r2 * c / det).sqrt()), widen((r2 * a / det).sqrt())))
    }
}

/// The splats of each tile, front to back: tile `t`'s are `order[starts[t]..starts[t + 1]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Bins {
    pub tiles_x: usize,
    pub tiles_y: usize,
    pub starts: Vec<usize>,
    pub order: Vec<u32>,
}

impl Bins {
    /// The splats over tile `(tx, ty)`, front to back.
    pub fn tile(&self, tx: usize, ty: usize) -> &[u32] {
        let t = ty * self.tiles_x + tx;
        &self.order[self.starts[t]..self.starts[t + 1]]
    }
}

/// Bins the splats (`[N, SPLAT_WIDTH]`) into tiles, each tile's sorted by depth (then index, so that equal
/// depths keep their input order).
pub fn bin(splats: &[f32], spec: &RasterSpec) -> Bins {
    bin_boxes(splats, &boxes(splats), spec)
}

/// [`bin`] with the splats' [`boxes`] at hand.
fn bin_boxes(splats: &[f32], boxes: &[Option<(Splat, [f32; 4])>], spec: &RasterSpec) -> Bins {
    let tile = TILE as usize;
    let (w, h) = (spec.width as usize, spec.height as usize);
    let (tiles_x, tiles_y) = (w.div_ceil(tile), h.div_ceil(tile));
    // Each splat's pixel box, clipped to the image, as a range of tiles.
    let tiles: Vec<Option<[usize; 4]>> = boxes
        .par_iter()
        .map(|b| {
            let (_, [lx, hx, ly, hy]) = b.as_ref()?;
            let range = |lo: f32, hi: f32, len: usize| {
                let lo = lo.ceil().max(0.0);
                let hi = hi.floor().min(len as f32 - 1.0);
                (lo <= hi).then(|| (lo as usize / tile, hi as usize / tile))
            };
            let (x0, x1) = range(*lx, *hx, w)?;
            let (y0, y1) = range(*ly, *hy, h)?;
            Some([x0, x1, y0, y1])
        })
        .collect();
    let mut keys: Vec<(usize, f32, u32)> = Vec::new();
    for (i, b) in tiles.iter().enumerate() {
        let Some([x0, x1, y0, y1]) = *b else { continue };
        let depth = splats[i * SPLAT_WIDTH + 9];
        for ty in y0..=y1 {
            for tx in x0..=x1 {
                keys.push((ty * tiles_x + tx, depth, i as u32));
            }
        }
    }
    keys.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut starts = vec![0; tiles_x * tiles_y + 1];
    for &(t, _, _) in &keys {
        starts[t + 1] += 1;
    }
    for t in 0..tiles_x * tiles_y {
        starts[t + 1] += starts[t];
    }
    Bins {
        tiles_x,
        tiles_y,
        starts,
        order: keys.into_iter().map(|(_, _, i)| i).collect(),
    }
}

/// A splat's alpha at a point and what its gradient needs.
#[derive(Debug, Clone, Copy)]
struct Share {
    /// The alpha composited (capped, at least [`ALPHA_MIN`]).
    alpha: f32,
    /// `exp(power)`.
    gaussian: f32,
    /// Whether `opacity · gaussian` was under [`ALPHA_MAX`] (above, the cap holds alpha constant).
    uncapped: bool,
    dx: f32,
    dy: f32,
}

/// One splat's share of a pixel, as the compositing met it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Contribution {
    index: u32,
    share: Share,
    /// Transmittance in front of the splat.
    before: f32,
}

/// Composites pixel `(x, y)` from `list` (front to back), calling `visit` with each splat that contributes;
/// returns the colour (without background) and the transmittance left. The plain pixel-by-pixel order the
/// tests hold [`composite_band`]'s splat-major order to.
#[cfg(test)]
pub(super) fn composite(
    splats: &[f32],
    list: &[u32],
    x: usize,
    y: usize,
    mut visit: impl FnMut(&Contribution),
) -> ([f32; 3], f32) {
    let (px, py) = (x as f32, y as f32);
    let mut rgb = [0.0f32; 3];
    let mut t = 1.0f32;
    for &index in list {
        let s = Splat::read(splats, index as usize);
        let Some(share) = s.at(px, py) else {
            continue;
        };
        let alpha = share.alpha;
        let after = t * (1.0 - alpha);
        if after < T_MIN {
            break;
        }
        for (c, v) in rgb.iter_mut().zip(s.colour) {
            *c += t * alpha * v;
        }
        visit(&Contribution {
            index,
            share,
            before: t,
        });
        t = after;
    }
    (rgb, t)
}

/// Each splat's pixel box (`[x_lo, x_hi, y_lo, y_hi]`, pixels) beside the splat; `None` for a splat that
/// touches no pixel.
fn boxes(splats: &[f32]) -> Vec<Option<(Splat, [f32; 4])>> {
    (0..splats.len() / SPLAT_WIDTH)
        .into_par_iter()
        .map(|i| {
            let s = Splat::read(splats, i);
            let (ex, ey) = s.extent()?;
            let [mx, my] = s.mean;
            Some((s, [mx - ex, mx + ex, my - ey, my + ey]))
        })
        .collect()
}

/// Composites the band of tile row `ty` (`rows` image rows of width `w`) tile by tile, splat-major: each
/// splat of a tile's front-to-back list visits only the tile's pixels inside its cut-off box that are still
/// open, so a pixel meets the same splats in the same order with the same arithmetic as [`composite`] at
/// a fraction of the tests. Writes each pixel's colour and transmittance into `pixels` (`[rows · w]`,
/// row-major within the band) and calls `visit(k, contribution)` for pixel `k`'s contributions, front to
/// back.
fn composite_band(
    bins: &Bins,
    boxes: &[Option<(Splat, [f32; 4])>],
    ty: usize,
    w: usize,
    rows: usize,
    pixels: &mut [[f32; PIXEL_WIDTH]],
    mut visit: impl FnMut(usize, &Contribution),
) {
    let tile = TILE as usize;
    pixels.fill([0.0, 0.0, 0.0, 1.0]);
    let mut open = [true; (TILE * TILE) as usize];
    for tx in 0..bins.tiles_x {
        let (x0, y0) = (tx * tile, ty * tile);
        let cols = tile.min(w - x0);
        open.fill(true);
        let mut remaining = cols * rows;
        for &index in bins.tile(tx, ty) {
            let Some((s, [lx, hx, ly, hy])) = &boxes[index as usize] else {
                continue;
            };
            // The tile's pixels inside the box (pixel (x, y) sits at the point (x, y)).
            let span = |lo: f32, hi: f32, start: usize, len: usize| {
                let first = lo.ceil().max(start as f32);
                let last = hi.floor().min((start + len - 1) as f32);
                first as usize..(last + 1.0).max(first) as usize
            };
            for y in span(*ly, *hy, y0, rows) {
                for x in span(*lx, *hx, x0, cols) {
                    let o = (y - y0) * tile + (x - x0);
                    if !open[o] {
                        continue;
                    }
                    let Some(share) = s.at(x as f32, y as f32) else {
                        continue;
                    };
                    let alpha = share.alpha;
                    let k = (y - y0) * w + x;
                    let pixel = &mut pixels[k];
                    let t = pixel[3];
                    let after = t * (1.0 - alpha);
                    if after < T_MIN {
                        open[o] = false;
                        remaining -= 1;
                        continue;
                    }
                    for (c, v) in pixel[..3].iter_mut().zip(s.colour) {
                        *c += t * alpha * v;
                    }
                    pixel[3] = after;
                    visit(
                        k,
                        &Contribution {
                            index,
                            share,
                            before: t,
                        },
                    );
                }
            }
            if remaining == 0 {
                break;
            }
        }
    }
}

/// Renders the splats into `out` (`[H·W, PIXEL_WIDTH]`, row-major pixels): premultiplied colour and alpha,
/// bands of [`TILE`] rows in parallel ([`composite_band`]).
pub fn forward(splats: &[f32], spec: &RasterSpec, out: &mut [f32]) {
    let (w, h) = (spec.width as usize, spec.height as usize);
    assert_eq!(out.len(), w * h * PIXEL_WIDTH, "rasteriser output");
    let boxes = boxes(splats);
    let bins = bin_boxes(splats, &boxes, spec);
    let band = TILE as usize * w * PIXEL_WIDTH;
    out.par_chunks_mut(band)
        .enumerate()
        .for_each_init(Vec::new, |pixels, (ty, rows)| {
            let n = rows.len() / PIXEL_WIDTH;
            pixels.resize(n, [0.0; PIXEL_WIDTH]);
            composite_band(&bins, &boxes, ty, w, n / w, &mut pixels[..n], |_, _| {});
            for (p, o) in pixels.iter().zip(rows.chunks_mut(PIXEL_WIDTH)) {
                o[..3].copy_from_slice(&p[..3]);
                o[3] = 1.0 - p[3];
            }
        });
}

/// The gradient of the splats (`[N, SPLAT_WIDTH]`; the depth's is 0) from the gradient of the output
/// (`[H·W, PIXEL_WIDTH]`): each band is composited again as [`forward`] does it, keeping every pixel's
/// contributions, whose gradients [`pixel_backward`] then adds pixel by pixel.
pub fn backward(splats: &[f32], grad: &[f32], spec: &RasterSpec, out: &mut [f32]) {
    let (w, h) = (spec.width as usize, spec.height as usize);
    assert_eq!(
        grad.len(),
        w * h * PIXEL_WIDTH,
        "rasteriser output gradient"
    );
    assert_eq!(out.len(), splats.len(), "splat gradient");
    let boxes = boxes(splats);
    let bins = bin_boxes(splats, &boxes, spec);
    let band = TILE as usize * w * PIXEL_WIDTH;
    let total = grad
        .par_chunks(band)
        .enumerate()
        .fold(
            || (vec![0.0f32; splats.len()], Vec::new(), Vec::new()),
            |(mut acc, mut pixels, mut seen), (ty, g)| {
                let n = g.len() / PIXEL_WIDTH;
                pixels.resize(n, [0.0; PIXEL_WIDTH]);
                seen.resize_with(n, Vec::new);
                seen.iter_mut().for_each(Vec::clear);
                composite_band(&bins, &boxes, ty, w, n / w, &mut pixels[..n], |k, c| {
                    seen[k].push(*c)
                });
                for (k, g) in g.chunks(PIXEL_WIDTH).enumerate() {
                    pixel_backward(splats, &seen[k], pixels[k][3], g, &mut acc);
                }
                (acc, pixels, seen)
            },
        )
        .map(|(acc, _, _)| acc)
        .reduce(
            || vec![0.0f32; splats.len()],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            },
        );
    out.copy_from_slice(&total);
}

/// Adds one pixel's gradient (`g`: colour and alpha) to its splats' rows of `acc`, walking `seen` (the
/// pixel's contributions, front to back) backwards.
///
/// With `C = Σ T_k α_k c_k`, `A = 1 − T_final` and `R_k = Σ_{j>k} T_j α_j c_j` (the colour behind `k`):
/// `∂C/∂c_k = T_k α_k`, `∂C/∂α_k = T_k c_k − R_k / (1 − α_k)`, `∂A/∂α_k = T_final / (1 − α_k)`; and
/// below the cap `α = o · exp(p)`, so `∂α/∂o = exp(p)` and `∂α/∂p = α`.
pub(super) fn pixel_backward(
    splats: &[f32],
    seen: &[Contribution],
    t_final: f32,
    g: &[f32],
    acc: &mut [f32],
) {
    let (g_rgb, g_alpha) = ([g[0], g[1], g[2]], g[3]);
    let mut behind = [0.0f32; 3];
    for c in seen.iter().rev() {
        let i = c.index as usize;
        let s = Splat::read(splats, i);
        let row = &mut acc[i * SPLAT_WIDTH..(i + 1) * SPLAT_WIDTH];
        let weight = c.before * c.share.alpha;
        let keep = 1.0 - c.share.alpha;
        let mut g_a = g_alpha * t_final / keep;
        for k in 0..3 {
            row[5 + k] += weight * g_rgb[k];
            g_a += g_rgb[k] * (c.before * s.colour[k] - behind[k] / keep);
            behind[k] += weight * s.colour[k];
        }
        if !c.share.uncapped {
            continue;
        }
        row[8] += g_a * c.share.gaussian;
        let g_p = g_a * c.share.alpha;
        let [a, b, cc] = s.conic;
        let (dx, dy) = (c.share.dx, c.share.dy);
        // p = −(a dx² + c dy²)/2 − b dx dy with dx = x − mean_x.
        row[0] += g_p * (a * dx + b * dy);
        row[1] += g_p * (cc * dy + b * dx);
        row[2] += g_p * -0.5 * dx * dx;
        row[3] += g_p * -dx * dy;
        row[4] += g_p * -0.5 * dy * dy;
    }
}
