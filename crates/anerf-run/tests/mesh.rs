//! Meshes: the canonical mesh skinned with the canonical blend-weight field lands on the posed body, and
//! `anerf mesh` writes every kind of mesh.

mod common;

use anerf_core::geometry::skinning::points_tensor;
use anerf_core::model::AnimatableNerf;
use anerf_core::tensor::to_host;
use anerf_core::FrameId;
use anerf_data::synthetic::{write_subject, SyntheticSpec};
use anerf_device::cpu_device;
use anerf_run::mesh::{repose, MeshJob};
use anerf_train::experiment::Experiment;
use common::tiny;

/// With the residual off, `w^can` is the body model's weights read from the canonical volume (nearest
/// surface point, trilinear between 2.5 cm nodes); reposing the synthetic subject's canonical vertices with
/// it must reproduce the stored posed vertices up to that interpolation.
#[test]
fn reposing_the_canonical_mesh_reproduces_the_posed_synthetic_body() {
    let dir = tempfile::tempdir().unwrap();
    let summary = write_subject(&SyntheticSpec::tiny(), &dir.path().join("subject")).unwrap();
    let config = tiny(dir.path(), &["model.neural_blend_weights=false"]);
    let device = cpu_device();
    let exp = Experiment::open(config.clone(), device.clone(), false).unwrap();
    let model = AnimatableNerf::new(&config.model, exp.model_sizes(), &device);
    let vertices = exp.prepared.canonical.vertices.clone();
    let weights =
        to_host(model.canonical_weights(points_tensor(&vertices, &device), exp.canonical()));
    let mut errors = Vec::new();
    for f in [0usize, 3, 8] {
        let frame = exp.prepared.frame(FrameId(f)).unwrap();
        let posed = repose(&vertices, &weights, &frame.bones, &frame.pose.global).unwrap();
        for (p, q) in posed.iter().zip(&summary.posed_vertices[f]) {
            errors.push((*p - *q).length());
        }
    }
    errors.sort_by(f32::total_cmp);
    let median = errors[errors.len() / 2];
    let p95 = errors[errors.len() * 95 / 100];
    eprintln!(
        "reposing error: median {median:.5} m, 95th percentile {p95:.5} m, max {:.5} m",
        errors.last().unwrap()
    );
    let max = *errors.last().unwrap();
    assert!(
        median < 0.001 && p95 < 0.005 && max < 0.02,
        "median {median} m, 95th {p95} m, max {max} m"
    );

    // The exact body weights reproduce the posed vertices to float precision: the bound above is the
    // volume's interpolation, not the reposing.
    let exact = exp.prepared.canonical.weights.as_slice();
    let frame = exp.prepared.frame(FrameId(3)).unwrap();
    let posed = repose(&vertices, exact, &frame.bones, &frame.pose.global).unwrap();
    let worst = posed
        .iter()
        .zip(&summary.posed_vertices[3])
        .map(|(p, q)| (*p - *q).length())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "{worst}");
}

/// Vertex and face counts from a PLY header.
fn ply_counts(path: &std::path::Path) -> (usize, usize) {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes.windows(10).position(|w| w == b"end_header").unwrap();
    let header = String::from_utf8_lossy(&bytes[..end]).into_owned();
    let count = |element: &str| -> usize {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {element} ")))
            .unwrap()
            .parse()
            .unwrap()
    };
    (count("vertex"), count("face"))
}

/// `anerf mesh` end to end on a briefly trained run, at an iso level the untrained density crosses: the
/// canonical mesh (with colours and weights), its reposed copy, and the reference's carved posed mesh.
#[test]
fn the_mesh_command_writes_canonical_reposed_and_posed_meshes() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=4"]);
    let run = common::trained(&config, dir.path());
    let job = MeshJob {
        voxel: 0.02,
        level: 0.0,
        smooth: 2,
        frames: vec![3],
        posed_frames: vec![3],
        carve: true,
    };
    let canonical = anerf_run::mesh(&run, &job, &common::quiet())
        .unwrap()
        .canonical
        .ply;
    let meshes = run.join("meshes");
    assert_eq!(canonical, meshes.join("canonical.ply"));
    let (v, f) = ply_counts(&canonical);
    assert!(v > 0 && f > 0, "{v} vertices, {f} faces");
    // Reposing moves vertices and keeps the faces.
    assert_eq!(ply_counts(&meshes.join("frame_000003.ply")), (v, f));
    let (pv, pf) = ply_counts(&meshes.join("posed_frame_000003.ply"));
    assert!(pv > 0 && pf > 0, "{pv} vertices, {pf} faces");
    for name in ["canonical", "frame_000003", "posed_frame_000003"] {
        assert!(meshes.join(format!("{name}.obj")).is_file(), "{name}.obj");
    }
}
