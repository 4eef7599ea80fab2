//! Ray sampling against the reference's masks and boxes (computed by numpy/OpenCV in
//! `scripts/fixtures/datasets.py`) and its sampling rules.

use anerf_core::geometry::Camera;
use anerf_core::{FrameId, ViewId};
use anerf_data::formats::{self, NdArray};
use anerf_data::prepare::edge_band;
use anerf_data::prepare::{FrameSelection, ImageScale};
use anerf_data::sampler::box_mask;
use anerf_data::{
    draw_step, image_rays, load_zju_mocap, prepare, BackgroundPlate, Backgrounds, ImageCache,
    LoadOptions, MaskEdges, Prefetch, PrepareOptions, PreparedSubject, RaySampler, SamplerOptions,
    StepImages, StepPlan,
};
use anerf_testing::fixture;
use image::{GrayImage, Rgb32FImage};

fn npy(rel: &str) -> NdArray {
    formats::read_npy(&fixture(rel)).unwrap()
}

/// The 377-style fixture prepared at full resolution (no distortion), so pixels match the fixtures.
fn prepared(cache: &std::path::Path) -> PreparedSubject {
    let subject =
        load_zju_mocap(&fixture("zju_mocap/CoreView_377"), &LoadOptions::default()).unwrap();
    let options = PrepareOptions {
        cache_dir: cache.to_path_buf(),
        ratio: ImageScale::FULL,
        frames: FrameSelection {
            start: 0,
            end: Some(2),
            step: 1,
        },
        ..PrepareOptions::default()
    };
    prepare(&subject, &options).unwrap()
}

/// `view`'s camera, image, mask and prepared band in `frame`.
fn image_of(
    p: &PreparedSubject,
    frame: FrameId,
    view: ViewId,
) -> (&Camera, Rgb32FImage, (GrayImage, Vec<bool>)) {
    let image = p.image(frame, view).unwrap();
    (
        &p.cameras[view.0],
        image,
        p.mask_and_edge(frame, view).unwrap(),
    )
}

#[test]
fn edge_band_matches_opencv_erode_and_dilate() {
    let a = npy("opencv/disc_mask.npy");
    let s = a.shape();
    let mask = GrayImage::from_raw(
        s[1] as u32,
        s[0] as u32,
        a.to_f64().iter().map(|&x| x as u8).collect(),
    )
    .unwrap();
    let expected: Vec<bool> = npy("opencv/disc_edge_band.npy")
        .to_f64()
        .iter()
        .map(|&x| x != 0.0)
        .collect();
    assert_eq!(edge_band(&mask), expected);
}

#[test]
fn bound_mask_and_mask_at_box_match_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let cam = &p.cameras[0];
    let bounds = p.frames[0].bounds;
    let expected: Vec<bool> = npy("zju_mocap/reference_rays/bound_mask.npy")
        .to_f64()
        .iter()
        .map(|&x| x != 0.0)
        .collect();
    let ours = box_mask(cam, &bounds);
    let differ = ours.iter().zip(&expected).filter(|(a, b)| a != b).count();
    assert_eq!(
        differ, 0,
        "bound_mask differs from cv2.fillPoly on {differ} pixels"
    );
    let rays = image_rays(cam, &bounds, None, &SamplerOptions::default()).unwrap();
    let at_box = npy("zju_mocap/reference_rays/mask_at_box.npy").to_f64();
    let (near, far) = (
        npy("zju_mocap/reference_rays/near.npy").to_f32(),
        npy("zju_mocap/reference_rays/far.npy").to_f32(),
    );
    let hits: Vec<usize> = rays
        .rays
        .pixels
        .iter()
        .map(|[u, v]| (v * cam.width + u) as usize)
        .collect();
    let expected_hits: Vec<usize> = (0..at_box.len()).filter(|&i| at_box[i] != 0.0).collect();
    assert_eq!(hits, expected_hits);
    for (k, &i) in hits.iter().enumerate() {
        assert!(
            (rays.rays.near[k] - near[i]).abs() < 1e-4 && (rays.rays.far[k] - far[i]).abs() < 1e-4
        );
    }
}

