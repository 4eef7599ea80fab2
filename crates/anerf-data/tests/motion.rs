//! Motions (`scripts/fixtures/motion.py`): each reader gives, after retargeting onto a body, the joint
//! rotations, Rh, Th and world vertices numpy computed for that format (the standard SMPL root converted
//! with the pelvis offset); a ZJU pose round-trips through an AMASS file; placement puts the body on the
//! floor, above the start and facing the target; bad files are named with the key at fault.

use std::path::Path;

use anerf_core::geometry::{Pose, Skeleton};
use anerf_data::formats::npz::read_npz_arrays;
use anerf_data::formats::read_npy;
use anerf_data::motion::{
    retarget, FrameRange, Motion, MotionFormat, Placement, Scene, TargetBody, Timing,
};
use anerf_data::SkinningWeights;
use anerf_testing::{assert_close, fixture, fixtures_dir, Tolerance};
use glam::{DVec3, Vec3};

/// The target body of the fixtures.
struct Body {
    skeleton: Skeleton,
    vertices: Vec<Vec3>,
    weights: SkinningWeights,
}

impl Body {
    fn read() -> Self {
        let npy = |name: &str| read_npy(&fixture(&format!("motion/body/{name}.npy"))).unwrap();
        let points = |name: &str| -> Vec<Vec3> {
            npy(name)
                .to_f32()
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect()
        };
        let parents = npy("parents").to_i64().unwrap();
        Self {
            skeleton: Skeleton::from_parent_table(points("joints"), &parents).unwrap(),
            vertices: points("tvertices"),
            weights: SkinningWeights::new(npy("weights").to_f32(), parents.len()).unwrap(),
        }
    }

    fn target(&self) -> TargetBody<'_> {
        TargetBody {
            skeleton: &self.skeleton,
            vertices: &self.vertices,
            weights: &self.weights,
        }
    }

    /// World vertices of `pose` (metres).
    fn world(&self, pose: &Pose) -> Vec<Vec3> {
        self.target()
            .pose_space_vertices(pose)
            .unwrap()
            .into_iter()
            .map(|x| pose.global.pose_to_world(x))
            .collect()
    }
}

fn flat(v: impl IntoIterator<Item = Vec3>) -> Vec<f32> {
    v.into_iter().flat_map(|p| p.to_array()).collect()
}

/// Checks retargeted poses against `<name>_expected.npz`: joints, Rh and Th within 1e-6, world vertices
/// within 1e-5 m.
fn check_against(name: &str, poses: &[Pose], body: &Body) {
    let expected = read_npz_arrays(&fixture(&format!("motion/{name}_expected.npz"))).unwrap();
    let get = |key: &str| expected[key].to_f32();
    let exact = Tolerance::Absolute(1e-6);
    assert_close(
        &format!("{name} joint rotations"),
        &flat(poses.iter().flat_map(|p| p.joint_rotations.clone())),
        &get("joints"),
        exact,
    );
    assert_close(
        &format!("{name} Rh"),
        &flat(poses.iter().map(|p| p.global.rh)),
        &get("rh"),
        exact,
    );
    assert_close(
        &format!("{name} Th"),
        &flat(poses.iter().map(|p| p.global.th)),
        &get("th"),
        Tolerance::Absolute(2e-6),
    );
    assert_close(
        &format!("{name} world vertices (m)"),
        &flat(poses.iter().flat_map(|p| body.world(p))),
        &get("vertices"),
        Tolerance::Absolute(1e-5),
    );
}

fn recorded(path: &Path, body: &Body) -> (Motion, Vec<Pose>) {
    let motion = Motion::read(path, None).unwrap();
    let poses = retarget(&motion, body.target(), &Placement::AsRecorded).unwrap();
    (motion, poses)
}

