//! `anerf export`: the skinned glTF of a tiny trained run passes the Khronos validator, reads back through
//! the `gltf` crate with the run's vertex, joint and frame counts, and its skinned pose at a frame —
//! computed here from the glTF data alone — is anerf's reposed mesh of that frame.

mod common;

use std::path::{Path, PathBuf};

use anerf_device::cpu_device;
use anerf_run::{capture_to_gltf, ExportJob, TRAINING_FPS};
use anerf_train::experiment::Experiment;
use common::{quiet, surface, tiny, trained};
use glam::{Mat4, Quat, Vec3};

fn job(out: Option<PathBuf>, level: f32) -> ExportJob {
    ExportJob {
        surface: surface(0.02, level),
        motion: None,
        view: None,
        out,
        overwrite: false,
    }
}

/// The Khronos validator's report of `file` (scripts/gltf/validate.cjs with the package scripts/test.sh
/// installs).
fn validate(file: &Path) -> serde_json::Value {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let modules = root.join("target/npm/node_modules");
    assert!(
        modules.join("gltf-validator").is_dir(),
        "the glTF validator is not installed in {}: run `bash scripts/test.sh`",
        modules.display()
    );
    let out = std::process::Command::new("node")
        .arg(root.join("scripts/gltf/validate.cjs"))
        .arg(file)
        .env("NODE_PATH", &modules)
        .output()
        .expect("node (Node.js) runs the glTF validator");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Global transform of every node at keyframe `k` of animation 0, from the glTF alone.
fn node_globals(doc: &gltf::Document, blob: &[u8], k: usize) -> Vec<Mat4> {
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    let mut local: Vec<(Vec3, Quat)> = nodes
        .iter()
        .map(|n| {
            let (t, r, s) = n.transform().decomposed();
            assert_eq!(s, [1.0; 3]);
            (Vec3::from(t), Quat::from_array(r))
        })
        .collect();
    let animation = doc.animations().next().expect("an animation");
    for channel in animation.channels() {
        let reader = channel.reader(|_| Some(blob));
        let node = channel.target().node().index();
        match reader.read_outputs().unwrap() {
            gltf::animation::util::ReadOutputs::Translations(t) => {
                local[node].0 = Vec3::from(t.clone().nth(k).unwrap())
            }
            gltf::animation::util::ReadOutputs::Rotations(r) => {
                local[node].1 = Quat::from_array(r.into_f32().nth(k).unwrap())
            }
            _ => panic!("unexpected channel"),
        }
    }
    let mut parent = vec![None; nodes.len()];
    for n in &nodes {
        for c in n.children() {
            parent[c.index()] = Some(n.index());
        }
    }
    fn global(i: usize, local: &[(Vec3, Quat)], parent: &[Option<usize>]) -> Mat4 {
        let own = Mat4::from_rotation_translation(local[i].1, local[i].0);
        match parent[i] {
            Some(p) => global(p, local, parent) * own,
            None => own,
        }
    }
    (0..nodes.len())
        .map(|i| global(i, &local, &parent))
        .collect()
}

#[test]
fn the_exported_glb_validates_reads_back_and_skins_as_anerf_reposes() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=4"]);
    let run = trained(&config, dir.path());
    // An iso level the briefly trained density crosses (as the mesh tests use).
    let exported = anerf_run::export(&run, &job(None, 0.0), &quiet()).unwrap();
    assert_eq!(exported.path, run.join("export/avatar.glb"));

    let report = validate(&exported.path);
    let issues = &report["issues"];
    assert_eq!(issues["numErrors"], 0, "validator: {issues:#}");
    eprintln!(
        "validator: {} errors, {} warnings, {} infos",
        issues["numErrors"], issues["numWarnings"], issues["numInfos"]
    );

    let glb = gltf::Gltf::from_slice(&std::fs::read(&exported.path).unwrap()).unwrap();
    let blob = glb.blob.as_deref().expect("a binary chunk");
    let doc = &glb.document;
    let mesh = doc.meshes().next().unwrap();
    let primitive = mesh.primitives().next().unwrap();
    let reader = primitive.reader(|_| Some(blob));
    let positions: Vec<Vec3> = reader.read_positions().unwrap().map(Vec3::from).collect();
    let joints: Vec<[u16; 4]> = reader.read_joints(0).unwrap().into_u16().collect();
    let weights: Vec<[f32; 4]> = reader.read_weights(0).unwrap().into_f32().collect();
    let skin = doc.skins().next().unwrap();
    let exp = Experiment::open(config.clone(), cpu_device(), false).unwrap();
    let k_joints = exp.prepared.skeleton.num_joints();
    assert_eq!(positions.len(), exported.vertices);
    assert_eq!(skin.joints().count(), k_joints);
    let times: Vec<f32> = {
        let sampler = doc.animations().next().unwrap().samplers().next().unwrap();
        gltf::accessor::Iter::<f32>::new(sampler.input(), |_| Some(blob))
            .unwrap()
            .collect()
    };
    assert_eq!(times.len(), exp.train_frames.len());
    assert!((times[times.len() - 1] - (times.len() - 1) as f32 / TRAINING_FPS as f32).abs() < 1e-5);

    // Skinning from the glTF alone at keyframe `k`: joint world matrices times inverse bind matrices.
    let ibms: Vec<Mat4> = skin
        .reader(|_| Some(blob))
        .read_inverse_bind_matrices()
        .unwrap()
        .map(|m| Mat4::from_cols_array_2d(&m))
        .collect();
    let k = 3;
    let globals = node_globals(doc, blob, k);
    let joint_nodes: Vec<usize> = skin.joints().map(|n| n.index()).collect();
    let skinned: Vec<Vec3> = positions
        .iter()
        .zip(joints.iter().zip(&weights))
        .map(|(p, (j, w))| {
            let m = (0..4).fold(Mat4::ZERO, |acc, s| {
                acc + globals[joint_nodes[j[s] as usize]] * ibms[j[s] as usize] * w[s]
            });
            m.transform_point3(*p)
        })
        .collect();
    // anerf's reposed mesh of training frame k with those weights, turned into glTF's Y-up world.
    let frame = exp.prepared.frame(exp.train_frames[k]).unwrap();
    let dense: Vec<f32> = joints
        .iter()
        .zip(&weights)
        .flat_map(|(j, w)| {
            let mut row = vec![0.0; k_joints];
            for s in 0..4 {
                row[j[s] as usize] += w[s];
            }
            row
        })
        .collect();
    let reposed =
        anerf_run::mesh::repose(&positions, &dense, &frame.bones, &frame.pose.global).unwrap();
    let q = capture_to_gltf(&exp);
    let worst = skinned
        .iter()
        .zip(&reposed)
        .map(|(a, b)| (*a - q * *b).length())
        .fold(0.0f32, f32::max);
    eprintln!("glTF skinning vs anerf's reposed mesh: worst {worst:.2e} m");
    assert!(worst < 1e-3, "worst vertex {worst} m apart");
}