#[test]
fn training_rays_follow_the_reference_scheme() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let (frame, view) = (FrameId(1), ViewId(2));
    let cam = &p.cameras[view.0];
    let bounds = p.frame(frame).unwrap().bounds;
    let img = p.image(frame, view).unwrap();
    let (mask, band) = p.mask_and_edge(frame, view).unwrap();
    let bound = box_mask(cam, &bounds);
    assert!(band.iter().any(|&b| b), "the frame has a mask-edge band");
    let options = SamplerOptions {
        rays: 500,
        ..SamplerOptions::default()
    };
    let mut sampler = RaySampler::new(11, options.clone());
    let rays = sampler
        .sample_prepared(&p, None, frame, &[view], 500)
        .unwrap();
    assert_eq!(rays.len(), 500);
    let mut on_body = 0;
    for k in 0..rays.len() {
        let [u, v] = rays.pixels[k];
        let i = (v * cam.width + u) as usize;
        assert!(
            bound[i] && !band[i],
            "pixel {u},{v} is outside the box projection or on the mask edge"
        );
        assert!(!rays.edge[k], "pixel {u},{v} is marked as on the band");
        assert!(rays.near[k] < rays.far[k]);
        let fg = mask.get_pixel(u, v)[0] != 0;
        on_body += fg as usize;
        assert_eq!(rays.foreground[k], fg, "foreground flag of {u},{v}");
        let expect = if fg { img.get_pixel(u, v).0 } else { [0.0; 3] };
        assert_eq!(rays.colors[k], expect, "target colour of {u},{v}");
        let ray = cam.pixel_ray(u as f32, v as f32, options.convention);
        assert!((rays.directions[k][0] - ray.direction.x).abs() < 1e-6);
    }
    // Half of the first round is drawn on the body; the uniform half adds some more.
    assert!((250..450).contains(&on_body), "{on_body} rays on the body");
}

/// `train` and `robust` draw the band like every pixel, with the mask's colour and label, and mark each
/// ray's membership of the band as the prepared band says; both draw the same rays from the same seed.
#[test]
fn a_trained_band_is_drawn_with_the_masks_labels_and_marked() {
    let dir = tempfile::tempdir().unwrap();
    let (p, frame, view) = (prepared(dir.path()), FrameId(1), ViewId(2));
    let (cam, img, (mask, band)) = image_of(&p, frame, view);
    let draw = |mask_edges| {
        let options = SamplerOptions {
            rays: 4000,
            mask_edges,
            ..SamplerOptions::default()
        };
        RaySampler::new(5, options)
            .sample_prepared(&p, None, frame, &[view], 4000)
            .unwrap()
    };
    let rays = draw(MaskEdges::Train);
    assert_eq!(draw(MaskEdges::Robust), rays);
    let mut on_band = 0;
    for k in 0..rays.len() {
        let [u, v] = rays.pixels[k];
        let in_band = band[(v * cam.width + u) as usize];
        assert_eq!(rays.edge[k], in_band, "band flag of {u},{v}");
        if in_band {
            on_band += 1;
            let fg = mask.get_pixel(u, v)[0] != 0;
            assert_eq!(rays.foreground[k], fg, "foreground flag of {u},{v}");
            let expect = if fg { img.get_pixel(u, v).0 } else { [0.0; 3] };
            assert_eq!(rays.colors[k], expect, "target colour of {u},{v}");
        }
    }
    // The band is a few percent of the box's pixels, drawn by the uniform half of the rays.
    assert!(on_band > 10, "{on_band} of 4000 rays on the band");
}

