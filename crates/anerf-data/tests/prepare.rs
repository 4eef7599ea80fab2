//! Preparation against independent references: undistortion and resizing against OpenCV, blend-weight
//! volumes against brute-force nearest-point search, and the cache's reuse and rebuild rules.

mod common;

use anerf_core::geometry::Distortion;
use anerf_core::{FrameId, ViewId};
use anerf_data::formats::{self, NdArray};
use anerf_data::prepare::nearest::MeshIndex;
use anerf_data::prepare::resize::{resize_area, resize_nearest};
use anerf_data::prepare::undistort::UndistortMap;
use anerf_data::prepare::{compute_volume, FrameSelection, ImageScale, NearestMethod, VolumeGrid};
use anerf_data::{load_zju_mocap, prepare, LoadOptions, PrepareOptions, SkinningWeights};
use anerf_testing::{fixture, floats, json};
use glam::{Mat3, Vec3};
use image::{GrayImage, Rgb32FImage};
use rand::{Rng, SeedableRng};

fn npy(rel: &str) -> NdArray {
    formats::read_npy(&fixture(rel)).unwrap()
}

fn rgb(a: &NdArray) -> Rgb32FImage {
    let s = a.shape();
    Rgb32FImage::from_raw(s[1] as u32, s[0] as u32, a.to_f32()).unwrap()
}

fn gray(a: &NdArray) -> GrayImage {
    let s = a.shape();
    GrayImage::from_raw(
        s[1] as u32,
        s[0] as u32,
        a.to_f64().iter().map(|&x| x as u8).collect(),
    )
    .unwrap()
}

