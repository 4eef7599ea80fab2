//! Drawing training rays from a prepared subject on the host, the part of a stage-1 step that runs before
//! the model sees a ray: `cargo bench -p anerf-data --bench ray_sampling -- <prepared dir> [FRAMES] [VIEWS]`
//! (a cache entry `<cache>/v2/<hash>`, e.g. of `anerf train --data`, as an absolute path: cargo runs a
//! bench in its crate's folder). Prints the median and range over repeated steps of a whole step (`FRAMES`
//! frames × `VIEWS` views, default 4 × 4, 1,024 rays, the `robust` band) and of its parts for one image:
//! reading the image, reading the mask and its band, the box's projection, and drawing the rays.

use std::path::PathBuf;

use anerf_data::sampler::{box_mask, ImageView};
use anerf_data::{ImageCache, MaskEdges, PreparedSubject, RaySampler, SamplerOptions, StepImages};
use anerf_testing::report_ms;

/// Timed repetitions of each measurement, after one untimed one.
const REPEATS: usize = 30;

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let Some(dir) = args.first().map(PathBuf::from) else {
        eprintln!("usage: cargo bench -p anerf-data --bench ray_sampling -- <prepared dir> [FRAMES] [VIEWS]");
        std::process::exit(2);
    };
    let count = |k: usize, default: usize| {
        args.get(k).map_or(default, |a| {
            a.parse().expect("FRAMES and VIEWS: whole numbers")
        })
    };
    let (frames, views) = (count(1, 4), count(2, 4));
    let subject = PreparedSubject::open(&dir).expect("a prepared subject");
    let ids: Vec<_> = subject.frames.iter().map(|f| f.id).collect();
    let options = SamplerOptions {
        mask_edges: MaskEdges::Robust,
        ..SamplerOptions::default()
    };
    let mut sampler = RaySampler::new(0, options.clone());
    println!(
        "{}: {} frames, {} views at {}×{}",
        dir.display(),
        ids.len(),
        subject.views.len(),
        subject.cameras[0].width,
        subject.cameras[0].height
    );
    // A step reading every image afresh, then with every image kept, as training keeps them.
    let step_ms = |label: &str, sampler: &mut RaySampler, cache: &ImageCache| {
        report_ms(label, REPEATS, || {
            let images = sampler
                .pick_step(&ids, &subject.views, frames, views)
                .expect("enough frames and views");
            sampler
                .sample_step(&subject, None, &images, cache)
                .expect("rays");
        })
    };
    let label = format!("step of {frames} frames × {views} views");
    step_ms(&label, &mut sampler, &ImageCache::none());
    let kept = ImageCache::for_training();
    for &frame in &ids {
        let all = [StepImages {
            frame,
            views: subject.views.clone(),
        }];
        let mut warm = sampler.clone();
        warm.sample_step(&subject, None, &all, &kept).expect("rays");
    }
    let (held, bytes) = kept.held();
    let label = format!("{label}, {held} images kept ({} MB)", bytes >> 20);
    step_ms(&label, &mut sampler, &kept);
    let (frame, view) = (ids[0], subject.views[0]);
    let camera = &subject.cameras[view.0];
    let bounds = subject.frames[0].bounds;
    report_ms("  read the image", REPEATS, || {
        subject.image(frame, view).expect("image");
    });
    report_ms("  read the mask and band", REPEATS, || {
        subject.mask_and_edge(frame, view).expect("mask");
    });
    report_ms("  project the box", REPEATS, || {
        box_mask(camera, &bounds);
    });
    let image = subject.image(frame, view).expect("image");
    let (mask, edge) = subject.mask_and_edge(frame, view).expect("mask");
    let per_image = options.rays / (frames * views).max(1);
    report_ms(&format!("  draw {per_image} rays"), REPEATS, || {
        sampler
            .sample(
                &ImageView {
                    camera,
                    bounds: &bounds,
                    image: (&image).into(),
                    mask: &mask,
                    edge: Some(&edge),
                    background: None,
                },
                per_image,
            )
            .expect("rays");
    });
}
