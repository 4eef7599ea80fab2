//! The CPU kernel against closed forms (one splat, two splats in depth order, the cap and the stop), the
//! plain-tensor reference (forward and gradients on a scene with every rule at work), and central
//! differences.

use super::reference::rasterize as rasterize_reference;
use super::*;
use crate::tensor::{from_rows, to_host};
use anerf_device::cpu_device;

/// A splat by its shape: `sigma` along axes turned by `angle` (radians) from the image's.
#[derive(Debug, Clone, Copy)]
struct Shape {
    mean: [f32; 2],
    sigma: [f32; 2],
    angle: f32,
    colour: [f32; 3],
    opacity: f32,
    depth: f32,
}

impl Shape {
    fn round(mean: [f32; 2], sigma: f32, colour: [f32; 3], opacity: f32, depth: f32) -> Self {
        Self {
            mean,
            sigma: [sigma; 2],
            angle: 0.0,
            colour,
            opacity,
            depth,
        }
    }

    /// The packed row: the conic is the inverse of `R diag(σ²) Rᵀ`.
    fn row(&self) -> [f32; SPLAT_WIDTH] {
        let (s, c) = self.angle.sin_cos();
        let [v1, v2] = self.sigma.map(|s| s * s);
        let (xx, yy, xy) = (
            c * c * v1 + s * s * v2,
            s * s * v1 + c * c * v2,
            c * s * (v1 - v2),
        );
        let det = xx * yy - xy * xy;
        let [r, g, b] = self.colour;
        [
            self.mean[0],
            self.mean[1],
            yy / det,
            -xy / det,
            xx / det,
            r,
            g,
            b,
            self.opacity,
            self.depth,
        ]
    }
}

fn pack(shapes: &[Shape]) -> Vec<f32> {
    shapes.iter().flat_map(|s| s.row()).collect()
}

/// The kernel's and the reference's images of `rows` (`[H·W, 4]` each).
fn both(rows: &[f32], spec: &RasterSpec) -> (Vec<f32>, Vec<f32>) {
    let device = cpu_device();
    let t = from_rows(rows, rows.len() / SPLAT_WIDTH, SPLAT_WIDTH, &device);
    (
        to_host(extension::rasterize(t.clone(), spec)),
        to_host(rasterize_reference(t, spec)),
    )
}

