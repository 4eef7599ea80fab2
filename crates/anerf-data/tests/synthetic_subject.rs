//! The tiny synthetic subject on disk: numpy reads every file back as written, forward LBS reproduces the
//! posed vertices, the posed vertices land inside the masks, and the seed fixes every byte.

mod common;

use std::path::Path;

use anerf_data::synthetic::{
    write_subject, ClothingSpec, Lighting, StudioLights, SynthError, SyntheticSpec,
    SyntheticSummary,
};
use common::{array, f64s, files_under, flat, ordered, relative};
use serde_json::{json, Value};

/// What each file of the subject must hold, stated from the summary and the ZJU-MoCap layout.
fn manifest(s: &SyntheticSummary) -> Value {
    let subject = &s.subject;
    let root = &subject.root;
    let cams = &subject.cameras;
    let mut files = vec![common::annots_entry(subject)];
    for (i, frame) in subject.frames.iter().enumerate() {
        assert_eq!(frame.file_index, i);
        files.push(json!({
            "path": format!("new_params/{i}.npy"),
            "kind": "object",
            "expected": ordered(&[
                ("poses", array("<f8", &[1, 72], f64s(flat(&frame.pose.joint_rotations)))),
                ("Rh", array("<f8", &[1, 3], f64s(frame.pose.global.rh.to_array()))),
                ("Th", array("<f8", &[1, 3], f64s(frame.pose.global.th.to_array()))),
                ("shapes", array("<f8", &[1, 10], json!(vec![0.0f64; 10]))),
            ])
        }));
        let verts = &s.posed_vertices[i];
        files.push(json!({"path": relative(root, frame.vertices.file().unwrap()), "kind": "npy", "expected": array("<f4", &[verts.len(), 3], json!(flat(verts)))}));
        for (v, (image, mask)) in frame.images.iter().zip(&frame.masks).enumerate() {
            let (w, h) = (cams[v].width, cams[v].height);
            files.push(
                json!({"path": relative(root, image), "kind": "jpeg", "width": w, "height": h}),
            );
            files.push(json!({"path": relative(root, mask), "kind": "png", "width": w, "height": h, "foreground": s.foreground_pixels[i][v]}));
        }
    }
    files.extend(common::lbs_entries(&subject.body));
    files.extend([
        json!({"path": "splits.json", "kind": "json", "expected": {
            "training_views": s.splits.training_views,
            "test_views": s.splits.test_views,
            "training_frames": s.splits.training_frames,
            "novel_pose_frames": s.splits.novel_pose_frames,
        }}),
        json!({"kind": "lbs", "frames": (0..subject.frames.len()).collect::<Vec<_>>(), "tolerance": 2e-6}),
    ]);
    json!({ "files": files })
}

fn write_tiny(dir: &Path, name: &str, spec: &SyntheticSpec) -> SyntheticSummary {
    let summary = write_subject(spec, &dir.join(name)).unwrap();
    let t = summary.timings;
    println!(
        "{name}: {} vertices, {} faces; body {:.2?}, images {:.2?}, arrays {:.2?}, total {:.2?}",
        summary.subject.body.canonical_vertices.len(),
        summary.subject.body.faces.len(),
        t.body,
        t.images,
        t.arrays,
        t.total
    );
    summary
}

#[test]
fn numpy_reads_the_tiny_subject_back_and_lbs_reproduces_the_vertices() {
    let dir = tempfile::tempdir().unwrap();
    let spec = SyntheticSpec::tiny();
    let summary = write_tiny(dir.path(), "tiny", &spec);
    assert_eq!(summary.subject.cameras.len(), 4);
    assert_eq!(summary.subject.frames.len(), 10);
    assert_eq!(summary.splits.training_views, vec![0, 2]);
    assert_eq!(summary.splits.test_views, vec![1, 3]);
    assert_eq!(
        summary.splits.novel_pose_frames,
        (6..10).collect::<Vec<_>>()
    );
    common::numpy_check(&summary.subject.root, &manifest(&summary));
}