#[test]
fn each_reader_gives_the_poses_numpy_expects() {
    let body = Body::read();
    let cases = [
        (
            "amass_smplh",
            "amass_smplh.npz",
            MotionFormat::AmassSmplh,
            Some(120.0),
            52,
        ),
        (
            "amass_smplx",
            "amass_smplx.npz",
            MotionFormat::AmassSmplx,
            Some(60.0),
            55,
        ),
        ("easymocap", "easymocap", MotionFormat::EasyMocap, None, 24),
        ("zju", "zju", MotionFormat::ZjuParams, None, 24),
    ];
    for (name, file, format, fps, joints) in cases {
        let (motion, poses) = recorded(&fixture(&format!("motion/{file}")), &body);
        assert_eq!(
            (motion.format, motion.fps, motion.model_joints),
            (format, fps, joints),
            "{name}"
        );
        assert_eq!(poses.len(), 6, "{name}");
        check_against(name, &poses, &body);
    }
    // One file of a folder reads as a one-frame motion of the same pose.
    let (_, one) = recorded(&fixture("motion/zju/2.npy"), &body);
    let (_, all) = recorded(&fixture("motion/zju"), &body);
    assert_eq!(one, all[2..3]);
}

#[test]
fn a_zju_pose_written_as_amass_comes_back_to_its_rh_th_and_vertices() {
    let body = Body::read();
    let (_, zju) = recorded(&fixture("motion/roundtrip/params"), &body);
    let (motion, amass) = recorded(&fixture("motion/roundtrip/amass.npz"), &body);
    assert_eq!(motion.format, MotionFormat::AmassSmplh);
    let tight = Tolerance::Absolute(1e-6);
    let all = |poses: &[Pose], f: fn(&Pose) -> Vec<Vec3>| flat(poses.iter().flat_map(f));
    assert_close(
        "Rh",
        &all(&amass, |p| vec![p.global.rh]),
        &all(&zju, |p| vec![p.global.rh]),
        tight,
    );
    assert_close(
        "Th (m)",
        &all(&amass, |p| vec![p.global.th]),
        &all(&zju, |p| vec![p.global.th]),
        tight,
    );
    assert_close(
        "joint rotations",
        &all(&amass, |p| p.joint_rotations.clone()),
        &all(&zju, |p| p.joint_rotations.clone()),
        tight,
    );
    let world = |poses: &[Pose]| flat(poses.iter().flat_map(|p| body.world(p)));
    assert_close(
        "posed vertices (m)",
        &world(&amass),
        &world(&zju),
        Tolerance::Absolute(1e-5),
    );
}