fn differing(a: &GrayImage, b: &GrayImage) -> usize {
    assert_eq!(a.dimensions(), b.dimensions());
    a.pixels().zip(b.pixels()).filter(|(x, y)| x != y).count()
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn undistortion_matches_opencv() {
    let index = json("opencv/index.json");
    let (w, h) = (
        index["width"].as_u64().unwrap() as u32,
        index["height"].as_u64().unwrap() as u32,
    );
    let smooth = rgb(&npy("opencv/smooth.npy"));
    let disc = gray(&npy("opencv/disc_mask.npy"));
    for case in index["undistort"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let k = floats(&case["K"]);
        let k = Mat3::from_cols_slice(&k.iter().map(|&x| x as f32).collect::<Vec<_>>()).transpose();
        let d = floats(&case["D"]);
        let map = UndistortMap::new(k, &Distortion(std::array::from_fn(|i| d[i] as f32)), w, h);
        let (mx, my) = (
            npy(&format!("opencv/{name}_mapx.npy")).to_f32(),
            npy(&format!("opencv/{name}_mapy.npy")).to_f32(),
        );
        let ours_x: Vec<f32> = map.source.iter().map(|s| s[0]).collect();
        let ours_y: Vec<f32> = map.source.iter().map(|s| s[1]).collect();
        let px = max_diff(&ours_x, &mx).max(max_diff(&ours_y, &my));
        println!("{name}: map max error {px:e} px");
        assert!(
            px < 1e-3,
            "{name}: map differs from cv2.initUndistortRectifyMap by {px} px"
        );
        let img = map.remap_rgb(&smooth);
        let expected = npy(&format!("opencv/{name}_image.npy")).to_f32();
        let v = max_diff(img.as_raw(), &expected);
        println!("{name}: image max error {v:e}");
        assert!(v < 1e-3, "{name}: image differs from cv2.undistort by {v}");
        let m = map.remap_nearest(&disc);
        let expected = gray(&npy(&format!("opencv/{name}_mask.npy")));
        let differ = differing(&m, &expected);
        assert_eq!(
            differ, 0,
            "{name}: mask differs from cv2.remap(INTER_NEAREST) on {differ} pixels"
        );
    }
}

#[test]
fn resizing_matches_opencv_area_and_nearest() {
    let index = json("opencv/index.json");
    let img = rgb(&npy("opencv/noise.npy"));
    let mask = gray(&npy("opencv/noise_mask.npy"));
    for case in index["resize"].as_array().unwrap() {
        let tag = case["tag"].as_str().unwrap();
        let (w, h) = (
            case["width"].as_u64().unwrap() as u32,
            case["height"].as_u64().unwrap() as u32,
        );
        let ratio = ImageScale::try_from(case["ratio"].as_f64().unwrap() as f32).unwrap();
        assert_eq!(
            (
                anerf_data::prepare::resize::scaled_size(img.width(), ratio),
                anerf_data::prepare::resize::scaled_size(img.height(), ratio)
            ),
            (w, h),
            "{tag}: output size"
        );
        let ours = resize_area(&img, w, h);
        let v = max_diff(
            ours.as_raw(),
            &npy(&format!("opencv/area_{tag}.npy")).to_f32(),
        );
        println!("ratio {tag}: INTER_AREA max error {v:e}");
        assert!(v < 1e-3, "ratio {tag}: INTER_AREA differs by {v}");
        let near = resize_nearest(&mask, w, h);
        let expected = gray(&npy(&format!("opencv/nearest_{tag}.npy")));
        let differ = differing(&near, &expected);
        assert_eq!(
            differ, 0,
            "ratio {tag}: INTER_NEAREST differs on {differ} pixels"
        );
    }
}

/// The body of the fixtures: canonical vertices, faces, weights.
fn tiny_body() -> (Vec<Vec3>, Vec<[u32; 3]>, SkinningWeights) {
    let m = formats::npz::read_npz_arrays(&fixture("body_model/tiny_body.npz")).unwrap();
    let v: Vec<Vec3> = m["v_template"]
        .to_f32()
        .chunks(3)
        .map(Vec3::from_slice)
        .collect();
    let f: Vec<[u32; 3]> = m["f"]
        .to_i64()
        .unwrap()
        .chunks(3)
        .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
        .collect();
    let k = m["weights"].shape()[1];
    (
        v,
        f,
        SkinningWeights::new(m["weights"].to_f32(), k).unwrap(),
    )
}

/// Distance from `p` to triangle `abc` computed independently of the library: the in-plane projection
/// when it falls inside (same-side tests), else the nearest of the three edge segments.
fn brute_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (f32, [f32; 3]) {
    let n = (b - a).cross(c - a).normalize();
    let q = p - n * n.dot(p - a);
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|&(s, e)| (e - s).cross(q - s).dot(n) >= 0.0);
    if inside {
        let area = (b - a).cross(c - a).dot(n);
        let wa = (b - q).cross(c - q).dot(n) / area;
        let wb = (c - q).cross(a - q).dot(n) / area;
        return ((p - q).length(), [wa, wb, 1.0 - wa - wb]);
    }
    let seg = |s: Vec3, e: Vec3| {
        let t = ((p - s).dot(e - s) / (e - s).length_squared()).clamp(0.0, 1.0);
        ((s + (e - s) * t - p).length(), t)
    };
    let (dab, tab) = seg(a, b);
    let (dbc, tbc) = seg(b, c);
    let (dca, tca) = seg(c, a);
    if dab <= dbc && dab <= dca {
        (dab, [1.0 - tab, tab, 0.0])
    } else if dbc <= dca {
        (dbc, [0.0, 1.0 - tbc, tbc])
    } else {
        (dca, [tca, 0.0, 1.0 - tca])
    }
}

