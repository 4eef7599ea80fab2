//! Pose and mask noise and backdrops of synthetic subjects (`anerf synth --pose-noise`, `--mask-noise`,
//! `--backdrop`), checked against
//! the noise-free subject of the same spec and seed: the noisy files are self-consistent, the truth is kept,
//! the noise has the size asked for, and nothing else changes.

use std::path::{Path, PathBuf};

use anerf_core::geometry::{
    axis_angle_to_matrix, forward_lbs_points, matrix_to_axis_angle, CanonicalPose, Pose,
};
use anerf_data::formats::read_npy;
use anerf_data::loaders::read_pose_file;
use anerf_data::synthetic::{write_subject, Backdrop, PoseNoise, SyntheticSpec, SyntheticSummary};
use anerf_data::{load_zju_mocap, LoadOptions, Subject};
use glam::{Vec2, Vec3};

mod common;
use common::files_under;

fn same_bytes(a: &Path, b: &Path) -> bool {
    std::fs::read(a).unwrap() == std::fs::read(b).unwrap()
}

/// The tiny subject without noise and with `noisy`'s, written under `dir`, and the noisy one loaded back.
fn exact_and_noisy(
    dir: &Path,
    noisy: &SyntheticSpec,
) -> (SyntheticSummary, SyntheticSummary, Subject) {
    let exact = write_subject(&SyntheticSpec::tiny(), &dir.join("exact")).unwrap();
    let written = write_subject(noisy, &dir.join("noisy")).unwrap();
    let loaded = load_zju_mocap(&dir.join("noisy"), &LoadOptions::default()).unwrap();
    (exact, written, loaded)
}

/// Files of the two subjects that differ, except `splits.json` (it records the spec).
fn differing_files(a: &Path, b: &Path) -> Vec<PathBuf> {
    let files = files_under(a);
    files
        .into_iter()
        .filter(|f| f != Path::new("splits.json"))
        .filter(|f| !b.join(f).is_file() || !same_bytes(&a.join(f), &b.join(f)))
        .collect()
}

/// `R(Rh) · LBS(x) + Th` of every canonical vertex of `subject`'s body (world space, metres).
fn skinned(subject: &Subject, pose: &Pose) -> Vec<Vec3> {
    let body = &subject.body;
    let bones = body
        .skeleton
        .bone_transforms(pose, CanonicalPose::TPose)
        .unwrap();
    let rotation = pose.global.rotation();
    forward_lbs_points(&body.canonical_vertices, body.weights.as_slice(), &bones)
        .unwrap()
        .into_iter()
        .map(|x| rotation * x + pose.global.th)
        .collect()
}

fn read_points(path: &Path) -> Vec<Vec3> {
    read_npy(path)
        .unwrap()
        .to_f32()
        .chunks(3)
        .map(Vec3::from_slice)
        .collect()
}

/// The error rotation `ε` (axis-angle, radians) with `R(noisy) = R(truth) · exp(ε)`.
fn right_error(truth: Vec3, noisy: Vec3) -> Vec3 {
    matrix_to_axis_angle(axis_angle_to_matrix(truth).transpose() * axis_angle_to_matrix(noisy))
}

/// Root mean square of each axis of `samples`.
fn rms_per_axis(samples: &[Vec3]) -> Vec3 {
    let sum: Vec3 = samples.iter().map(|e| *e * *e).sum();
    (sum / samples.len() as f32).powf(0.5)
}

