//! Writing a synthetic subject in the ZJU-MoCap layout (docs/REFERENCE.md §1.1, §1.3): `annots.npy`,
//! `Camera_B<c>/<frame:06>.jpg`, `mask_cihp/Camera_B<c>/<frame:06>.png`, `new_params/<i>.npy`,
//! `new_vertices/<i>.npy`, `lbs/{joints,parents,tvertices,weights,faces}.npy`, plus `splits.json`.

use std::path::Path;
use std::time::Instant;

use anerf_core::geometry::{forward_lbs_point, Camera, CanonicalPose, GlobalTransform, Pose};
use anerf_core::mesh::TriMesh;
use anerf_core::FrameId;
use glam::Vec3;
use image::ImageEncoder;
use rayon::prelude::*;

use super::appearance::Outfit;
use super::body::{build_body, Body};
use super::cameras::ring_cameras;
use super::clothing::dress;
use super::lighting::Lighting;
use super::motion::{angles_to_axis_angle, clip_angles, global_rotation, heading, ClipSpec};
use super::raster::{render, RenderedView, Scene};
use super::rng::SplitMix64;
use super::{Splits, SynthError, SyntheticSpec, SyntheticSummary, Timings};
use crate::formats::{write_npy, write_object_npy, ArrayData, NdArray, PyValue};
use crate::subject::{BodyModel, DatasetKind, FrameRecord, PosedVertices, Subject};

/// Writes the subject of `spec` into the new folder `out_dir`. Everything goes into a temporary sibling
/// folder first, renamed into place at the end, so `out_dir` either holds a complete subject or does not
/// exist.
pub fn write_subject(spec: &SyntheticSpec, out_dir: &Path) -> Result<SyntheticSummary, SynthError> {
    let start = Instant::now();
    spec.validate()?;
    if out_dir.exists() {
        return Err(SynthError::AlreadyExists(out_dir.to_path_buf()));
    }
    let name = out_dir.file_name().ok_or_else(|| {
        SynthError::invalid(
            "output folder",
            format!("{} has no folder name", out_dir.display()),
        )
    })?;
    let parent = out_dir
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(SynthError::io(parent))?;
    let staging = parent.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    if staging.exists() {
        std::fs::remove_dir_all(&staging).map_err(SynthError::io(&staging))?;
    }
    std::fs::create_dir(&staging).map_err(SynthError::io(&staging))?;
    let result = write_into(spec, &staging, out_dir, start).and_then(|summary| {
        std::fs::rename(&staging, out_dir)
            .map(|()| summary)
            .map_err(SynthError::io(out_dir))
    });
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    result
}

/// One frame's pose and posed surfaces.
struct PosedFrame {
    pose: Pose,
    /// The described body posed (world space, metres): `new_vertices/<i>.npy`.
    vertices: Vec<Vec3>,
    /// The rendered surface posed (world space, metres).
    surface: Vec<Vec3>,
}

fn camera_folder(view: usize) -> String {
    format!("Camera_B{}", view + 1)
}

fn image_path(view: usize, frame: usize) -> String {
    format!("{}/{frame:06}.jpg", camera_folder(view))
}

fn mask_path(view: usize, frame: usize) -> String {
    format!("mask_cihp/{}/{frame:06}.png", camera_folder(view))
}