/// `backdrop` draws no band pixel whose background is unknown; where the camera's background is known a
/// ray's target is the image whatever the mask says, it carries that background, and in the band it has no
/// label (the colours decide there) unless it lies outside the mask and shows its background; without
/// backgrounds it draws `robust`'s rays.
#[test]
fn a_backdrop_band_trains_on_the_image_over_its_background() {
    let dir = tempfile::tempdir().unwrap();
    let (p, frame, view) = (prepared(dir.path()), FrameId(1), ViewId(2));
    let (cam, img, (mask, band)) = image_of(&p, frame, view);
    // The background wherever one of the two frames leaves a pixel uncovered.
    let frames = [FrameId(0), frame];
    let images: Vec<_> = frames.iter().map(|&f| p.image(f, view).unwrap()).collect();
    let masks: Vec<_> = frames.iter().map(|&f| p.mask(f, view).unwrap()).collect();
    let plate = BackgroundPlate::estimate(&images, &masks, 0, 1, 1.0);
    let backgrounds = Backgrounds::new([(view, plate.clone())]);
    let draw = |mask_edges, backgrounds| {
        let options = SamplerOptions {
            rays: 4000,
            mask_edges,
            ..SamplerOptions::default()
        };
        RaySampler::new(5, options)
            .sample_prepared(&p, backgrounds, frame, &[view], 4000)
            .unwrap()
    };
    let robust = draw(MaskEdges::Robust, None);
    let rays = draw(MaskEdges::Backdrop, Some(&backgrounds));
    assert_eq!(rays.backgrounds.len(), rays.len());
    let (mut known_band, mut unknown, mut cleared) = (0, 0, 0);
    for k in 0..rays.len() {
        let [u, v] = rays.pixels[k];
        let i = (v * cam.width + u) as usize;
        let (behind, in_band) = (plate.at(i), band[i]);
        let fg = mask.get_pixel(u, v)[0] != 0;
        let expect = if fg || behind.is_some() {
            img.get_pixel(u, v).0
        } else {
            [0.0; 3]
        };
        assert_eq!(rays.colors[k], expect, "target colour of {u},{v}");
        assert_eq!(
            rays.backgrounds[k],
            behind.unwrap_or([0.0; 3]),
            "background of {u},{v}"
        );
        // A band pixel outside the mask that shows its background (within 0.03 a channel on average)
        // keeps its label 0.
        let clear = !fg
            && behind.is_some_and(|b| {
                let seen = img.get_pixel(u, v).0;
                (0..3).map(|c| (seen[c] - b[c]).abs()).sum::<f32>() / 3.0 < 0.03
            });
        assert_eq!(
            rays.labelled[k],
            !(in_band && behind.is_some()) || clear,
            "label of {u},{v}"
        );
        cleared += usize::from(in_band && clear);
        assert!(
            !(in_band && behind.is_none()),
            "band pixel {u},{v} drawn without a background"
        );
        assert!(!rays.edge[k], "band flag of {u},{v}");
        assert_eq!(rays.foreground[k], fg, "foreground flag of {u},{v}");
        known_band += usize::from(in_band && behind.is_some());
        unknown += usize::from(behind.is_none());
    }
    assert!(
        known_band > 5 && unknown > 5 && cleared > 0 && cleared < known_band,
        "{known_band} band rays over a known background ({cleared} of them showing it), {unknown} over none"
    );
    // `robust` does draw band pixels without a background.
    assert!((0..robust.len()).any(|k| {
        let [u, v] = robust.pixels[k];
        let i = (v * cam.width + u) as usize;
        band[i] && plate.at(i).is_none()
    }));
    // Without backgrounds it is `robust`.
    assert_eq!(draw(MaskEdges::Backdrop, None), robust);
}

#[test]
fn sampling_is_deterministic_and_resumes_from_serialised_state() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let opts = SamplerOptions {
        rays: 64,
        ..SamplerOptions::default()
    };
    let frames = [FrameId(0), FrameId(1)];
    let views: Vec<ViewId> = p.views.clone();
    let run = |sampler: &mut RaySampler, n: usize| {
        (0..n)
            .map(|_| {
                let images = sampler.pick_step(&frames, &views, 2, 2).unwrap();
                sampler
                    .sample_step(&p, None, &images, &ImageCache::none())
                    .unwrap()
            })
            .collect::<Vec<_>>()
    };
    let mut a = RaySampler::new(3, opts.clone());
    let straight = run(&mut a, 6);
    let mut b = RaySampler::new(3, opts.clone());
    let mut resumed = run(&mut b, 3);
    let saved = serde_json::to_string(&b).unwrap();
    let mut c: RaySampler = serde_json::from_str(&saved).unwrap();
    resumed.extend(run(&mut c, 3));
    assert_eq!(straight, resumed);
    let mut d = RaySampler::new(4, opts);
    assert_ne!(run(&mut d, 1)[0], straight[0], "another seed, other rays");
}