/// Brute force over all faces: distance and interpolated weights at `p`, plus the runner-up distance on a
/// face sharing no vertex with the best one (to skip genuine ties).
fn brute_surface(p: Vec3, v: &[Vec3], f: &[[u32; 3]], w: &SkinningWeights) -> (f32, Vec<f32>, f32) {
    let mut all: Vec<(f32, usize, [f32; 3])> = f
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let (d, b) = brute_distance(p, v[t[0] as usize], v[t[1] as usize], v[t[2] as usize]);
            (d, i, b)
        })
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (d, i, b) = all[0];
    let mut weights = vec![0.0; w.num_joints()];
    for (bc, vi) in b.iter().zip(f[i]) {
        for (o, x) in weights.iter_mut().zip(w.row(vi as usize)) {
            *o += bc * x;
        }
    }
    let runner = all
        .iter()
        .find(|x| f[x.1].iter().all(|vi| !f[i].contains(vi)))
        .map_or(f32::MAX, |x| x.0);
    (d, weights, runner)
}

/// A random point in a box around the tiny body (metres), inside and outside it.
fn point_near_body(rng: &mut impl Rng) -> Vec3 {
    Vec3::new(
        rng.random_range(-0.6..0.6),
        rng.random_range(-0.3..1.0),
        rng.random_range(-0.4..0.4),
    )
}

