//! The synthetic writer and the ZJU-MoCap loader built against each other: loading a written subject gives
//! back the cameras, poses, body, vertices and images that were written.

use anerf_data::formats::{images, read_npy};
use anerf_data::synthetic::{write_subject, SyntheticSpec};
use anerf_data::{load_zju_mocap, LoadOptions};

#[test]
fn loading_a_written_subject_gives_back_what_was_written() {
    let dir = tempfile::tempdir().unwrap();
    let written = write_subject(&SyntheticSpec::tiny(), &dir.path().join("subject")).unwrap();
    let loaded = load_zju_mocap(&dir.path().join("subject"), &LoadOptions::default()).unwrap();
    let w = &written.subject;

    assert_eq!(loaded.cameras.len(), w.cameras.len());
    for (a, b) in loaded.cameras.iter().zip(&w.cameras) {
        assert!(
            a.intrinsics.abs_diff_eq(b.intrinsics, 1e-4)
                && a.rotation.abs_diff_eq(b.rotation, 1e-6)
        );
        // T is stored in millimetres as f64 and divided by 1000 on load.
        assert!((a.translation - b.translation).abs().max_element() < 1e-6);
        assert_eq!(a.distortion, b.distortion);
        assert_eq!((a.width, a.height), (b.width, b.height));
    }

    assert_eq!(loaded.frames.len(), w.frames.len());
    for (i, (a, b)) in loaded.frames.iter().zip(&w.frames).enumerate() {
        assert_eq!((a.id, a.file_index), (b.id, b.file_index));
        assert_eq!(a.images, b.images);
        assert_eq!(a.masks, b.masks);
        for (ra, rb) in a.pose.joint_rotations.iter().zip(&b.pose.joint_rotations) {
            assert!((*ra - *rb).abs().max_element() < 1e-6);
        }
        assert!((a.pose.global.rh - b.pose.global.rh).abs().max_element() < 1e-6);
        assert!((a.pose.global.th - b.pose.global.th).abs().max_element() < 1e-6);
        let vertices = read_npy(a.vertices.file().unwrap()).unwrap().to_f32();
        let expected: Vec<f32> = written.posed_vertices[i]
            .iter()
            .flat_map(|v| v.to_array())
            .collect();
        assert_eq!(vertices, expected, "frame {i} vertices");
        for (v, (image, mask)) in a.images.iter().zip(&a.masks).enumerate() {
            let rgb = images::read_rgb(image).unwrap();
            let m = images::read_mask(mask).unwrap();
            assert_eq!(rgb.dimensions(), (w.cameras[v].width, w.cameras[v].height));
            let foreground = m.pixels().filter(|p| p[0] != 0).count();
            assert_eq!(
                foreground, written.foreground_pixels[i][v],
                "frame {i} view {v} mask"
            );
            // The background is black: every bright pixel lies on the mask.
            let outside_bright = rgb
                .pixels()
                .zip(m.pixels())
                .filter(|(c, p)| p[0] == 0 && c.0.iter().any(|x| *x > 0.1))
                .count();
            assert_eq!(outside_bright, 0, "frame {i} view {v}");
        }
    }

    let (a, b) = (&loaded.body, &w.body);
    assert_eq!(a.skeleton.parents(), b.skeleton.parents());
    for (ja, jb) in a
        .skeleton
        .rest_joints()
        .iter()
        .zip(b.skeleton.rest_joints())
    {
        assert!((*ja - *jb).abs().max_element() < 1e-6);
    }
    assert_eq!(a.canonical_vertices, b.canonical_vertices);
    assert_eq!(a.faces, b.faces);
    assert_eq!(a.weights, b.weights);
}