fn write_into(
    spec: &SyntheticSpec,
    staging: &Path,
    root: &Path,
    start: Instant,
) -> Result<SyntheticSummary, SynthError> {
    let body = build_body(&spec.body)?;
    // The surface the cameras see, and the body the files describe: the same without clothing.
    let (surface, body) = match &spec.clothing {
        Some(clothing) => {
            let (garment, prior) = dress(&body, &spec.body, clothing)?;
            (
                garment,
                Body {
                    weights: prior,
                    ..body
                },
            )
        }
        None => (body.clone(), body),
    };
    let cameras = ring_cameras(&spec.rig, &mut SplitMix64::new(spec.seed))?;
    let clips = [&spec.training, &spec.novel_pose];
    let frames: Vec<PosedFrame> = clips
        .iter()
        .flat_map(|clip| (0..clip.frames).map(move |f| (*clip, f)))
        .collect::<Vec<_>>()
        .par_iter()
        .map(|&(clip, f)| pose_frame(&body, &surface, clip, f))
        .collect::<Result<_, _>>()?;
    let body_done = Instant::now();

    for view in 0..cameras.len() {
        for dir in [
            staging.join(camera_folder(view)),
            staging.join("mask_cihp").join(camera_folder(view)),
        ] {
            std::fs::create_dir_all(&dir).map_err(SynthError::io(&dir))?;
        }
    }
    let outfit = Outfit::new(&spec.body);
    // Frame by frame (its shadow maps serve every camera), cameras in turn.
    let counts: Vec<Vec<usize>> = frames
        .par_iter()
        .enumerate()
        .map(|(f, frame)| {
            let world_normals = TriMesh {
                vertices: frame.surface.clone(),
                faces: surface.mesh.faces.clone(),
            }
            .vertex_normals();
            let scene = Scene {
                world: &frame.surface,
                world_normals: &world_normals,
                faces: &surface.mesh.faces,
                canonical: &body.mesh.vertices,
                normals: &surface.normals,
            };
            let lit = match &spec.lighting {
                Lighting::Studio(lights) => Some(lights.frame(&frame.surface, &surface.mesh.faces)),
                Lighting::BodyFixed => None,
            };
            (0..cameras.len())
                .map(|v| {
                    let eye = cameras[v].center();
                    let view = render(&cameras[v], &scene, spec.supersampling, |s| match &lit {
                        Some(lit) => lit.shade(outfit.albedo(s.canonical), s, eye),
                        None => outfit.colour(s.canonical, s.canonical_normal),
                    });
                    write_images(
                        &view,
                        &staging.join(image_path(v, f)),
                        &staging.join(mask_path(v, f)),
                        spec.jpeg_quality,
                    )?;
                    Ok(view.mask.iter().filter(|&&m| m > 0).count())
                })
                .collect()
        })
        .collect::<Result<_, SynthError>>()?;
    let images_done = Instant::now();

    write_arrays(staging, &body, &cameras, &frames)?;
    let splits = Splits {
        training_views: spec.training_view_list(),
        test_views: (0..cameras.len())
            .filter(|v| !spec.training_view_list().contains(v))
            .collect(),
        training_frames: (0..spec.training.frames).collect(),
        novel_pose_frames: (spec.training.frames..frames.len()).collect(),
    };
    let splits_json = serde_json::json!({
        "generator": "anerf synthetic subject",
        "training_views": splits.training_views,
        "test_views": splits.test_views,
        "training_frames": splits.training_frames,
        "novel_pose_frames": splits.novel_pose_frames,
        "spec": spec,
    });
    let splits_path = staging.join("splits.json");
    let text = serde_json::to_string_pretty(&splits_json)
        .map_err(|e| SynthError::io(&splits_path)(e.into()))?;
    std::fs::write(&splits_path, text).map_err(SynthError::io(&splits_path))?;
    let arrays_done = Instant::now();

    let subject = Subject {
        name: root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        root: root.to_path_buf(),
        kind: DatasetKind::Synthetic,
        cameras: cameras.clone(),
        frames: frames
            .iter()
            .enumerate()
            .map(|(i, frame)| FrameRecord {
                id: FrameId(i),
                file_index: i,
                images: (0..cameras.len())
                    .map(|v| root.join(image_path(v, i)))
                    .collect(),
                masks: (0..cameras.len())
                    .map(|v| root.join(mask_path(v, i)))
                    .collect(),
                pose: frame.pose.clone(),
                vertices: PosedVertices::File(root.join(format!("new_vertices/{i}.npy"))),
            })
            .collect(),
        body: BodyModel {
            skeleton: body.skeleton.clone(),
            canonical_vertices: body.mesh.vertices.clone(),
            faces: body.mesh.faces.clone(),
            weights: body.weights.clone(),
        },
        notes: vec![format!("synthetic subject, seed {}", spec.seed)],
    };
    Ok(SyntheticSummary {
        subject,
        foreground_pixels: counts,
        posed_vertices: frames.into_iter().map(|f| f.vertices).collect(),
        splits,
        timings: Timings {
            body: body_done - start,
            images: images_done - body_done,
            arrays: arrays_done - images_done,
            total: start.elapsed(),
        },
    })
}