#[test]
fn volumes_match_brute_force_nearest_surface_and_vertex() {
    let (v, f, w) = tiny_body();
    let index = MeshIndex::triangles(&v, &f);
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut ties = 0;
    for _ in 0..2000 {
        let p = point_near_body(&mut rng);
        let c = index.closest(p).unwrap();
        let (d, weights, runner) = brute_surface(p, &v, &f, &w);
        assert!((c.distance - d).abs() < 1e-5, "{p}: {} vs {d}", c.distance);
        if runner - d < 1e-4 {
            ties += 1;
            continue;
        }
        let mut ours = vec![0.0; w.num_joints()];
        for (b, vi) in c.barycentric.iter().zip(f[c.index]) {
            for (o, x) in ours.iter_mut().zip(w.row(vi as usize)) {
                *o += b * x;
            }
        }
        assert!(
            max_diff(&ours, &weights) < 1e-4,
            "{p}: {ours:?} vs {weights:?}"
        );
    }
    assert!(ties < 20, "{ties} near-ties");
    // Whole volumes: every node against brute force, both methods.
    let grid = VolumeGrid::default();
    let vol = compute_volume(&v, &f, &w, NearestMethod::Surface, grid);
    let k = w.num_joints();
    assert_eq!(vol.num_joints, k);
    let b = anerf_core::geometry::Aabb::from_points(v.iter().copied())
        .unwrap()
        .padded(0.05);
    assert!(
        (vol.bounds.min - b.min).length() < 1e-6
            && vol.bounds.max.cmpge(b.max - Vec3::splat(1e-5)).all()
    );
    assert!(vol.bounds.max.cmplt(b.max + Vec3::splat(0.025)).all());
    let vv = compute_volume(&v, &f, &w, NearestMethod::Vertex, grid);
    assert_eq!(vv.dims, vol.dims);
    let mut checked = 0;
    for i in (0..vol.dims[0]).step_by(3) {
        for j in (0..vol.dims[1]).step_by(3) {
            for l in 0..vol.dims[2] {
                let p = vol.node_position(i, j, l);
                let expect_p = vol.bounds.min + Vec3::new(i as f32, j as f32, l as f32) * 0.025;
                assert!(
                    (p - expect_p).length() < 1e-5,
                    "nodes are exactly 0.025 m apart"
                );
                let at = ((i * vol.dims[1] + j) * vol.dims[2] + l) * (k + 1);
                let node = &vol.data[at..at + k + 1];
                let (d, weights, runner) = brute_surface(p, &v, &f, &w);
                assert!((node[k] - d).abs() < 1e-5);
                if runner - d > 1e-4 {
                    assert!(max_diff(&node[..k], &weights) < 1e-4);
                }
                let (vi, vd) = v
                    .iter()
                    .enumerate()
                    .map(|(n, x)| (n, x.distance(p)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .unwrap();
                let vnode = &vv.data[at..at + k + 1];
                assert!((vnode[k] - vd).abs() < 1e-5);
                assert!(
                    max_diff(&vnode[..k], w.row(vi)) < 1e-6
                        || (v
                            .iter()
                            .filter(|x| (x.distance(p) - vd).abs() < 1e-6)
                            .count()
                            > 1)
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 200, "{checked}");
}

#[test]
fn a_bounded_search_agrees_with_the_full_one_and_finds_nothing_beyond_its_bound() {
    // The volumes bound each node's search by its neighbour's nearest face; a bound at or above the true
    // distance must give the full search's face, point and distance, and one below it nothing.
    let (v, f, _) = tiny_body();
    let index = MeshIndex::triangles(&v, &f);
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    for _ in 0..500 {
        let p = point_near_body(&mut rng);
        let full = index.closest(p).unwrap();
        // An arbitrary face's distance is a valid bound, as is the exact one.
        let other = index.distance_to(rng.random_range(0..f.len()), p);
        assert!(other >= full.distance);
        for bound in [other, full.distance] {
            assert_eq!(
                index.closest_within(p, bound),
                Some(full),
                "{p} within {bound}"
            );
        }
        if full.distance > 1e-2 {
            assert_eq!(index.closest_within(p, full.distance * 0.999), None, "{p}");
        }
    }
}

/// A frame's posed world vertices, the same in pose space, and the pose-space box ± 0.05 m.
fn frame_vertices(
    subject: &anerf_data::Subject,
    f: usize,
) -> (Vec<Vec3>, Vec<Vec3>, anerf_core::geometry::Aabb) {
    let world: Vec<Vec3> = formats::read_npy(subject.frames[f].vertices.file().unwrap())
        .unwrap()
        .to_f32()
        .chunks(3)
        .map(Vec3::from_slice)
        .collect();
    let global = subject.frames[f].pose.global;
    let pose: Vec<Vec3> = world.iter().map(|&x| global.world_to_pose(x)).collect();
    let b = anerf_core::geometry::Aabb::from_points(pose.iter().copied())
        .unwrap()
        .padded(0.05);
    (world, pose, b)
}

fn options(cache: &std::path::Path) -> PrepareOptions {
    PrepareOptions {
        cache_dir: cache.to_path_buf(),
        ..PrepareOptions::default()
    }
}

#[test]
fn prepare_writes_a_reusable_cache_and_rebuilds_on_change() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("CoreView_313");
    common::copy_tree(&fixture("zju_mocap/CoreView_313"), &data);
    let load = LoadOptions {
        body_model: Some(fixture("body_model/tiny_body.npz")),
        ..Default::default()
    };
    let subject = load_zju_mocap(&data, &load).unwrap();
    let cache = dir.path().join("cache");
    let p = prepare(&subject, &options(&cache)).unwrap();
    assert!(p
        .dir
        .starts_with(cache.join(anerf_data::prepare::cache::CACHE_VERSION)));
    assert_eq!(p.frames.len(), 3);
    assert_eq!(p.views.len(), 3);
    for (raw, cam) in subject.cameras.iter().zip(&p.cameras) {
        assert!(cam.distortion.is_identity());
        assert_eq!((cam.width, cam.height), (24, 20));
        assert!((cam.intrinsics.x_axis.x - 0.5 * raw.intrinsics.x_axis.x).abs() < 1e-5);
        assert!((cam.intrinsics.z_axis.y - 0.5 * raw.intrinsics.z_axis.y).abs() < 1e-5);
    }
    // Frame 2 of camera 1 against the reference loader's OpenCV pipeline (JPEG decoders and uint8
    // rounding differ by a level or two).
    let ours = p.image(FrameId(2), ViewId(1)).unwrap();
    let theirs = npy("zju_mocap/reference_pipeline/image_f2_c1.npy").to_f32();
    let diffs: Vec<f32> = ours
        .as_raw()
        .iter()
        .zip(&theirs)
        .map(|(a, b)| (a - b).abs())
        .collect();
    let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
    let max = diffs.iter().fold(0.0f32, |m, d| m.max(*d));
    println!("prepared image vs OpenCV pipeline: mean {mean:e}, max {max:e}");
    assert!(
        mean < 1.5 / 255.0 && max < 6.0 / 255.0,
        "mean {mean}, max {max}"
    );
    let mask = p.mask(FrameId(2), ViewId(1)).unwrap();
    let reference = gray(&npy("zju_mocap/reference_pipeline/mask_f2_c1.npy"));
    let fg = reference.pixels().filter(|m| m[0] != 0).count();
    let differ = differing(&mask, &reference);
    println!("prepared mask vs OpenCV pipeline: {differ} of {fg} foreground pixels differ");
    assert!(fg > 10 && differ * 10 <= fg, "{differ} of {fg}");
    // The training mask's edge band, marked at full resolution as the reference's `erode_edge` (its
    // bilinear undistortion of the 0/1/100 mask blurs a few band pixels out of the band).
    let (_, band) = p.mask_and_edge(FrameId(2), ViewId(1)).unwrap();
    let theirs: Vec<bool> = npy("zju_mocap/reference_pipeline/edge_f2_c1.npy")
        .to_f32()
        .iter()
        .map(|&b| b != 0.0)
        .collect();
    let in_band = theirs.iter().filter(|&&b| b).count();
    let differ = band.iter().zip(&theirs).filter(|(a, b)| a != b).count();
    println!(
        "prepared edge band vs OpenCV pipeline: {differ} pixels differ, {in_band} in its band"
    );
    assert!(
        in_band > 10 && differ * 20 <= in_band,
        "{differ} of {in_band}"
    );
    let img = p.image(FrameId(1), ViewId(2)).unwrap();
    assert_eq!(img.dimensions(), (24, 20));
    let mask = p.mask(FrameId(1), ViewId(2)).unwrap();
    assert!(mask.pixels().any(|m| m[0] == 1) && mask.pixels().all(|m| m[0] <= 1));
    // World bounds: posed vertices ± 0.05 m.
    let (verts, pose_space, pb) = frame_vertices(&subject, 2);
    let b = anerf_core::geometry::Aabb::from_points(verts.iter().copied())
        .unwrap()
        .padded(0.05);
    assert_eq!(p.frames[2].bounds, b);
    // The frame volume lives in pose space around the posed vertices.
    let vol = p.volume(FrameId(2)).unwrap();
    assert!((vol.bounds.min - pb.min).length() < 1e-5);
    for x in pose_space.iter().step_by(7) {
        assert!(
            vol.sample(*x)[vol.num_joints] < 0.03,
            "distance channel near the surface"
        );
    }
    let canon = p.canonical_volume().unwrap();
    assert!((canon.bounds.min - p.canonical.bounds.min).length() < 1e-6);
    assert_eq!(p.frames[0].bones.len(), subject.body.skeleton.num_joints());

    // Same inputs: same entry, nothing rewritten.
    let manifest = p.dir.join("manifest.json");
    let stamp = std::fs::metadata(&manifest).unwrap().modified().unwrap();
    let again = prepare(&subject, &options(&cache)).unwrap();
    assert_eq!(again.dir, p.dir);
    assert_eq!(
        std::fs::metadata(&manifest).unwrap().modified().unwrap(),
        stamp
    );
    // An interrupted run (no manifest yet, an image missing) is completed in place.
    std::fs::remove_file(&manifest).unwrap();
    let image_file = p.dir.join("images/000001_02.png");
    std::fs::remove_file(&image_file).unwrap();
    let resumed = prepare(&subject, &options(&cache)).unwrap();
    assert_eq!(resumed.dir, p.dir);
    assert_eq!(resumed.image(FrameId(1), ViewId(2)).unwrap(), img);
    // Other options or changed inputs: a new entry.
    let half = prepare(
        &subject,
        &PrepareOptions {
            frames: FrameSelection {
                start: 0,
                end: Some(2),
                step: 1,
            },
            ..options(&cache)
        },
    )
    .unwrap();
    assert_ne!(half.dir, p.dir);
    std::thread::sleep(std::time::Duration::from_millis(20));
    let img_path = &subject.frames[0].images[0];
    let bytes = std::fs::read(img_path).unwrap();
    std::fs::write(img_path, &bytes).unwrap();
    let changed = prepare(&subject, &options(&cache)).unwrap();
    assert_ne!(changed.dir, p.dir);
    // No temporary files are left behind.
    let leftovers: Vec<_> = walk(&cache)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn dataset_volumes_use_the_reference_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let subject =
        load_zju_mocap(&fixture("zju_mocap/CoreView_377"), &LoadOptions::default()).unwrap();
    let p = prepare(
        &subject,
        &PrepareOptions {
            dataset_volumes: true,
            ..options(dir.path())
        },
    )
    .unwrap();
    let tbw = npy("zju_mocap/CoreView_377/lbs/tbw.npy");
    let canon = p.canonical_volume().unwrap();
    assert_eq!(canon.dims.to_vec(), tbw.shape()[..3].to_vec());
    assert_eq!(canon.data, tbw.to_f32());
    assert_eq!(canon.bounds, p.canonical.bounds);
    let bw = npy("zju_mocap/CoreView_377/lbs/bweights/2.npy");
    let vol = p.volume(FrameId(2)).unwrap();
    assert_eq!(vol.data, bw.to_f32());
    // The stretch: the last node sits at the padded max, not at min + (n − 1)·0.025.
    let (_, _, pb) = frame_vertices(&subject, 2);
    assert!((vol.bounds.max - pb.max).length() < 1e-5);
}

/// The error of preparing the 377-style fixture after `edit` changed it: after loading, so that only
/// preparation can notice. No manifest may have been written.
fn prepare_error_after_edit(edit: impl FnOnce(&std::path::Path)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("CoreView_377");
    common::copy_tree(&fixture("zju_mocap/CoreView_377"), &data);
    let subject = load_zju_mocap(&data, &LoadOptions::default()).unwrap();
    edit(&data);
    let err = prepare(&subject, &options(&dir.path().join("cache")))
        .unwrap_err()
        .to_string();
    assert!(!walk(&dir.path().join("cache"))
        .iter()
        .any(|p| p.ends_with("manifest.json")));
    err
}

#[test]
fn images_of_the_wrong_size_are_named_when_preparing() {
    let err = prepare_error_after_edit(|data| {
        image::RgbImage::new(30, 30)
            .save(data.join("Camera_B2/000001.jpg"))
            .unwrap()
    });
    assert!(
        err.contains("Camera_B2/000001.jpg") && err.contains("30×30") && err.contains("48×40"),
        "{err}"
    );
}

#[test]
fn cut_images_and_masks_are_named_when_preparing() {
    for rel in ["Camera_B2/000001.jpg", "mask_cihp/Camera_B3/000002.png"] {
        let err = prepare_error_after_edit(|data| common::cut_file(&data.join(rel), |n| n - 4));
        assert!(err.contains(rel) && err.contains("cut short"), "{err}");
    }
}

/// A pose file of a frame poses the body as the prepared frame: the synthetic subject's posed vertices are
/// exact LBS of its canonical vertices (0.3 µm), so bones, box and volume must agree with the cached ones
/// (the posing here shares no code with the writer's).
#[test]
fn a_frames_pose_file_poses_the_body_as_the_prepared_frame() {
    use anerf_data::loaders::read_pose_file;
    use anerf_data::synthetic::{write_subject, SyntheticSpec};

    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("subject");
    write_subject(&SyntheticSpec::tiny(), &root).unwrap();
    let subject = load_zju_mocap(&root, &LoadOptions::default()).unwrap();
    let p = prepare(&subject, &options(&dir.path().join("cache"))).unwrap();
    for f in [0usize, 5] {
        let record = &subject.frames[f];
        let file = root
            .join("new_params")
            .join(format!("{}.npy", record.file_index));
        let pose = read_pose_file(&file, p.skeleton.num_joints()).unwrap();
        let posed = p.pose_body(&pose, &file).unwrap();
        let frame = p.frame(FrameId(f)).unwrap();
        for (a, b) in posed.bones.matrices().iter().zip(frame.bones.matrices()) {
            assert!(a.abs_diff_eq(*b, 1e-6), "frame {f}: {a} vs {b}");
        }
        assert!((posed.bounds.min - frame.bounds.min).abs().max_element() < 1e-5);
        assert!((posed.bounds.max - frame.bounds.max).abs().max_element() < 1e-5);
        let cached = p.volume(FrameId(f)).unwrap();
        assert_eq!(posed.volume.dims, cached.dims, "frame {f}");
        assert!((posed.volume.bounds.min - cached.bounds.min).length() < 1e-5);
        let c = cached.num_joints + 1;
        let (mut worst, mut moved) = ([0.0f32; 2], 0);
        for (a, b) in posed.volume.data.chunks(c).zip(cached.data.chunks(c)) {
            let w = max_diff(&a[..c - 1], &b[..c - 1]);
            worst[0] = worst[0].max(w);
            worst[1] = worst[1].max((a[c - 1] - b[c - 1]).abs());
            moved += usize::from(w > 1e-5);
        }
        let nodes = cached.data.len() / c;
        eprintln!(
            "frame {f}: worst weight {worst:?} (weight, distance), {moved}/{nodes} nodes moved"
        );
        // Sub-micrometre vertex differences move distances by as much; the weights of a few nodes move
        // more: barycentric coordinates on the synthetic mesh's sliver triangles, and near-ties between
        // two triangles that flip.
        assert!(
            worst[1] < 1e-5 && worst[0] < 0.05 && moved * 200 < nodes,
            "frame {f}: {worst:?}, {moved}/{nodes} nodes moved"
        );
    }
    // A pose file with the wrong number of joints is refused, naming the file and the joint count.
    let err = read_pose_file(
        &root.join("new_params").join("0.npy"),
        p.skeleton.num_joints() + 1,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("0.npy") && err.contains("joints"), "{err}");
}

/// The visual hull of a synthetic frame (masks rasterised from the body) holds every posed vertex and
/// nothing far from the body.
#[test]
fn the_visual_hull_holds_the_posed_body_and_carves_the_box_corners() {
    use anerf_data::synthetic::{write_subject, SyntheticSpec};
    use anerf_data::visual_hull::VisualHull;

    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("subject");
    let written = write_subject(&SyntheticSpec::tiny(), &root).unwrap();
    let subject = load_zju_mocap(&root, &LoadOptions::default()).unwrap();
    let p = prepare(
        &subject,
        &PrepareOptions {
            ratio: ImageScale::FULL,
            ..options(&dir.path().join("cache"))
        },
    )
    .unwrap();
    let views: Vec<ViewId> = p.views.clone();
    let f = 3;
    let hull = VisualHull::of_frame(&p, FrameId(f), &views, 1).unwrap();
    let outside = written.posed_vertices[f]
        .iter()
        .filter(|&&x| !hull.contains(x))
        .count();
    assert_eq!(outside, 0, "posed vertices outside the hull");
    // The corners of the padded body box lie off the body in most views.
    let b = p.frame(FrameId(f)).unwrap().bounds;
    for corner in 0..8 {
        let pick = |bit: usize, lo: f32, hi: f32| if corner >> bit & 1 == 0 { lo } else { hi };
        let x = Vec3::new(
            pick(0, b.min.x, b.max.x),
            pick(1, b.min.y, b.max.y),
            pick(2, b.min.z, b.max.z),
        );
        assert!(!hull.contains(x), "box corner {x} is inside the hull");
    }
}
