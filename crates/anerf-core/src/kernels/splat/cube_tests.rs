//! The rasteriser's CubeCL kernels on each compiled GPU runtime (wgpu, CUDA) against the CPU kernel
//! (flex), the plain-tensor reference on the same device, and central differences of their own forward
//! pass. Each test first checks every GPU backend in a child process (`anerf_device::probe`) and runs on
//! those that work, printing why for the others.
//!
//! Tolerances: the kernels use the CPU kernel's formulas but the device's `exp` and rounding, and the
//! backward pass recovers transmittances by division where the CPU kernel keeps them, so images agree to
//! `2e-5 · (1 + |x|)` and gradients to `1e-3 · (1 + |x|)` (the CPU kernel's own bound against the
//! reference).

use burn::prelude::*;

use super::cube;
use super::cube_bins;
use super::reference::rasterize as rasterize_reference;
use super::tests::{check_central_differences, scene, smooth_scene, weights};
use super::*;
use crate::kernels::cube::testing::{atomic_schemes, cube_tensor};
use crate::kernels::cube_sort::download_u32;
use crate::tensor::{from_rows, to_host};
use crate::DeviceChoice;
use anerf_device::cpu_device;
use anerf_device::testing::gpu_devices_for_test;
use burn_cubecl::ops::into_data_sync;

/// The GPU devices (wgpu, CUDA) for the test `test` (under `kernels::splat::cube_tests::`) that pass the
/// probe; each one missing is printed with the reason.
fn gpus(test: &str) -> Vec<(DeviceChoice, Device)> {
    gpu_devices_for_test(&format!("kernels::splat::cube_tests::{test}"))
}

/// 3 × 2 tiles, the last ones partial.
const SPEC: RasterSpec = RasterSpec {
    width: 37,
    height: 29,
};

fn splats_on(rows: &[f32], device: &Device) -> Tensor<2> {
    from_rows(rows, rows.len() / SPLAT_WIDTH, SPLAT_WIDTH, device)
}

fn assert_near(what: &str, got: &[f32], want: &[f32], tolerance: f32) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= tolerance * (1.0 + w.abs()),
            "{what}, value {i} (splat or pixel {}, column {}): {g} vs {w}",
            i / SPLAT_WIDTH.max(PIXEL_WIDTH),
            i % SPLAT_WIDTH.max(PIXEL_WIDTH)
        );
    }
}

#[test]
fn cube_rasteriser_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_rasteriser_matches_flex_and_the_reference") {
        eprintln!("on {choice}");
        let rows = scene(200, SPEC.width as f32, SPEC.height as f32);
        let got = to_host(rasterize(splats_on(&rows, &gpu), &SPEC));
        let flex = to_host(rasterize(splats_on(&rows, &cpu_device()), &SPEC));
        let reference = to_host(rasterize_reference(splats_on(&rows, &gpu), &SPEC));
        assert_near(&format!("image on {choice} vs flex"), &got, &flex, 2e-5);
        assert_near(
            &format!("image on {choice} vs the reference there"),
            &got,
            &reference,
            2e-5,
        );
        assert!(got.chunks(PIXEL_WIDTH).any(|p| p[3] > 0.999));
        // No splat at all: an empty image, not a failed launch.
        let empty = to_host(rasterize(Tensor::zeros([0, SPLAT_WIDTH], &gpu), &SPEC));
        assert!(empty.iter().all(|&v| v == 0.0));
    }
}

#[test]
fn cube_gradient_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_gradient_matches_flex_and_the_reference") {
        let rows = scene(200, SPEC.width as f32, SPEC.height as f32);
        let w = weights(&SPEC);
        let mut flex = vec![0.0; rows.len()];
        cpu::backward(&rows, &w, &SPEC, &mut flex);
        let reference = {
            let splats = splats_on(&rows, &gpu.clone().autodiff()).require_grad();
            let image = rasterize_reference(splats.clone(), &SPEC);
            let weights = from_rows(&w, SPEC.pixels(), PIXEL_WIDTH, &gpu.clone().autodiff());
            let grads = (image * weights).sum().backward();
            to_host(splats.grad(&grads).expect("splat gradient"))
        };
        for scheme in atomic_schemes(&gpu) {
            eprintln!("on {choice}, {scheme:?}");
            let got = cube::backward(
                cube_tensor(splats_on(&rows, &gpu)),
                cube_tensor(from_rows(&w, SPEC.pixels(), PIXEL_WIDTH, &gpu)),
                &SPEC,
                scheme,
            );
            let got = into_data_sync(got).try_into_vec::<f32>().unwrap();
            assert_near(&format!("gradient on {choice} vs flex"), &got, &flex, 1e-3);
            assert_near(
                &format!("gradient on {choice} vs the reference there"),
                &got,
                &reference,
                1e-3,
            );
            assert!(got.iter().any(|&g| g != 0.0));
        }
    }
}