/// A deterministic value in `[0, 1)` for `i` (independent of any global RNG).
pub(super) fn unit(i: usize) -> f32 {
    let mut x = (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    x ^= x >> 29;
    x = x.wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x ^= x >> 32;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// `n` splats scattered over and around a `w × h` image (some cross tile edges, some lie off it), of
/// every size, shape and opacity, plus the kernel's skip cases: too transparent to show anywhere, and a
/// conic that is not positive definite.
pub(super) fn scene(n: usize, w: f32, h: f32) -> Vec<f32> {
    let mut rows: Vec<f32> = (0..n)
        .flat_map(|i| {
            let u = |k: usize| unit(i * 16 + k);
            Shape {
                mean: [u(0) * (w + 8.0) - 4.0, u(1) * (h + 8.0) - 4.0],
                sigma: [0.6 + 5.0 * u(2), 0.6 + 5.0 * u(3)],
                angle: u(4) * 3.0,
                colour: [u(5), u(6), u(7)],
                opacity: 0.05 + 0.95 * u(8),
                depth: 0.5 + 4.0 * u(9),
            }
            .row()
        })
        .collect();
    let mut faint = Shape::round([w / 2.0, h / 2.0], 4.0, [1.0; 3], 0.003, 0.1).row();
    rows.extend(faint);
    faint[2] = -faint[2];
    faint[8] = 0.9;
    rows.extend(faint);
    rows
}

#[test]
fn one_splat_is_its_gaussian_cut_at_the_smallest_alpha() {
    let spec = RasterSpec {
        width: 37,
        height: 29,
    };
    let (mean, sigma, colour, opacity) = ([10.3, 7.6], 2.5f32, [0.2, 0.5, 0.9], 0.8);
    let rows = Shape::round(mean, sigma, colour, opacity, 1.0).row();
    for image in <[Vec<f32>; 2]>::from(both(&rows, &spec)) {
        for (i, pixel) in image.chunks(PIXEL_WIDTH).enumerate() {
            let (x, y) = ((i % 37) as f32, (i / 37) as f32);
            let d2 = (x - mean[0]).powi(2) + (y - mean[1]).powi(2);
            let alpha = opacity * (-d2 / (2.0 * sigma * sigma)).exp();
            let alpha = if alpha < ALPHA_MIN { 0.0 } else { alpha };
            let expected = [
                alpha * colour[0],
                alpha * colour[1],
                alpha * colour[2],
                alpha,
            ];
            for (got, want) in pixel.iter().zip(expected) {
                assert!(
                    (got - want).abs() < 1e-6,
                    "pixel ({x}, {y}): {pixel:?} vs {expected:?}"
                );
            }
        }
    }
}

#[test]
fn nearer_splats_cover_farther_ones_whatever_the_input_order() {
    let spec = RasterSpec {
        width: 9,
        height: 7,
    };
    let near = Shape::round([4.0, 3.0], 1.5, [1.0, 0.0, 0.0], 0.6, 1.0);
    let far = Shape::round([4.0, 3.0], 1.5, [0.0, 0.0, 1.0], 0.5, 2.0);
    // At the shared centre both Gaussians are 1: red 0.6, then blue 0.5 through the 0.4 left.
    let expected = [0.6, 0.0, 0.4 * 0.5, 1.0 - 0.4 * 0.5];
    let centre = (3 * 9 + 4) * PIXEL_WIDTH;
    for order in [[near, far], [far, near]] {
        for image in <[Vec<f32>; 2]>::from(both(&pack(&order), &spec)) {
            let got = &image[centre..centre + PIXEL_WIDTH];
            for (g, e) in got.iter().zip(expected) {
                assert!((g - e).abs() < 1e-6, "{got:?} vs {expected:?}");
            }
        }
    }
}

#[test]
fn alphas_are_capped_and_a_pixel_stops_before_it_turns_opaque() {
    let spec = RasterSpec {
        width: 5,
        height: 5,
    };
    let centre = 12 * PIXEL_WIDTH;
    // Fully opaque alone: alpha stops at the cap.
    let solid = Shape::round([2.0, 2.0], 1.0, [1.0; 3], 1.0, 1.0).row();
    for image in <[Vec<f32>; 2]>::from(both(&solid, &spec)) {
        assert!(
            (image[centre + 3] - ALPHA_MAX).abs() < 1e-7,
            "{}",
            image[centre + 3]
        );
    }
    // Four splats of alpha 0.95 at the centre: transmittance 0.05, 0.0025, 1.25e-4, then 6.25e-6 < T_MIN,
    // so the fourth (green) is never composited.
    let colours = [
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.5, 0.0, 0.5],
        [0.0, 1.0, 0.0],
    ];
    let stack: Vec<Shape> = colours
        .iter()
        .enumerate()
        .map(|(k, &c)| Shape::round([2.0, 2.0], 1.0, c, 0.95, 1.0 + k as f32))
        .collect();
    let mut expected = [0.0f32; 4];
    for (k, c) in colours[..3].iter().enumerate() {
        let weight = 0.05f32.powi(k as i32) * 0.95;
        for j in 0..3 {
            expected[j] += weight * c[j];
        }
    }
    expected[3] = 1.0 - 0.05f32.powi(3);
    for image in <[Vec<f32>; 2]>::from(both(&pack(&stack), &spec)) {
        let got = &image[centre..centre + PIXEL_WIDTH];
        assert_eq!(got[1], 0.0, "the fourth splat is composited: {got:?}");
        for (g, e) in got.iter().zip(expected) {
            assert!((g - e).abs() < 1e-6, "{got:?} vs {expected:?}");
        }
    }
}

#[test]
fn no_splats_or_only_broken_ones_leave_the_image_empty() {
    let spec = RasterSpec {
        width: 20,
        height: 18,
    };
    let mut nan = Shape::round([5.0, 5.0], 2.0, [1.0; 3], 0.9, 1.0).row();
    nan[0] = f32::NAN;
    let device = cpu_device();
    for rows in [vec![], nan.to_vec()] {
        let t = from_rows(&rows, rows.len() / SPLAT_WIDTH, SPLAT_WIDTH, &device);
        let image = to_host(extension::rasterize(t, &spec));
        assert_eq!(image, vec![0.0; spec.pixels() * PIXEL_WIDTH]);
    }
}

#[test]
fn kernel_matches_the_reference_forward() {
    // 3 × 2 tiles, the last ones partial.
    let spec = RasterSpec {
        width: 37,
        height: 29,
    };
    let rows = scene(200, 37.0, 29.0);
    let (kernel, reference) = both(&rows, &spec);
    let mut covered = 0;
    for (i, (k, r)) in kernel.iter().zip(&reference).enumerate() {
        assert!((k - r).abs() < 2e-5, "value {i}: kernel {k}, reference {r}");
        covered += usize::from(i % PIXEL_WIDTH == 3 && *r > 0.999);
    }
    assert!(covered > 0, "some pixels should reach the stop or the cap");
}

/// The tile-major forward pass meets each pixel's splats in the order the backward pass replays them
/// ([`cpu::composite`], pixel-major), with the same arithmetic: the images agree bit for bit.
#[test]
fn the_forward_pass_is_the_pixel_by_pixel_compositing_exactly() {
    let spec = RasterSpec {
        width: 37,
        height: 29,
    };
    let rows = scene(400, 37.0, 29.0);
    let mut out = vec![0.0; spec.pixels() * PIXEL_WIDTH];
    cpu::forward(&rows, &spec, &mut out);
    let bins = cpu::bin(&rows, &spec);
    let tile = TILE as usize;
    for y in 0..29 {
        for x in 0..37 {
            let (rgb, t) = cpu::composite(&rows, bins.tile(x / tile, y / tile), x, y, |_| {});
            let at = (y * 37 + x) * PIXEL_WIDTH;
            assert_eq!(&out[at..at + 3], &rgb, "pixel ({x}, {y})");
            assert_eq!(out[at + 3], 1.0 - t, "pixel ({x}, {y})");
        }
    }
}

/// The splat-major backward pass keeps the contributions the pixel-by-pixel compositing finds: its
/// gradient is the sum of [`cpu::pixel_backward`] over every pixel's [`cpu::composite`] (up to the order
/// of the sums).
#[test]
fn the_backward_pass_is_the_pixel_by_pixel_gradient() {
    let spec = RasterSpec {
        width: 37,
        height: 29,
    };
    let rows = scene(400, 37.0, 29.0);
    let g = weights(&spec);
    let mut got = vec![0.0; rows.len()];
    cpu::backward(&rows, &g, &spec, &mut got);
    let bins = cpu::bin(&rows, &spec);
    let tile = TILE as usize;
    let mut want = vec![0.0; rows.len()];
    let mut seen = Vec::new();
    for y in 0..29 {
        for x in 0..37 {
            seen.clear();
            let list = bins.tile(x / tile, y / tile);
            let (_, t) = cpu::composite(&rows, list, x, y, |c| seen.push(*c));
            let at = (y * 37 + x) * PIXEL_WIDTH;
            cpu::pixel_backward(&rows, &seen, t, &g[at..at + PIXEL_WIDTH], &mut want);
        }
    }
    let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (i, (a, b)) in got.iter().zip(&want).enumerate() {
        assert!(
            (a - b).abs() <= 1e-5 * scale,
            "splat {} value {}: {a} vs {b}",
            i / SPLAT_WIDTH,
            i % SPLAT_WIDTH
        );
    }
    assert!(want.iter().filter(|v| **v != 0.0).count() > rows.len() / 4);
}

/// The gradient of `Σ weights ⊙ rasterize(splats)` through the kernel or the reference.
fn gradient(rows: &[f32], spec: &RasterSpec, weights: &[f32], use_kernel: bool) -> Vec<f32> {
    let device = cpu_device().autodiff();
    let splats = from_rows(rows, rows.len() / SPLAT_WIDTH, SPLAT_WIDTH, &device).require_grad();
    let image = if use_kernel {
        extension::rasterize(splats.clone(), spec)
    } else {
        rasterize_reference(splats.clone(), spec)
    };
    let w = from_rows(weights, spec.pixels(), PIXEL_WIDTH, &device);
    let grads = (image * w).sum().backward();
    to_host(splats.grad(&grads).expect("splat gradient"))
}

pub(super) fn weights(spec: &RasterSpec) -> Vec<f32> {
    (0..spec.pixels() * PIXEL_WIDTH)
        .map(|i| unit(1_000_000 + i) * 2.0 - 1.0)
        .collect()
}

#[test]
fn kernel_matches_the_reference_backward() {
    let spec = RasterSpec {
        width: 37,
        height: 29,
    };
    let rows = scene(200, 37.0, 29.0);
    let w = weights(&spec);
    let kernel = gradient(&rows, &spec, &w, true);
    let reference = gradient(&rows, &spec, &w, false);
    for (i, (k, r)) in kernel.iter().zip(&reference).enumerate() {
        assert!(
            (k - r).abs() < 1e-3 * (1.0 + r.abs()),
            "splat {} value {}: kernel {k}, reference {r}",
            i / SPLAT_WIDTH,
            i % SPLAT_WIDTH
        );
    }
    assert!(kernel.iter().any(|&g| g != 0.0));
}

/// Large splats whose cut-off ellipses hold the whole (small) image, under the cap and far from the stop:
/// there the image is a smooth function of every value, for central differences.
pub(super) fn smooth_scene() -> (RasterSpec, Vec<f32>) {
    // The narrowest cut-off (σ = 6 px, opacity 0.3) reaches 6·√(2 ln 76.5) ≈ 17.7 px from the mean, past
    // every corner (at most √(12² + 8²) ≈ 14.4 px away).
    let spec = RasterSpec {
        width: 16,
        height: 12,
    };
    let shapes: Vec<Shape> = (0..5)
        .map(|i| {
            let u = |k: usize| unit(5_000 + i * 16 + k);
            Shape {
                mean: [4.0 + 8.0 * u(0), 4.0 + 4.0 * u(1)],
                sigma: [6.0 + 2.0 * u(2), 12.0 + 4.0 * u(3)],
                angle: u(4) * 3.0,
                colour: [u(5), u(6), u(7)],
                opacity: 0.3 + 0.4 * u(8),
                depth: 1.0 + i as f32,
            }
        })
        .collect();
    (spec, pack(&shapes))
}

/// Central difference steps per splat value: means in pixels, conics in pixels⁻² (about 0.01), colours and
/// opacity (the depth has none).
const STEPS: [f32; 9] = [1e-2, 1e-2, 1e-4, 1e-4, 1e-4, 1e-2, 1e-2, 1e-2, 1e-3];

/// Checks `analytic`, the gradient of `Σ weights(spec) ⊙ image` at [`smooth_scene`]'s splats, against
/// central differences of `forward` (splat rows → `[H·W, 4]` image; the objective summed in f64); `what`
/// names the gradient's source in a failure.
pub(super) fn check_central_differences(
    what: &str,
    analytic: &[f32],
    forward: impl Fn(&[f32]) -> Vec<f32>,
) {
    let (spec, rows) = smooth_scene();
    let w = weights(&spec);
    let objective = |rows: &[f32]| -> f64 {
        let image = forward(rows);
        image
            .iter()
            .zip(&w)
            .map(|(a, b)| *a as f64 * *b as f64)
            .sum()
    };
    for (i, g) in analytic.iter().enumerate() {
        let k = i % SPLAT_WIDTH;
        if k == 9 {
            assert_eq!(*g, 0.0, "{what}: depth has no gradient");
            continue;
        }
        let (mut plus, mut minus) = (rows.clone(), rows.clone());
        plus[i] += STEPS[k];
        minus[i] -= STEPS[k];
        let numeric = (objective(&plus) - objective(&minus)) / (2.0 * STEPS[k] as f64);
        assert!(
            (numeric - *g as f64).abs() < 2e-2 * (1.0 + numeric.abs()),
            "{what}, splat {} value {k}: numeric {numeric}, analytic {g}",
            i / SPLAT_WIDTH
        );
    }
}

/// Central differences against the kernel's backward pass on [`smooth_scene`].
#[test]
fn kernel_gradients_match_central_differences() {
    let (spec, rows) = smooth_scene();
    let analytic = gradient(&rows, &spec, &weights(&spec), true);
    check_central_differences("the CPU kernel", &analytic, |rows| {
        let mut out = vec![0.0; spec.pixels() * PIXEL_WIDTH];
        cpu::forward(rows, &spec, &mut out);
        out
    });
}