#[test]
fn evaluation_ground_truth_blacks_out_background_and_outside_box() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let (frame, view) = (FrameId(0), ViewId(1));
    let cam = &p.cameras[view.0];
    let bounds = p.frame(frame).unwrap().bounds;
    let (img, mask) = (p.image(frame, view).unwrap(), p.mask(frame, view).unwrap());
    let r = image_rays(
        cam,
        &bounds,
        Some((&img, &mask)),
        &SamplerOptions::default(),
    )
    .unwrap();
    let gt = r.ground_truth.unwrap();
    let bound = box_mask(cam, &bounds);
    for (i, (g, (o, m))) in gt.pixels().zip(img.pixels().zip(mask.pixels())).enumerate() {
        let keep = m[0] != 0 && bound[i];
        assert_eq!(g.0, if keep { o.0 } else { [0.0; 3] });
    }
    for (k, [u, v]) in r.rays.pixels.iter().enumerate() {
        assert_eq!(r.rays.colors[k], gt.get_pixel(*u, *v).0);
    }
    assert!(r.rays.len() > 100 && r.rays.len() < (cam.width * cam.height) as usize);
}

/// Several views a step: distinct views of one frame, the first drawn as one view a step draws it (the
/// reference's stream), the rays split evenly in view order, each view's rays leaving its own camera.
#[test]
fn several_views_a_step_draw_distinct_views_of_one_frame_split_evenly() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let frames = [FrameId(0), FrameId(1)];
    let views: Vec<ViewId> = p.views.clone();
    assert!(views.len() >= 3, "the fixture has {} views", views.len());
    let options = SamplerOptions {
        rays: 100,
        ..SamplerOptions::default()
    };
    let (mut one, mut three) = (
        RaySampler::new(7, options.clone()),
        RaySampler::new(7, options.clone()),
    );
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..20 {
        let (f1, v1) = one.pick(&frames, &views, 1).unwrap();
        let (f3, v3) = three.pick(&frames, &views, 3).unwrap();
        assert_eq!(
            (f1, v1[0]),
            (f3, v3[0]),
            "the first view is the one-view stream's"
        );
        let distinct: std::collections::BTreeSet<_> = v3.iter().collect();
        assert_eq!(distinct.len(), 3, "views {v3:?} repeat");
        assert!(v3.iter().all(|v| views.contains(v)));
        seen.extend(v3[1..].iter().copied());
        // Keep the two streams aligned: the three-view pick drew two more numbers.
        let rays = three.sample_prepared(&p, None, f3, &v3, 100).unwrap();
        assert_eq!(rays.len(), 100);
        for (k, range) in [(0, 0..34), (1, 34..67), (2, 67..100)] {
            let centre = p.cameras[v3[k].0].center();
            for i in range {
                let o = glam::Vec3::from(rays.origins[i]);
                assert!(
                    (o - centre).length() < 1e-4,
                    "ray {i} of view {:?} leaves {o}, not its camera at {centre}",
                    v3[k]
                );
            }
        }
        one = three.clone();
    }
    assert_eq!(
        seen.len(),
        views.len(),
        "every view is drawn as a further view"
    );
    assert!(one.pick(&frames, &views, views.len() + 1).is_none());
    assert!(one.pick(&frames, &views, 0).is_none());
}

/// Several frames a step: distinct frames, the first drawn as one frame a step draws it, the step's rays
/// split evenly over the frames (the first taking the remainder) and each frame's share over its views;
/// more frames than the subject has give all of them.
#[test]
fn several_frames_a_step_draw_distinct_frames_and_split_the_rays_evenly() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let frames = [FrameId(0), FrameId(1)];
    let views: Vec<ViewId> = p.views.clone();
    let options = SamplerOptions {
        rays: 101,
        ..SamplerOptions::default()
    };
    let (mut one, mut two) = (
        RaySampler::new(9, options.clone()),
        RaySampler::new(9, options.clone()),
    );
    let mut firsts = std::collections::BTreeSet::new();
    for _ in 0..12 {
        let single = one.pick(&frames, &views, 2).unwrap();
        let images = two.pick_step(&frames, &views, 2, 2).unwrap();
        assert_eq!(
            images[0],
            StepImages {
                frame: single.0,
                views: single.1
            },
            "the first frame is the one-frame stream's"
        );
        assert_eq!(images.len(), 2);
        assert_ne!(images[0].frame, images[1].frame, "frames repeat");
        firsts.insert(images[0].frame);
        let rays = two
            .sample_step(&p, None, &images, &ImageCache::none())
            .unwrap();
        assert_eq!(rays.iter().map(|r| r.len()).collect::<Vec<_>>(), [51, 50]);
        for (step, rays) in images.iter().zip(&rays) {
            // The frame's share, split over its two views: the first view's rays leave its camera.
            let split = rays.len() / 2 + rays.len() % 2;
            for (i, o) in rays.origins.iter().enumerate() {
                let view = step.views[usize::from(i >= split)];
                let centre = p.cameras[view.0].center();
                assert!((glam::Vec3::from(*o) - centre).length() < 1e-4);
            }
        }
        one = two.clone();
    }
    assert_eq!(firsts.len(), 2, "either frame comes first");
    let all = one.pick_step(&frames, &views, 5, 1).unwrap();
    assert_eq!(all.len(), 2, "at most the subject's frames");
    assert!(one.pick_step(&frames, &views, 0, 1).is_none());
    assert!(one.pick_step(&[], &views, 1, 1).is_none());
}