/// The GPU's gradient through Burn's autodiff (the extension's backward step) against central differences
/// of the GPU's own forward pass (summed in f64 on the host).
#[test]
fn cube_gradient_matches_central_differences() {
    for (choice, gpu) in gpus("cube_gradient_matches_central_differences") {
        eprintln!("on {choice}");
        let (spec, rows) = smooth_scene();
        let w = weights(&spec);
        let autodiff = gpu.clone().autodiff();
        let splats = splats_on(&rows, &autodiff).require_grad();
        let weights_t = from_rows(&w, spec.pixels(), PIXEL_WIDTH, &autodiff);
        let grads = (rasterize(splats.clone(), &spec) * weights_t)
            .sum()
            .backward();
        let analytic = to_host(splats.grad(&grads).expect("splat gradient"));
        check_central_differences(&format!("the kernel on {choice}"), &analytic, |rows| {
            to_host(rasterize(splats_on(rows, &gpu), &spec))
        });
    }
}

/// Binning on the device gives the CPU kernel's tile lists exactly: the same entries, each tile's front to
/// back, equal depths in splat order (negative depths, `±0` and ties included), nothing for splats that are
/// not finite or off the image; and so does the host path taken for scenes too large for `u32` entries.
#[test]
fn device_bins_match_the_cpu_kernels() {
    for (choice, gpu) in gpus("device_bins_match_the_cpu_kernels") {
        let wide = RasterSpec {
            width: 150,
            height: 70,
        };
        let one_tile = RasterSpec {
            width: 16,
            height: 16,
        };
        let mut crowded = scene(3000, wide.width as f32, wide.height as f32);
        for (i, row) in crowded.chunks_mut(SPLAT_WIDTH).enumerate() {
            match i % 7 {
                0 => row[9] = 2.0,
                1 => row[9] = -1.5 - (i % 3) as f32,
                2 => row[9] = if i % 2 == 0 { 0.0 } else { -0.0 },
                3 if i % 70 == 3 => row[0] = f32::NAN,
                _ => {}
            }
        }
        let cases = [
            (
                "the test scene",
                SPEC,
                scene(200, SPEC.width as f32, SPEC.height as f32),
            ),
            ("a crowded scene with ties", wide, crowded),
            ("one tile", one_tile, scene(40, 16.0, 16.0)),
            ("no splat", SPEC, Vec::new()),
        ];
        for (what, spec, rows) in cases {
            let expected = cpu::bin(&rows, &spec);
            assert!(what == "no splat" || !expected.order.is_empty());
            let splats = cube_tensor(if rows.is_empty() {
                Tensor::zeros([0, SPLAT_WIDTH], &gpu)
            } else {
                splats_on(&rows, &gpu)
            });
            for (path, bins) in [
                ("device", cube_bins::bin_on_device(&splats, &spec)),
                ("host", cube_bins::bin_on_host(&splats, &spec)),
            ] {
                assert_eq!(bins.tiles_x as usize, expected.tiles_x);
                let starts = download_u32(bins.starts);
                let order = download_u32(bins.order);
                let expected_starts: Vec<u32> = expected.starts.iter().map(|&s| s as u32).collect();
                assert_eq!(
                    starts, expected_starts,
                    "{what} on {choice}, {path}: tile starts"
                );
                assert_eq!(
                    &order[..expected.order.len()],
                    &expected.order[..],
                    "{what} on {choice}, {path}: tile lists"
                );
            }
        }
    }
}