/// Height of the lowest vertex over all frames along `up`.
fn lowest(poses: &[Pose], body: &Body, up: Vec3) -> f32 {
    poses
        .iter()
        .flat_map(|p| body.world(p))
        .map(|x| x.dot(up))
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn placement_puts_the_body_on_the_floor_above_the_start_facing_the_target() {
    let body = Body::read();
    let motion = Motion::read(&fixture("motion/amass_smplh.npz"), None).unwrap();
    // A capture whose up is -Y (as OpenCV-style worlds often are), floor at height -0.3 along it.
    let up = DVec3::new(0.0, -1.0, 0.0);
    let scene = Scene {
        up,
        floor: -0.3,
        start: DVec3::new(1.5, 7.0, -2.0),
        toward: DVec3::new(4.5, -3.0, 2.0),
        offset: DVec3::ZERO,
    };
    let poses = retarget(&motion, body.target(), &Placement::InScene(scene)).unwrap();
    let upf = up.as_vec3();
    assert!(
        (lowest(&poses, &body, upf) - -0.3).abs() < 1e-5,
        "the lowest vertex is on the floor"
    );
    let flat3 = |v: Vec3| v - v.dot(upf) * upf;
    let pelvis = poses[0]
        .global
        .pose_to_world(body.skeleton.rest_joints()[0]);
    let start = scene.start.as_vec3();
    assert!(
        (flat3(pelvis) - flat3(start)).length() < 1e-5,
        "pelvis {pelvis} above {start}"
    );
    // Canonical +Z through the global rotation (joint 0 is unrotated after conversion), made horizontal.
    assert_eq!(poses[0].joint_rotations[0], Vec3::ZERO);
    let facing = flat3(poses[0].global.rotation() * Vec3::Z).normalize();
    let wanted = flat3((scene.toward - scene.start).as_vec3()).normalize();
    assert!(
        facing.dot(wanted) > 1.0 - 1e-5,
        "faces {facing}, wanted {wanted}"
    );
    // The motion's up (+Z) became the scene's: the body's up in frame 0 relative to the original.
    let tilt = poses[0].global.rotation()
        * Motion::read(&fixture("motion/amass_smplh.npz"), None)
            .map(|m| {
                let r = retarget(&m, body.target(), &Placement::AsRecorded).unwrap();
                r[0].global.rotation().transpose() * Vec3::Z
            })
            .unwrap();
    assert!(tilt.dot(upf) > 1.0 - 1e-5, "motion up maps to {tilt}");
    // Rigid: every frame moved by one rotation and translation, so distances between frames' pelvises keep.
    let recorded = retarget(&motion, body.target(), &Placement::AsRecorded).unwrap();
    let pel = |p: &Pose| p.global.pose_to_world(body.skeleton.rest_joints()[0]);
    for i in 1..poses.len() {
        let (a, b) = (
            (pel(&poses[i]) - pel(&poses[0])).length(),
            (pel(&recorded[i]) - pel(&recorded[0])).length(),
        );
        assert!((a - b).abs() < 1e-5, "frame {i}: {a} vs {b}");
    }
    // The offset moves every frame by itself.
    let offset = DVec3::new(0.25, -0.5, 1.0);
    let moved = retarget(
        &motion,
        body.target(),
        &Placement::InScene(Scene { offset, ..scene }),
    )
    .unwrap();
    for (m, p) in moved.iter().zip(&poses) {
        assert!((m.global.th - p.global.th - offset.as_vec3()).length() < 1e-5);
        assert_eq!(m.global.rh, p.global.rh);
    }
}

#[test]
fn resampling_and_ranges_apply_to_read_motions() {
    let motion = Motion::read(&fixture("motion/walk.npz"), None).unwrap();
    assert_eq!((motion.frames.len(), motion.fps), (1200, Some(120.0)));
    let clip = motion
        .resampled(120.0, 30.0)
        .unwrap()
        .select("0:300".parse::<FrameRange>().unwrap())
        .unwrap();
    assert_eq!(clip.frames.len(), 300);
    assert_eq!(clip.frames[7], motion.frames[28]);
    let err = motion
        .select("1000:1300".parse().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("walk.npz") && err.contains("1200 frames"),
        "{err}"
    );
    let folder = Motion::read(&fixture("motion/zju"), None).unwrap();
    let err = folder.rate(None).unwrap_err().to_string();
    assert!(err.contains("--motion-fps") && err.contains("zju"), "{err}");
    assert_eq!(folder.rate(Some(25.0)).unwrap(), 25.0);
}

/// A timed read (only the recorded frames the output needs) gives exactly the frames of reading the whole
/// motion, resampling it and cutting it, for rates that divide and that do not, for folders whose rate is
/// declared, and refuses the same ranges with the same message.
#[test]
fn timed_reads_equal_whole_reads_resampled_and_cut() {
    let cases = [
        ("motion/walk.npz", None, None, "7:300:5"),
        ("motion/walk.npz", None, Some(50.0), "3:41:3"),
        ("motion/walk.npz", None, Some(30.0), "299:"),
        ("motion/walk.npz", None, None, "1000:1100"),
        ("motion/walk.npz", None, Some(170.0), "100:"),
        ("motion/zju", Some(25.0), Some(60.0), "1:"),
        ("motion/zju", Some(25.0), None, "1:2"),
        ("motion/easymocap", Some(30.0), Some(45.0), "2:"),
    ];
    for (file, declared, fps, range) in cases {
        let path = fixture(file);
        let frames: FrameRange = range.parse().unwrap();
        let whole = Motion::read(&path, None).unwrap();
        let from = whole.rate(declared).unwrap();
        let to = fps.unwrap_or(from);
        let want = whole.resampled(from, to).unwrap().select(frames).unwrap();
        let timing = Timing {
            declared_fps: declared,
            fps,
            frames,
        };
        let got = Motion::read_timed(&path, None, &timing).unwrap();
        assert_eq!(got, want, "{file} at {fps:?} fps, frames {range}");
        assert!(!got.frames.is_empty());
    }
    let outside = Timing {
        declared_fps: None,
        fps: Some(30.0),
        frames: "300:301".parse().unwrap(),
    };
    let err = Motion::read_timed(&fixture("motion/walk.npz"), None, &outside)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("walk.npz") && err.contains("outside the motion's 300 frames"),
        "{err}"
    );
}

