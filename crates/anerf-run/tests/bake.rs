//! `anerf bake` on the tiny trained run: the avatar is written within its budget, fitting it brings the
//! rendered training views closer to the images than the avatar it started from, the paper's protocol
//! evaluates it on every split (novel poses without a stage-2 field), it exports as PLY files, and the job
//! keeps an existing bake and refuses a run without a surface.

mod common;

use anerf_eval::report::EvalSplit;
use anerf_run::bake::{bake, export_splats, BakeJob, BakedAvatar, SplatExportJob};
use anerf_run::Avatar;
use common::{quiet, surface, tiny, trained};

fn job(iterations: usize, level: f32) -> BakeJob {
    BakeJob {
        surface: surface(0.02, level),
        budget: 3_000,
        sh_degree: 1,
        iterations,
        overwrite: true,
    }
}

#[test]
fn a_baked_avatar_fits_the_training_views_and_evaluates_on_every_split() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained(&tiny(dir.path(), &[]), dir.path());
    let psnr = |iterations: usize| {
        let baked = bake(&run, &job(iterations, 0.0), &quiet()).unwrap();
        let avatar = BakedAvatar::load(&baked.dir).unwrap();
        assert_eq!(avatar.info, baked.info);
        assert_eq!(avatar.means.len(), avatar.info.gaussians);
        assert!(avatar.info.gaussians > 0 && avatar.info.gaussians <= 3_000);
        for w in &avatar.skin_weights {
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{w:?}");
        }
        anerf_run::eval(&run, EvalSplit::TrainingView, Avatar::Baked, &quiet())
            .unwrap()
            .summary
            .psnr
    };
    let start = psnr(1);
    let fitted = psnr(150);
    assert!(
        fitted > start + 1.0,
        "fitting should bring the training views closer: {start:.2} dB -> {fitted:.2} dB"
    );
    // Novel poses need no stage-2 field: the Gaussians carry their canonical skin.
    let novel = anerf_run::eval(&run, EvalSplit::NovelPose, Avatar::Baked, &quiet()).unwrap();
    assert!(
        novel.dir.starts_with(run.join("baked")),
        "{}",
        novel.dir.display()
    );
    assert!(novel.summary.psnr.is_finite() && novel.summary.images > 0);
    // The mesh the glb holds, scored the same way; each form writes the files the NeRF's evaluation does.
    let surface = anerf_run::Surface {
        voxel: 0.02,
        level: 0.0,
        smooth: 0,
    };
    let forms = [Avatar::Nerf, Avatar::Baked, Avatar::Mesh(surface)];
    let listings: Vec<Vec<String>> = forms
        .iter()
        .map(|&avatar| {
            let e = anerf_run::eval(&run, EvalSplit::TrainingView, avatar, &quiet()).unwrap();
            assert!(e.summary.psnr.is_finite(), "{avatar:?}: {:?}", e.summary);
            files_under(&e.dir)
        })
        .collect();
    assert!(listings[0].iter().any(|f| f.ends_with("_pred.png")));
    assert_eq!(
        listings[1], listings[0],
        "the baked avatar's evaluation files"
    );
    assert_eq!(listings[2], listings[0], "the mesh's evaluation files");
    assert!(run.join("meshes/eval/training-view/summary.json").is_file());

    // The PLY export: the canonical Gaussians, their skin, one posed file per training frame.
    let ply = SplatExportJob {
        motion: None,
        view: None,
        out: None,
        overwrite: false,
    };
    let exported = export_splats(&run, &ply, &quiet()).unwrap();
    let header = std::fs::read(exported.dir.join("avatar.ply")).unwrap();
    let count = format!("element vertex {}\n", exported.gaussians);
    assert!(header.windows(count.len()).any(|w| w == count.as_bytes()));
    let skin: serde_json::Value =
        serde_json::from_slice(&std::fs::read(exported.dir.join("skin.json")).unwrap()).unwrap();
    assert_eq!(skin["joints"].as_array().unwrap().len(), exported.gaussians);
    assert_eq!(exported.frames, 6, "the tiny subject's training frames");
    // motion.json skins the canonical Gaussians on the GPU: the blend of a Gaussian's four joint matrices
    // carries its canonical mean to where the posed file of that frame has it.
    let motion: serde_json::Value =
        serde_json::from_slice(&std::fs::read(exported.dir.join("motion.json")).unwrap()).unwrap();
    assert_eq!(motion["frames"].as_array().unwrap().len(), 6);
    assert_eq!(
        motion["cameras"].as_array().unwrap().len(),
        4,
        "the tiny subject's cameras"
    );
    let avatar = BakedAvatar::load(&run.join("baked")).unwrap();
    let posed = ply_means(&exported.dir.join("frames/frame_000005.ply"));
    assert_eq!(posed.len(), exported.gaussians);
    let matrices = &motion["frames"][5];
    for i in (0..exported.gaussians).step_by(97) {
        let mut at = [0.0f64; 3];
        for (&j, &w) in avatar.skin_joints[i].iter().zip(&avatar.skin_weights[i]) {
            let m: Vec<f64> = floats(&matrices[j as usize]);
            let x = avatar.means[i].map(f64::from);
            for (r, a) in at.iter_mut().enumerate() {
                // Column-major: element (r, c) at 4·c + r.
                *a += w as f64 * (m[r] * x[0] + m[4 + r] * x[1] + m[8 + r] * x[2] + m[12 + r]);
            }
        }
        for r in 0..3 {
            assert!(
                (at[r] - posed[i][r] as f64).abs() < 1e-4,
                "Gaussian {i}: {at:?} vs {:?}",
                posed[i]
            );
        }
    }
    let err = format!("{:#}", export_splats(&run, &ply, &quiet()).unwrap_err());
    assert!(err.contains("--overwrite"), "{err}");

    let kept = BakeJob {
        overwrite: false,
        ..job(1, 0.0)
    };
    let err = format!("{:#}", bake(&run, &kept, &quiet()).unwrap_err());
    assert!(err.contains("--overwrite"), "{err}");
    let err = format!("{:#}", bake(&run, &job(1, 1e12), &quiet()).unwrap_err());
    assert!(err.contains("cannot be baked"), "{err}");
    let huge = BakeJob {
        budget: usize::MAX / 2,
        ..job(1, 0.0)
    };
    let err = format!("{:#}", bake(&run, &huge, &quiet()).unwrap_err());
    assert!(err.contains("--budget") && err.contains("memory"), "{err}");
    // The refused bakes left the avatar in place.
    assert!(BakedAvatar::load(&run.join("baked")).is_ok());
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// The first three properties (x, y, z) of every row of a binary little-endian PLY of float properties.
fn ply_means(path: &std::path::Path) -> Vec<[f32; 3]> {
    let bytes = std::fs::read(path).unwrap();
    let end = b"end_header\n";
    let body = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let header = std::str::from_utf8(&bytes[..body]).unwrap();
    assert!(
        header.contains("format binary_little_endian 1.0"),
        "{header}"
    );
    let properties = header
        .lines()
        .filter(|l| l.starts_with("property float "))
        .count();
    bytes[body..]
        .chunks_exact(4 * properties)
        .map(|row| {
            let f = |k: usize| f32::from_le_bytes(row[4 * k..4 * k + 4].try_into().unwrap());
            [f(0), f(1), f(2)]
        })
        .collect()
}

/// The files under `dir`, relative and sorted.
fn files_under(dir: &std::path::Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push(path.strip_prefix(dir).unwrap().display().to_string());
            }
        }
    }
    out.sort();
    out
}