#[test]
fn pose_noise_perturbs_the_training_files_consistently_and_keeps_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let noise = PoseNoise {
        degrees: 3.0,
        cm: 2.0,
    };
    let spec = SyntheticSpec {
        pose_noise: Some(noise),
        ..SyntheticSpec::tiny()
    };
    let (exact, written, loaded) = exact_and_noisy(dir.path(), &spec);
    let root = &written.subject.root;
    let training = spec.training.frames;
    let report = written.pose_noise.as_ref().expect("a pose-noise report");
    assert_eq!(report.true_poses.len(), training);

    let (mut joint_errors, mut rh_errors, mut th_errors) = (Vec::new(), Vec::new(), Vec::new());
    let (mut distance, mut count) = (0.0f64, 0usize);
    for (i, frame) in loaded.frames.iter().enumerate().take(training) {
        // The noisy files are what a fitter's would be: new_vertices is forward LBS of new_params.
        let vertices = read_points(&root.join(format!("new_vertices/{i}.npy")));
        for (v, (a, b)) in vertices
            .iter()
            .zip(skinned(&loaded, &frame.pose))
            .enumerate()
        {
            assert!(a.distance(b) < 1e-5, "frame {i} vertex {v}: {a} vs {b}");
        }
        // true_params holds the noise-free subject's pose, as the report does.
        let truth = read_pose_file(&root.join(format!("true_params/{i}.npy")), 24).unwrap();
        assert_eq!(truth, exact.subject.frames[i].pose, "frame {i}");
        assert_eq!(truth, report.true_poses[i], "frame {i}");
        assert_eq!(
            frame.pose.joint_rotations[0],
            Vec3::ZERO,
            "the root stays zero"
        );
        for (t, n) in truth
            .joint_rotations
            .iter()
            .zip(&frame.pose.joint_rotations)
            .skip(1)
        {
            joint_errors.push(right_error(*t, *n));
        }
        rh_errors.push(right_error(truth.global.rh, frame.pose.global.rh));
        th_errors.push(frame.pose.global.th - truth.global.th);
        for (a, b) in vertices.iter().zip(&exact.posed_vertices[i]) {
            distance += f64::from(a.distance(*b));
            count += 1;
        }
    }
    // n Gaussian samples of σ give n·RMS²/σ² ~ χ²(n). Joints: 6 frames × 23 joints = 138 per axis, χ² sd
    // √276 ≈ 17, so RMS within ±30% of σ lies more than 4 sd inside. Rh and Th: 6 frames × 3 axes = 18
    // pooled samples; RMS/σ outside [0.4, 1.7] has probability below 1e-4.
    let sigma = noise.degrees.to_radians();
    let joints = rms_per_axis(&joint_errors) / sigma;
    assert!(
        joints.cmpgt(Vec3::splat(0.7)).all() && joints.cmplt(Vec3::splat(1.3)).all(),
        "joint error RMS / σ per axis: {joints}"
    );
    let pooled = |e: &[Vec3], sigma: f32| rms_per_axis(e).length() / 3f32.sqrt() / sigma;
    let rh = pooled(&rh_errors, sigma / 3.0);
    let th = pooled(&th_errors, noise.cm / 100.0);
    assert!((0.4..1.7).contains(&rh), "Rh error RMS / σ: {rh}");
    assert!((0.4..1.7).contains(&th), "Th error RMS / σ: {th}");
    let mean = (distance / count as f64) as f32;
    assert!(
        (report.mean_vertex_error - mean).abs() < 1e-6 && mean > 0.01,
        "reported {} m, measured {mean} m",
        report.mean_vertex_error
    );
    println!(
        "3°, 2 cm: joint RMS/σ {joints}, Rh {rh}, Th {th}, mean vertex error {:.2} cm",
        mean * 100.0
    );

    // Only the training frames' parameters and vertices differ; novel poses, images, masks, cameras and
    // body are byte for byte the noise-free subject's, and true_params covers the training frames alone.
    let mut expected: Vec<PathBuf> = (0..training)
        .flat_map(|i| {
            [
                format!("new_params/{i}.npy"),
                format!("new_vertices/{i}.npy"),
            ]
        })
        .map(PathBuf::from)
        .collect();
    expected.sort();
    assert_eq!(differing_files(&exact.subject.root, root), expected);
    let extra: Vec<PathBuf> = files_under(root)
        .into_iter()
        .filter(|f| !exact.subject.root.join(f).is_file())
        .collect();
    let mut true_params: Vec<PathBuf> = (0..training)
        .map(|i| PathBuf::from(format!("true_params/{i}.npy")))
        .collect();
    true_params.sort();
    assert_eq!(extra, true_params);
}