#[test]
fn bad_motion_files_are_named_with_the_key_at_fault() {
    let cases = [
        ("nan", "poses holds a non-finite value"),
        ("width", "fits no known body model"),
        ("rate_zero", "'mocap_framerate' is 0"),
        ("rate_negative", "'mocap_framerate' is -30"),
        ("object", "'poses' holds pickled objects"),
        (
            "unknown",
            "this file has fps (), positions (6, 3), rotations (6, 24, 4)",
        ),
    ];
    for (name, wanted) in cases {
        let path = fixture(&format!("motion/bad/{name}.npz"));
        let err = Motion::read(&path, None).unwrap_err().to_string();
        assert!(
            err.contains(&format!("{name}.npz")) && err.contains(wanted),
            "{name}: {err}"
        );
    }
    // A one-dimensional `poses` (one frame written without its frame axis) names the shape it needs.
    let dir = tempfile::tempdir().unwrap();
    let flat_poses = dir.path().join("flat.npz");
    let array = |shape: Vec<usize>, value: f64| {
        let n = shape.iter().product();
        anerf_data::formats::NdArray::new(
            shape,
            anerf_data::formats::ArrayData::F64(vec![value; n]),
        )
        .unwrap()
    };
    anerf_data::formats::npz::write_npz(
        &flat_poses,
        &[
            ("poses", &array(vec![156], 0.0)),
            ("trans", &array(vec![40, 3], 0.0)),
            ("mocap_framerate", &array(vec![], 120.0)),
        ],
    )
    .unwrap();
    let err = Motion::read(&flat_poses, None).unwrap_err().to_string();
    assert!(
        err.contains("flat.npz") && err.contains("has shape (156,)") && err.contains("T = 40"),
        "{err}"
    );
    let err = Motion::read(&fixture("motion/easymocap"), Some(7))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("no person 7") && err.contains("[3, 1]"),
        "{err}"
    );
    let err = Motion::read(&fixture("motion/body/joints.npy"), None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("joints.npy"), "{err}");
    let err = Motion::read(&fixtures_dir().join("motion/nothing.bvh"), None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("nothing.bvh") && err.contains("motion file"),
        "{err}"
    );
}

#[test]
fn a_body_of_another_family_is_refused_with_both_joint_counts() {
    let body = Body::read();
    let nine = Skeleton::from_parent_table(
        body.skeleton.rest_joints()[..9].to_vec(),
        &[-1, 0, 0, 0, 1, 2, 3, 4, 5],
    )
    .unwrap();
    let weights = SkinningWeights::new(vec![1.0 / 9.0; 9 * body.vertices.len()], 9).unwrap();
    let target = TargetBody {
        skeleton: &nine,
        vertices: &body.vertices,
        weights: &weights,
    };
    let motion = Motion::read(&fixture("motion/amass_smplh.npz"), None).unwrap();
    let err = retarget(&motion, target, &Placement::AsRecorded)
        .unwrap_err()
        .to_string();
    assert!(err.contains("52 joints") && err.contains("has 9"), "{err}");
}