/// Poses frame `f` of `clip`: joint rotations from the clip, `Rh` from its heading, and `Th` that puts the
/// rendered surface's lowest vertex on the ground (`z = 0`). World vertices are
/// `R_h · LBS(canonical) + T_h`, for the described body and the rendered surface alike.
fn pose_frame(
    body: &Body,
    surface: &Body,
    clip: &ClipSpec,
    f: usize,
) -> Result<PosedFrame, SynthError> {
    let mut pose = Pose {
        joint_rotations: angles_to_axis_angle(&clip_angles(clip, f)).to_vec(),
        global: GlobalTransform {
            rh: global_rotation(heading(clip, f)),
            th: Vec3::ZERO,
        },
    };
    let transforms = body.skeleton.bone_transforms(&pose, CanonicalPose::TPose)?;
    let rotation = pose.global.rotation();
    let posed = |b: &Body| -> Result<Vec<Vec3>, SynthError> {
        Ok(b.mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(v, &x)| {
                forward_lbs_point(x, b.weights.row(v), &transforms).map(|p| rotation * p)
            })
            .collect::<Result<_, _>>()?)
    };
    let seen = posed(surface)?;
    let floor = seen.iter().map(|p| p.z).fold(f32::INFINITY, f32::min);
    pose.global.th = Vec3::new(0.0, 0.0, -floor);
    let th = pose.global.th;
    let lift = |v: Vec<Vec3>| -> Vec<Vec3> { v.into_iter().map(|p| p + th).collect() };
    let vertices = lift(posed(body)?);
    let surface = lift(seen);
    Ok(PosedFrame {
        pose,
        vertices,
        surface,
    })
}

fn write_images(
    view: &RenderedView,
    image: &Path,
    mask: &Path,
    quality: u8,
) -> Result<(), SynthError> {
    let (w, h) = (view.width, view.height);
    write_encoded(image, |out| {
        image::codecs::jpeg::JpegEncoder::new_with_quality(out, quality).write_image(
            &view.rgb,
            w,
            h,
            image::ExtendedColorType::Rgb8,
        )
    })?;
    write_encoded(mask, |out| {
        image::codecs::png::PngEncoder::new(out).write_image(
            &view.mask,
            w,
            h,
            image::ExtendedColorType::L8,
        )
    })
}

/// Encodes into memory, then writes `path` (inside the staging folder, so no partial file survives).
fn write_encoded(
    path: &Path,
    encode: impl FnOnce(&mut Vec<u8>) -> image::ImageResult<()>,
) -> Result<(), SynthError> {
    let mut bytes = Vec::new();
    encode(&mut bytes).map_err(|source| SynthError::Image {
        path: path.to_path_buf(),
        source,
    })?;
    std::fs::write(path, bytes).map_err(SynthError::io(path))
}

fn f32_array(
    shape: Vec<usize>,
    values: impl IntoIterator<Item = f32>,
) -> Result<NdArray, SynthError> {
    Ok(NdArray::new(
        shape,
        ArrayData::F32(values.into_iter().collect()),
    )?)
}

fn f64_value(
    shape: Vec<usize>,
    values: impl IntoIterator<Item = f32>,
) -> Result<PyValue, SynthError> {
    let data = ArrayData::F64(values.into_iter().map(f64::from).collect());
    Ok(PyValue::Array(NdArray::new(shape, data)?))
}

fn vec3s(v: &[Vec3]) -> impl Iterator<Item = f32> + '_ {
    v.iter().flat_map(|p| p.to_array())
}

/// Row-major 3×3 entries of a glam (column-major) matrix.
fn rows(m: glam::Mat3) -> [f32; 9] {
    m.transpose().to_cols_array()
}