/// Kept images draw the rays that fresh reads draw, under each treatment of the band (whose pools differ, so
/// the cache keys on it); the cache keeps every image drawn within its budget and none beyond it.
#[test]
fn kept_images_draw_the_rays_of_fresh_reads() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let frames = [FrameId(0), FrameId(1)];
    let views: Vec<ViewId> = p.views.clone();
    let kept = ImageCache::for_training();
    let one_byte = ImageCache::new(1);
    let mut drawn = std::collections::HashSet::new();
    for mask_edges in [MaskEdges::Skip, MaskEdges::Train] {
        let options = SamplerOptions {
            rays: 64,
            mask_edges,
            ..SamplerOptions::default()
        };
        let (mut fresh, mut cached, mut small) = (
            RaySampler::new(5, options.clone()),
            RaySampler::new(5, options.clone()),
            RaySampler::new(5, options),
        );
        for step in 0..8 {
            let images = fresh.pick_step(&frames, &views, 2, 2).unwrap();
            assert_eq!(cached.pick_step(&frames, &views, 2, 2).unwrap(), images);
            assert_eq!(small.pick_step(&frames, &views, 2, 2).unwrap(), images);
            for step in &images {
                drawn.extend(step.views.iter().map(|&v| (step.frame, v, mask_edges)));
            }
            let expected = fresh
                .sample_step(&p, None, &images, &ImageCache::none())
                .unwrap();
            let through_cache = cached.sample_step(&p, None, &images, &kept).unwrap();
            assert_eq!(through_cache, expected, "step {step}, {mask_edges:?}");
            let beyond_budget = small.sample_step(&p, None, &images, &one_byte).unwrap();
            assert_eq!(beyond_budget, expected, "step {step}, {mask_edges:?}");
        }
    }
    // Every image drawn, once per treatment of the band.
    let (images, bytes) = kept.held();
    assert_eq!(images, drawn.len());
    assert!(bytes > images * 2 * p.cameras[0].width as usize * p.cameras[0].height as usize);
    assert_eq!(one_byte.held(), (0, 0), "an image is larger than a byte");
}

/// Drawing ahead changes nothing: the steps a [`Prefetch`] returns (through the images it keeps) are the
/// ones `draw_step` draws from each state in turn reading every image afresh, also after the caller's sampler
/// jumps to another state (a resume), and a plan that cannot be drawn is an error.
#[test]
fn prefetched_steps_are_the_sequential_draws() {
    let dir = tempfile::tempdir().unwrap();
    let p = std::sync::Arc::new(prepared(dir.path()));
    let plan = StepPlan {
        frames: vec![FrameId(0), FrameId(1)],
        views: p.views.clone(),
        frames_per_step: 2,
        views_per_step: 2,
        backgrounds: None,
    };
    let options = SamplerOptions {
        rays: 64,
        ..SamplerOptions::default()
    };
    let mut prefetch = Prefetch::new(p.clone(), plan.clone());
    let (mut sampler, mut sequential) = (
        RaySampler::new(3, options.clone()),
        RaySampler::new(3, options.clone()),
    );
    for step in 0..6 {
        if step == 3 {
            // Jump elsewhere: the draw started from the old state must not be used.
            sampler = RaySampler::new(8, options.clone());
            sequential = sampler.clone();
        }
        let ahead = prefetch.next(&sampler).unwrap();
        let direct = draw_step(&p, sequential.clone(), &plan, &ImageCache::none()).unwrap();
        assert_eq!(ahead.images, direct.images, "step {step}");
        assert_eq!(ahead.rays, direct.rays, "step {step}");
        assert_eq!(ahead.sampler, direct.sampler, "step {step}");
        (sampler, sequential) = (ahead.sampler, direct.sampler);
    }
    let impossible = StepPlan {
        views_per_step: p.views.len() + 1,
        ..plan
    };
    let err = Prefetch::new(p.clone(), impossible)
        .next(&sampler)
        .unwrap_err();
    assert!(err.to_string().contains("no step can be drawn"), "{err}");
}