fn read_mask(path: &Path) -> image::GrayImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_luma8()
}

#[test]
fn posed_vertices_project_inside_the_masks_and_the_images_show_the_body() {
    let dir = tempfile::tempdir().unwrap();
    let summary = write_tiny(dir.path(), "tiny", &SyntheticSpec::tiny());
    let mut outside = 0;
    let mut total = 0;
    for (f, frame) in summary.subject.frames.iter().enumerate() {
        for (v, cam) in summary.subject.cameras.iter().enumerate() {
            assert!(
                !cam.distortion.is_identity(),
                "the tiny rig has lens distortion"
            );
            let mask = read_mask(&frame.masks[v]);
            let image = image::open(&frame.images[v]).unwrap().to_rgb8();
            for x in &summary.posed_vertices[f] {
                let p = cam.project_distorted(*x).unwrap().round();
                assert!(
                    p.x >= 0.0 && p.y >= 0.0 && p.x < 64.0 && p.y < 64.0,
                    "vertex {x} leaves view {v}: {p}"
                );
                total += 1;
                if mask.get_pixel(p.x as u32, p.y as u32)[0] == 0 {
                    outside += 1;
                }
            }
            // Background is black (up to JPEG ringing next to the body) and the body is lit.
            let (mut bg, mut bg_sum, mut fg, mut fg_sum) = (0u32, 0u32, 0u32, 0u32);
            for (m, px) in mask.pixels().zip(image.pixels()) {
                let level = px.0.iter().map(|&c| c as u32).sum::<u32>();
                if m[0] == 0 {
                    bg += 1;
                    bg_sum += level;
                } else {
                    fg += 1;
                    fg_sum += level;
                }
            }
            assert!(fg > 100, "view {v} frame {f}: {fg} foreground pixels");
            assert!(
                (bg_sum as f32 / (3 * bg) as f32) < 3.0,
                "background not black in view {v} frame {f}"
            );
            assert!(
                fg_sum as f32 / (3 * fg) as f32 > 30.0,
                "body too dark in view {v} frame {f}"
            );
        }
    }
    println!("{outside} of {total} projected vertices fall outside the mask");
    assert_eq!(outside, 0);
}

#[test]
fn the_seed_fixes_every_byte() {
    let dir = tempfile::tempdir().unwrap();
    let spec = SyntheticSpec::tiny();
    let a = write_tiny(dir.path(), "a", &spec);
    let b = write_tiny(dir.path(), "b", &spec);
    let files = files_under(&a.subject.root);
    assert_eq!(files, files_under(&b.subject.root));
    assert!(files.len() > 90, "{} files", files.len());
    for f in &files {
        let same = std::fs::read(a.subject.root.join(f)).unwrap()
            == std::fs::read(b.subject.root.join(f)).unwrap();
        assert!(
            same,
            "{} differs between two runs with the same seed",
            f.display()
        );
    }
    let other = write_tiny(dir.path(), "c", &SyntheticSpec { seed: 1, ..spec });
    assert_ne!(other.subject.cameras, a.subject.cameras);
    assert_ne!(
        std::fs::read(other.subject.root.join("annots.npy")).unwrap(),
        std::fs::read(a.subject.root.join("annots.npy")).unwrap()
    );
}

#[test]
fn failures_leave_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let existing = dir.path().join("taken");
    std::fs::create_dir(&existing).unwrap();
    assert!(matches!(
        write_subject(&SyntheticSpec::tiny(), &existing),
        Err(SynthError::AlreadyExists(_))
    ));
    let mut bad = SyntheticSpec::tiny();
    bad.supersampling = 0;
    let err = write_subject(&bad, &dir.path().join("bad")).unwrap_err();
    assert!(err.to_string().contains("supersampling"), "{err}");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("taken")]);
}