/// `annots.npy`, `new_params/`, `new_vertices/` and `lbs/`, with the dtypes and shapes of the real data:
/// float64 calibration (`T` in millimetres), float64 parameters, float32 vertices and weights, int64
/// faces and parents (root = the uint32 sentinel 4294967295, as SMPL's `kintree_table`).
fn write_arrays(
    dir: &Path,
    body: &Body,
    cameras: &[Camera],
    frames: &[PosedFrame],
) -> Result<(), SynthError> {
    let cams = |f: &dyn Fn(&Camera) -> Result<PyValue, SynthError>| -> Result<PyValue, SynthError> {
        Ok(PyValue::List(
            cameras.iter().map(f).collect::<Result<_, _>>()?,
        ))
    };
    let annots = PyValue::dict([
        (
            "cams",
            PyValue::dict([
                ("K", cams(&|c| f64_value(vec![3, 3], rows(c.intrinsics)))?),
                ("D", cams(&|c| f64_value(vec![5, 1], c.distortion.0))?),
                ("R", cams(&|c| f64_value(vec![3, 3], rows(c.rotation)))?),
                (
                    "T",
                    cams(&|c| {
                        let mm = ArrayData::F64(
                            c.translation
                                .to_array()
                                .iter()
                                .map(|&t| f64::from(t) * 1000.0)
                                .collect(),
                        );
                        Ok(PyValue::Array(NdArray::new(vec![3, 1], mm)?))
                    })?,
                ),
            ]),
        ),
        (
            "ims",
            PyValue::List(
                (0..frames.len())
                    .map(|f| {
                        let paths = (0..cameras.len())
                            .map(|v| PyValue::Str(image_path(v, f)))
                            .collect();
                        PyValue::dict([("ims", PyValue::List(paths))])
                    })
                    .collect(),
            ),
        ),
    ]);
    write_object_npy(&dir.join("annots.npy"), &annots)?;

    for sub in ["new_params", "new_vertices", "lbs"] {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(SynthError::io(&d))?;
    }
    frames
        .par_iter()
        .enumerate()
        .map(|(i, frame)| {
            let params = PyValue::dict([
                (
                    "poses",
                    f64_value(vec![1, 72], vec3s(&frame.pose.joint_rotations))?,
                ),
                (
                    "Rh",
                    f64_value(vec![1, 3], frame.pose.global.rh.to_array())?,
                ),
                (
                    "Th",
                    f64_value(vec![1, 3], frame.pose.global.th.to_array())?,
                ),
                ("shapes", f64_value(vec![1, 10], [0.0; 10])?),
            ]);
            write_object_npy(&dir.join(format!("new_params/{i}.npy")), &params)?;
            let verts = f32_array(vec![frame.vertices.len(), 3], vec3s(&frame.vertices))?;
            write_npy(&dir.join(format!("new_vertices/{i}.npy")), &verts)?;
            Ok(())
        })
        .collect::<Result<(), SynthError>>()?;

    let lbs = dir.join("lbs");
    let joints = body.skeleton.rest_joints();
    write_npy(
        &lbs.join("joints.npy"),
        &f32_array(vec![joints.len(), 3], vec3s(joints))?,
    )?;
    let parents = body
        .skeleton
        .parents()
        .iter()
        .map(|p| p.map_or(i64::from(u32::MAX), |p| p as i64))
        .collect();
    write_npy(
        &lbs.join("parents.npy"),
        &NdArray::new(vec![joints.len()], ArrayData::I64(parents))?,
    )?;
    let verts = &body.mesh.vertices;
    write_npy(
        &lbs.join("tvertices.npy"),
        &f32_array(vec![verts.len(), 3], vec3s(verts))?,
    )?;
    let w = &body.weights;
    write_npy(
        &lbs.join("weights.npy"),
        &f32_array(
            vec![w.num_vertices(), w.num_joints()],
            w.as_slice().iter().copied(),
        )?,
    )?;
    let faces = body
        .mesh
        .faces
        .iter()
        .flat_map(|f| f.map(i64::from))
        .collect();
    write_npy(
        &lbs.join("faces.npy"),
        &NdArray::new(vec![body.mesh.faces.len(), 3], ArrayData::I64(faces))?,
    )?;
    Ok(())
}
