//! Prints how long the preparation steps take at the datasets' real sizes: blend-weight volumes of an
//! SMPL-sized body (≈6900 vertices, ≈13800 faces, 24 joints), undistorting and downscaling a 1024²
//! image, and drawing rays from a 512² image.
//!
//! `cargo run -p anerf-data --example prepare_figures`

use std::time::Instant;

use anerf_core::geometry::{Aabb, Camera, Distortion};
use anerf_data::prepare::resize::{resize_area, resize_nearest};
use anerf_data::prepare::undistort::UndistortMap;
use anerf_data::prepare::{compute_volume, NearestMethod, VolumeGrid};
use anerf_data::{image_rays, ImageView, RaySampler, SamplerOptions, SkinningWeights};
use glam::Vec3;
use image::{GrayImage, Rgb32FImage};

/// A closed ellipsoid of `rings × segments` vertices, standing 1.7 m tall, with weights spread over
/// `joints` height bands.
fn body(
    rings: usize,
    segments: usize,
    joints: usize,
) -> (Vec<Vec3>, Vec<[u32; 3]>, SkinningWeights) {
    let mut v = Vec::new();
    let mut w = Vec::new();
    for r in 0..rings {
        let t = std::f32::consts::PI * (r as f32 + 0.5) / rings as f32;
        for s in 0..segments {
            let p = 2.0 * std::f32::consts::PI * s as f32 / segments as f32;
            v.push(Vec3::new(
                0.25 * t.sin() * p.cos(),
                0.85 - 0.85 * t.cos(),
                0.15 * t.sin() * p.sin(),
            ));
            let band = t / std::f32::consts::PI * (joints - 1) as f32;
            let mut row = vec![0.0; joints];
            let lo = band.floor() as usize;
            row[lo] = 1.0 - band.fract();
            row[(lo + 1).min(joints - 1)] += band.fract();
            w.extend(row);
        }
    }
    let mut f = Vec::new();
    for r in 0..rings - 1 {
        for s in 0..segments {
            let (a, b) = (
                (r * segments + s) as u32,
                (r * segments + (s + 1) % segments) as u32,
            );
            let (c, d) = (a + segments as u32, b + segments as u32);
            f.push([a, c, b]);
            f.push([b, c, d]);
        }
    }
    (v, f, SkinningWeights::new(w, joints).expect("normalised"))
}

fn main() {
    let threads = rayon::current_num_threads();
    let (v, f, w) = body(66, 104, 24);
    println!(
        "body: {} vertices, {} faces, {} joints; {threads} rayon threads",
        v.len(),
        f.len(),
        w.num_joints()
    );
    for method in [NearestMethod::Surface, NearestMethod::Vertex] {
        let t = Instant::now();
        let vol = compute_volume(&v, &f, &w, method, VolumeGrid::default());
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let nodes: usize = vol.dims.iter().product();
        println!(
            "volume {method:?}: {:?} nodes ({nodes}), {ms:.0} ms ({:.2} µs/node)",
            vol.dims,
            ms * 1e3 / nodes as f64
        );
    }

    let size = 1024;
    let k = [[1100.0, 0.0, 512.3], [0.0, 1102.0, 511.7], [0.0, 0.0, 1.0]];
    let cam = Camera::from_rows(
        k,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, -0.85, 3.0],
        [-0.3, 0.15, 0.001, -0.001, 0.0],
        size,
        size,
    )
    .expect("valid camera");
    let img = Rgb32FImage::from_fn(size, size, |x, y| {
        image::Rgb([x as f32 / 1024.0, y as f32 / 1024.0, 0.5])
    });
    let mask = GrayImage::from_fn(size, size, |x, y| {
        image::Luma([((x as i32 - 512).pow(2) + (y as i32 - 512).pow(2) < 200 * 200) as u8])
    });
    let t = Instant::now();
    let map = UndistortMap::new(cam.intrinsics, &cam.distortion, size, size);
    let t_map = t.elapsed();
    let t = Instant::now();
    let und = map.remap_rgb(&img);
    let small = resize_area(&und, 512, 512);
    let t_img = t.elapsed();
    let t = Instant::now();
    let m = resize_nearest(&map.remap_nearest(&mask), 512, 512);
    let t_mask = t.elapsed();
    println!(
        "1024² → 512²: undistortion map {:.0} ms (once per camera), image undistort+INTER_AREA {:.0} ms, mask {:.0} ms",
        t_map.as_secs_f64() * 1e3,
        t_img.as_secs_f64() * 1e3,
        t_mask.as_secs_f64() * 1e3
    );

    let work = Camera {
        distortion: Distortion::default(),
        ..cam
    }
    .resized(0.5);
    let bounds = Aabb {
        min: Vec3::new(-0.3, -0.05, -0.2),
        max: Vec3::new(0.3, 1.75, 0.2),
    };
    let mut sampler = RaySampler::new(0, SamplerOptions::default());
    let view = ImageView {
        camera: &work,
        bounds: &bounds,
        image: (&small).into(),
        mask: &m,
        edge: None,
        background: None,
    };
    let t = Instant::now();
    let n = 50;
    for _ in 0..n {
        sampler.sample(&view, 1024).expect("rays");
    }
    println!(
        "training rays: 1024 rays from a 512² image in {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3 / n as f64
    );
    let t = Instant::now();
    let all = image_rays(
        &work,
        &bounds,
        Some((&small, &m)),
        &SamplerOptions::default(),
    )
    .expect("rays");
    println!(
        "evaluation rays: {} mask_at_box rays of a 512² image in {:.1} ms",
        all.rays.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
}