#[test]
fn export_refuses_a_model_without_surface_and_keeps_an_existing_file() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=2"]);
    let run = trained(&config, dir.path());
    let out = dir.path().join("avatar.glb");
    let err = anerf_run::export(&run, &job(Some(out.clone()), 1e12), &quiet()).unwrap_err();
    let text = format!("{err:#}");
    assert!(text.contains("no surface at density level"), "{text}");
    assert!(!out.exists(), "nothing is written");
    std::fs::write(&out, b"mine").unwrap();
    let err = anerf_run::export(&run, &job(Some(out.clone()), 0.0), &quiet()).unwrap_err();
    assert!(format!("{err:#}").contains("--overwrite"), "{err:#}");
    assert_eq!(std::fs::read(&out).unwrap(), b"mine");
}

/// Training draws `plots/stage1.svg`: one polyline per curve with a point per logged step, placed by one
/// affine map of (step, value) — the figure's data are the log's.
#[test]
fn a_training_run_draws_its_curves_from_its_log() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=6", "train.log_every=1"]);
    let run = trained(&config, dir.path());
    let svg = std::fs::read_to_string(run.join("plots/stage1.svg")).unwrap();
    let log =
        anerf_train::plots::read_log(&anerf_train::run_dir::RunDir::open(&run).unwrap()).unwrap();
    let lr = anerf_train::plots::series(&log, 1, "psnr");
    assert_eq!(lr.len(), 6);
    let polylines: Vec<Vec<(f64, f64)>> = svg
        .split("<polyline")
        .skip(1)
        .map(|p| {
            let pts = p
                .split("points=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap();
            pts.split_whitespace()
                .map(|xy| {
                    let (x, y) = xy.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect()
        })
        .collect();
    // Panels in order: loss (log y), PSNR (training, validation: none logged), learning rate (log y).
    // The PSNR panel is linear: pixels are an affine map of (step, value), fixed by the lowest and the
    // highest value and by the first and last step.
    let lo = (0..6).min_by(|&i, &j| lr[i].1.total_cmp(&lr[j].1)).unwrap();
    let hi = (0..6).max_by(|&i, &j| lr[i].1.total_cmp(&lr[j].1)).unwrap();
    let psnr = polylines.iter().find(|p| {
        p.len() == 6
            && p.iter().zip(&lr).all(|(q, v)| {
                let y = p[lo].1 + (p[hi].1 - p[lo].1) * (v.1 - lr[lo].1) / (lr[hi].1 - lr[lo].1);
                let x = p[0].0 + (p[5].0 - p[0].0) * (v.0 - lr[0].0) / (lr[5].0 - lr[0].0);
                (q.1 - y).abs() <= 1.0 && (q.0 - x).abs() <= 1.0
            })
    });
    assert!(
        psnr.is_some(),
        "no polyline carries the logged PSNR: {polylines:?}"
    );
    assert!(run.join("plots/stage1.svg").is_file());
}