#[test]
fn noise_options_are_checked_and_old_specs_still_parse() {
    let dir = tempfile::tempdir().unwrap();
    let bad_pose = [
        (-1.0, 1.0),
        (f32::NAN, 1.0),
        (20.5, 1.0),
        (1.0, -0.1),
        (1.0, 25.0),
    ];
    for (degrees, cm) in bad_pose {
        let spec = SyntheticSpec {
            pose_noise: Some(PoseNoise { degrees, cm }),
            ..SyntheticSpec::tiny()
        };
        let err = write_subject(&spec, &dir.path().join("bad"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("pose_noise") && err.contains("expected 0 to 20"),
            "{degrees}, {cm}: {err}"
        );
    }
    for px in [-0.5, f32::NAN, f32::INFINITY, 10.5] {
        let spec = SyntheticSpec {
            mask_noise: px,
            ..SyntheticSpec::tiny()
        };
        let err = write_subject(&spec, &dir.path().join("bad"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("mask_noise") && err.contains("expected 0 to 10"),
            "{px}: {err}"
        );
    }
    assert!(!dir.path().join("bad").exists());
    // A spec recorded before the options existed reads as noise-free.
    let mut old = serde_json::to_value(SyntheticSpec::tiny()).unwrap();
    let fields = old.as_object_mut().unwrap();
    fields.remove("pose_noise").unwrap();
    fields.remove("mask_noise").unwrap();
    fields.remove("backdrop").unwrap();
    let parsed: SyntheticSpec = serde_json::from_value(old).unwrap();
    assert_eq!(parsed, SyntheticSpec::tiny());
}

/// The edges between 4-neighbours of different class: unit segments `(a, b)` in pixel coordinates (pixel
/// centres at integers).
fn boundary_segments(mask: &image::GrayImage) -> Vec<(Vec2, Vec2)> {
    let body = |x: u32, y: u32| mask.get_pixel(x, y)[0] > 0;
    let mut segments = Vec::new();
    for y in 0..mask.height() {
        for x in 0..mask.width() {
            let c = Vec2::new(x as f32, y as f32);
            if x + 1 < mask.width() && body(x, y) != body(x + 1, y) {
                segments.push((c + Vec2::new(0.5, -0.5), c + Vec2::new(0.5, 0.5)));
            }
            if y + 1 < mask.height() && body(x, y) != body(x, y + 1) {
                segments.push((c + Vec2::new(-0.5, 0.5), c + Vec2::new(0.5, 0.5)));
            }
        }
    }
    segments
}

/// Euclidean distance (pixels) from `p` to the nearest of `segments`, by brute force.
fn distance_to(p: Vec2, segments: &[(Vec2, Vec2)]) -> f32 {
    segments
        .iter()
        .map(|&(a, b)| {
            let t = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
            p.distance(a + t * (b - a))
        })
        .fold(f32::INFINITY, f32::min)
}

fn read_mask(path: &Path) -> image::GrayImage {
    image::open(path).unwrap().to_luma8()
}

#[test]
fn mask_noise_moves_edges_both_ways_within_its_reach_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let px = 2.5;
    let spec = SyntheticSpec {
        mask_noise: px,
        ..SyntheticSpec::tiny()
    };
    let (exact, written, _) = exact_and_noisy(dir.path(), &spec);
    let (mut added, mut removed, mut both) = (0, 0, 0);
    let mut farthest = 0.0f32;
    for (f, frame) in written.subject.frames.iter().enumerate() {
        for (v, path) in frame.masks.iter().enumerate() {
            let truth = read_mask(&exact.subject.frames[f].masks[v]);
            let noisy = read_mask(path);
            let segments = boundary_segments(&truth);
            let (mut a, mut r) = (0, 0);
            for (x, y, n) in noisy.enumerate_pixels() {
                let t = truth.get_pixel(x, y);
                if t == n {
                    continue;
                }
                let d = distance_to(Vec2::new(x as f32, y as f32), &segments);
                assert!(
                    d < px,
                    "frame {f} view {v}: pixel ({x}, {y}) changed {d} px from the edge"
                );
                farthest = farthest.max(d);
                a += usize::from(n[0] > 0);
                r += usize::from(t[0] > 0);
            }
            let foreground = noisy.pixels().filter(|p| p[0] > 0).count();
            assert_eq!(foreground, written.foreground_pixels[f][v]);
            (added, removed) = (added + a, removed + r);
            both += usize::from(a > 0 && r > 0);
        }
    }
    let masks = written.subject.frames.len() * written.subject.cameras.len();
    println!("{px} px: {added} pixels added, {removed} removed, {both} of {masks} masks both ways, farthest {farthest} px");
    assert!(
        added > 100 && removed > 100,
        "{added} added, {removed} removed"
    );
    assert!(
        both * 4 >= masks * 3,
        "{both} of {masks} masks both dilated and eroded"
    );
    // Images and every other file are the noise-free subject's.
    let differing = differing_files(&exact.subject.root, &written.subject.root);
    assert!(!differing.is_empty());
    assert!(
        differing.iter().all(|f| f.starts_with("mask_cihp")),
        "{differing:?}"
    );
}

fn read_rgb(path: &Path) -> image::RgbImage {
    image::open(path).unwrap().to_rgb8()
}

/// Whether every pixel within `r` of `(x, y)` (a square) has `mask` value `value`.
fn all_around(mask: &image::GrayImage, x: u32, y: u32, r: i64, value: bool) -> bool {
    let (w, h) = (mask.width() as i64, mask.height() as i64);
    (-r..=r).all(|dy| {
        (-r..=r).all(|dx| {
            let (u, v) = (x as i64 + dx, y as i64 + dy);
            !(0..w).contains(&u)
                || !(0..h).contains(&v)
                || (mask.get_pixel(u as u32, v as u32)[0] > 0) == value
        })
    })
}

#[test]
fn a_room_backdrop_changes_only_what_lies_behind_the_body_and_stays_put() {
    let dir = tempfile::tempdir().unwrap();
    // Twice tiny's resolution and JPEG's finest quality, so that the body has pixels beyond the edge's ringing.
    let mut black = SyntheticSpec {
        jpeg_quality: 100,
        ..SyntheticSpec::tiny()
    };
    black.rig.resolution = 128;
    let spec = SyntheticSpec {
        backdrop: Backdrop::Room,
        ..black.clone()
    };
    let exact = write_subject(&black, &dir.path().join("black")).unwrap();
    let written = write_subject(&spec, &dir.path().join("room")).unwrap();
    // Masks and every array are the black subject's; only images differ.
    let differing = differing_files(&exact.subject.root, &written.subject.root);
    assert!(
        differing
            .iter()
            .all(|f| !f.starts_with("mask_cihp") && f.extension().is_some_and(|e| e == "jpg")),
        "{differing:?}"
    );
    let frames = &written.subject.frames;
    for v in 0..written.subject.cameras.len() {
        let (mut inside, mut inside_diff) = (0usize, 0u64);
        let (mut outside, mut outside_sum) = (0usize, 0u64);
        let (mut still, mut still_diff) = (0usize, 0u64);
        for f in 0..frames.len() {
            let mask = read_mask(&frames[f].masks[v]);
            let room = read_rgb(&frames[f].images[v]);
            let black = read_rgb(&exact.subject.frames[f].images[v]);
            let later = (f + 1 < frames.len()).then(|| {
                (
                    read_mask(&frames[f + 1].masks[v]),
                    read_rgb(&frames[f + 1].images[v]),
                )
            });
            for (x, y, p) in room.enumerate_pixels() {
                let sum = |q: &image::Rgb<u8>| q.0.iter().map(|&c| c as u64).sum::<u64>();
                let diff = |q: &image::Rgb<u8>| {
                    p.0.iter()
                        .zip(q.0)
                        .map(|(&a, b)| (a as i64 - b as i64).unsigned_abs())
                        .sum::<u64>()
                };
                if all_around(&mask, x, y, 3, true) {
                    // Inside the body, beyond JPEG's ringing at the edge: the black subject's colours.
                    inside += 1;
                    inside_diff += diff(black.get_pixel(x, y));
                } else if all_around(&mask, x, y, 2, false) {
                    outside += 1;
                    outside_sum += sum(p);
                    // Where the body is away in the next frame too, the same backdrop.
                    if let Some((next_mask, next)) = &later {
                        if all_around(next_mask, x, y, 8, false)
                            && all_around(&mask, x, y, 8, false)
                        {
                            still += 1;
                            still_diff += diff(next.get_pixel(x, y));
                        }
                    }
                }
            }
        }
        let mean = |total: u64, n: usize| total as f64 / (3 * n.max(1)) as f64;
        println!(
            "view {v}: inside {:.2} off, backdrop {:.1} bright, {:.3} change between frames",
            mean(inside_diff, inside),
            mean(outside_sum, outside),
            mean(still_diff, still)
        );
        assert!(
            inside > 100 && outside > 1000 && still > 1000,
            "{inside} {outside} {still}"
        );
        assert!(
            mean(inside_diff, inside) < 3.0,
            "view {v}: the body changed"
        );
        assert!(
            mean(outside_sum, outside) > 40.0,
            "view {v}: the backdrop is dark"
        );
        assert!(
            mean(still_diff, still) < 1.0,
            "view {v}: the backdrop moved"
        );
    }
    // The cameras see different parts of the room.
    let first: Vec<image::RgbImage> = (0..2).map(|v| read_rgb(&frames[0].images[v])).collect();
    assert_ne!(first[0], first[1]);
}