/// The tiny subject lit by world-fixed lights, with held-out cameras at another height and a garment over
/// the body the files describe.
fn tiny_studio() -> SyntheticSpec {
    let mut lights = StudioLights::three_point();
    lights.shadow_resolution = 256;
    let mut spec = SyntheticSpec::tiny();
    spec.rig.heights = vec![1.2, 0.5];
    spec.rig.height_jitter = 0.05;
    spec.lighting = Lighting::Studio(lights);
    spec.clothing = Some(ClothingSpec::loose());
    spec
}

#[test]
fn a_clothed_studio_subject_describes_the_bare_body_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let spec = tiny_studio();
    let a = write_tiny(dir.path(), "a", &spec);
    let b = write_tiny(dir.path(), "b", &spec);
    for f in files_under(&a.subject.root) {
        assert!(
            std::fs::read(a.subject.root.join(&f)).unwrap()
                == std::fs::read(b.subject.root.join(&f)).unwrap(),
            "{} differs between two runs with the same seed",
            f.display()
        );
    }
    // Training cameras (0, 2) stand at 1.2 m, the held-out ones (1, 3) at 0.5 m.
    for (v, cam) in a.subject.cameras.iter().enumerate() {
        let want = if v % 2 == 0 { 1.2 } else { 0.5 };
        assert!(
            (cam.center().z - want).abs() <= 0.05,
            "camera {v} at {}",
            cam.center()
        );
    }
    // The files describe a body whose own weights pose it exactly: forward LBS of lbs/ gives new_vertices.
    let body = &a.subject.body;
    for (f, frame) in a.subject.frames.iter().enumerate() {
        let bones = body
            .skeleton
            .bone_transforms(&frame.pose, anerf_core::geometry::CanonicalPose::TPose)
            .unwrap();
        let rotation = frame.pose.global.rotation();
        for (v, x) in body.canonical_vertices.iter().enumerate() {
            let p = rotation
                * anerf_core::geometry::forward_lbs_point(*x, body.weights.row(v), &bones).unwrap()
                + frame.pose.global.th;
            assert!(
                p.distance(a.posed_vertices[f][v]) < 1e-4,
                "frame {f} vertex {v}"
            );
        }
    }
    // ... and the images show a garment around it: the described vertices fall inside the masks (all but a
    // few where the diffused weights pose the bare body differently from the garment's own), and the masks
    // hold more pixels than those of the bare body rendered by the same rig.
    let bare = write_tiny(
        dir.path(),
        "bare",
        &SyntheticSpec {
            clothing: None,
            ..spec.clone()
        },
    );
    let (mut clothed_px, mut bare_px, mut outside, mut total) = (0, 0, 0, 0);
    for (f, frame) in a.subject.frames.iter().enumerate() {
        for (v, cam) in a.subject.cameras.iter().enumerate() {
            let mask = read_mask(&frame.masks[v]);
            for x in &a.posed_vertices[f] {
                let p = cam.project_distorted(*x).unwrap().round();
                outside += (mask.get_pixel(p.x as u32, p.y as u32)[0] == 0) as usize;
                total += 1;
            }
            clothed_px += a.foreground_pixels[f][v];
            bare_px += bare.foreground_pixels[f][v];
        }
    }
    assert!(
        outside * 100 < total,
        "{outside} of {total} described vertices outside the masks"
    );
    assert!(
        clothed_px as f32 > 1.03 * bare_px as f32,
        "{clothed_px} vs {bare_px}"
    );
    // The given weights are diffused: on average a vertex's largest weight is smaller than the rendered
    // surface's (which the bare subject's files hold).
    let mean_max = |w: &anerf_data::SkinningWeights| {
        (0..w.num_vertices())
            .map(|v| w.row(v).iter().copied().fold(0.0f32, f32::max))
            .sum::<f32>()
            / w.num_vertices() as f32
    };
    let (given, own) = (
        mean_max(&body.weights),
        mean_max(&bare.subject.body.weights),
    );
    assert!(given < own - 0.1, "{given} vs {own}");
}