/// `detail_fraction` draws its share of the rays in proportion to the target's gradient magnitude: on an
/// image whose colour is a ramp along `u` (slope `s` in one band of columns, `3s` in another, flat
/// elsewhere), the detail rays fall only where the analytic half central difference `|f(u+1) − f(u−1)|/2`
/// is non-zero, and the steep band's share of them is its share of the summed weights.
#[test]
fn detail_rays_follow_the_targets_gradient() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(dir.path());
    let (frame, view) = (FrameId(1), ViewId(2));
    let cam = &p.cameras[view.0];
    let bounds = p.frame(frame).unwrap().bounds;
    let bound = box_mask(cam, &bounds);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let columns: Vec<usize> = (0..w)
        .filter(|&u| (0..h).any(|v| bound[v * w + u]))
        .collect();
    let (first, last) = (columns[0], *columns.last().unwrap());
    assert!(last - first >= 20, "the box spans {first}..={last}");
    // f(u): 0, then slope s over `shallow`, flat, slope 3s over `steep`, flat.
    let s = 0.01f32;
    let shallow = first + 2..first + 7;
    let steep = first + 11..first + 16;
    let f = |u: isize| -> f32 {
        let rise = |range: &std::ops::Range<usize>, slope: f32| {
            (u.clamp(range.start as isize, range.end as isize) - range.start as isize) as f32
                * slope
        };
        rise(&shallow, s) + rise(&steep, 3.0 * s)
    };
    let weight = |u: usize| {
        let (l, r) = (u.saturating_sub(1), (u + 1).min(w - 1));
        (f(r as isize) - f(l as isize)).abs() / 2.0
    };
    let image = Rgb32FImage::from_fn(w as u32, h as u32, |u, _| image::Rgb([f(u as isize); 3]));
    let mask = GrayImage::from_pixel(w as u32, h as u32, image::Luma([255]));
    let view_of = anerf_data::ImageView {
        camera: cam,
        bounds: &bounds,
        image: (&image).into(),
        mask: &mask,
        edge: None,
        background: None,
    };
    let rays = 4000;
    let options = SamplerOptions {
        rays,
        detail_fraction: 1.0,
        mask_edges: MaskEdges::Train,
        ..SamplerOptions::default()
    };
    let drawn = RaySampler::new(9, options).sample(&view_of, rays).unwrap();
    let in_box = |u: usize| (0..h).filter(|&v| bound[v * w + u]).count() as f32;
    let total: f32 = columns.iter().map(|&u| weight(u) * in_box(u)).sum();
    let steep_weight: f32 = columns
        .iter()
        .filter(|&&u| (steep.start - 1..=steep.end).contains(&u))
        .map(|&u| weight(u) * in_box(u))
        .sum();
    let mut on_steep = 0usize;
    for &[u, _] in &drawn.pixels {
        let u = u as usize;
        assert!(weight(u) > 0.0, "a detail ray at the flat column {u}");
        on_steep += usize::from((steep.start - 1..=steep.end).contains(&u));
    }
    let share = steep_weight / total;
    let sigma = (share * (1.0 - share) / rays as f32).sqrt();
    let drawn_share = on_steep as f32 / rays as f32;
    assert!(
        (drawn_share - share).abs() < 5.0 * sigma,
        "{drawn_share} of the rays on the steep ramp, expected {share} ± {sigma}"
    );
    // The share is the slopes' 3 : 1 up to the box's outline and the ramps' ends.
    assert!(
        (0.6..0.9).contains(&share),
        "the steep ramp's share {share}"
    );
}
