//! Writing a synthetic subject in the ZJU-MoCap layout (docs/REFERENCE.md §1.1, §1.3): `annots.npy`,
//! `Camera_B<c>/<frame:06>.jpg`, `mask_cihp/Camera_B<c>/<frame:06>.png`, `new_params/<i>.npy`,
//! `new_vertices/<i>.npy`, `lbs/{joints,parents,tvertices,weights,faces}.npy`, plus `splits.json` and,
//! under pose noise, `true_params/<i>.npy`.

use std::path::Path;
use std::time::Instant;

use anerf_core::geometry::{
    forward_lbs_points, BoneTransforms, Camera, CanonicalPose, GlobalTransform, Pose,
};
use anerf_core::mesh::TriMesh;
use anerf_core::FrameId;
use glam::Vec3;
use image::ImageEncoder;
use rayon::prelude::*;

use super::appearance::Outfit;
use super::backdrop::Plate;
use super::body::{build_body, Body};
use super::cameras::ring_cameras;
use super::clothing::dress;
use super::lighting::Lighting;
use super::mask_noise;
use super::motion::{angles_to_axis_angle, clip_angles, global_rotation, heading, ClipSpec};
use super::pose_noise::{PoseNoise, PoseNoiseReport};
use super::raster::{render, RenderedView, Scene};
use super::rng::SplitMix64;
use super::{Splits, SynthError, SyntheticSpec, SyntheticSummary, Timings};
use crate::subject::{BodyModel, DatasetKind, FrameRecord, PosedVertices, Subject};
use crate::zju_layout;

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
    /// The pose of the files (`new_params/<i>.npy`): the true one, or under pose noise a fit's.
    pose: Pose,
    /// The described body posed by `pose` (world space, metres): `new_vertices/<i>.npy`.
    vertices: Vec<Vec3>,
    /// The rendered surface posed by the true pose (world space, metres).
    surface: Vec<Vec3>,
    /// Under pose noise, the truth the files miss.
    truth: Option<Truth>,
}

/// A frame's true pose (`true_params/<i>.npy`) and the described body posed by it (world space, metres).
struct Truth {
    pose: Pose,
    vertices: Vec<Vec3>,
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
        .enumerate()
        .map(|(i, &(clip, f))| {
            let frame = pose_frame(&body, &surface, clip, f)?;
            match &spec.pose_noise {
                Some(noise) if i < spec.training.frames => {
                    with_fit_errors(frame, &body, noise, spec.seed, i)
                }
                _ => Ok(frame),
            }
        })
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
    let plates: Vec<Option<Plate>> = cameras
        .par_iter()
        .map(|c| spec.backdrop.plate(c, spec.supersampling))
        .collect();
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
                    let mut view = render(
                        &cameras[v],
                        &scene,
                        spec.supersampling,
                        |s| match &lit {
                            Some(lit) => lit.shade(outfit.albedo(s.canonical), s, eye),
                            None => outfit.colour(s.canonical, s.canonical_normal),
                        },
                        plates[v].as_ref().map(|p| p.at_frame(f)),
                    );
                    if spec.mask_noise > 0.0 {
                        let (w, h) = (view.width as usize, view.height as usize);
                        let item = (f * cameras.len() + v) as u64;
                        mask_noise::perturb(&mut view.mask, w, h, spec.mask_noise, spec.seed, item);
                    }
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
        pose_noise: pose_noise_report(&frames),
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
    let seen = place(surface, &transforms, &pose.global)?;
    let floor = seen.iter().map(|p| p.z).fold(f32::INFINITY, f32::min);
    pose.global.th = Vec3::new(0.0, 0.0, -floor);
    let th = pose.global.th;
    Ok(PosedFrame {
        vertices: place(body, &transforms, &pose.global)?,
        surface: seen.into_iter().map(|p| p + th).collect(),
        pose,
        truth: None,
    })
}

/// `R(Rh) · LBS(x) + Th` for each canonical vertex `x` of `b`, with bones `transforms` and `global`'s
/// `Rh`, `Th` (world space, metres).
fn place(
    b: &Body,
    transforms: &BoneTransforms,
    global: &GlobalTransform,
) -> Result<Vec<Vec3>, SynthError> {
    let rotation = global.rotation();
    Ok(
        forward_lbs_points(&b.mesh.vertices, b.weights.as_slice(), transforms)?
            .into_iter()
            .map(|p| rotation * p + global.th)
            .collect(),
    )
}

/// `frame` as a fitter with errors `noise` would give it (frame `index` of the subject of `seed`): the
/// noisy pose and the described body posed by it exactly, the truth kept beside them, the rendered
/// surface untouched.
fn with_fit_errors(
    frame: PosedFrame,
    body: &Body,
    noise: &PoseNoise,
    seed: u64,
    index: usize,
) -> Result<PosedFrame, SynthError> {
    let pose = noise.perturb(&frame.pose, seed, index);
    let transforms = body.skeleton.bone_transforms(&pose, CanonicalPose::TPose)?;
    Ok(PosedFrame {
        vertices: place(body, &transforms, &pose.global)?,
        pose,
        surface: frame.surface,
        truth: Some(Truth {
            pose: frame.pose,
            vertices: frame.vertices,
        }),
    })
}

/// The true poses of the frames with fit errors and the mean distance (metres) of their noisy vertices
/// from the true ones; `None` without pose noise.
fn pose_noise_report(frames: &[PosedFrame]) -> Option<PoseNoiseReport> {
    let noisy: Vec<(&PosedFrame, &Truth)> = frames
        .iter()
        .filter_map(|f| f.truth.as_ref().map(|t| (f, t)))
        .collect();
    if noisy.is_empty() {
        return None;
    }
    let (sum, count) = noisy.iter().fold((0.0f64, 0usize), |(sum, count), (f, t)| {
        let d: f64 = f
            .vertices
            .iter()
            .zip(&t.vertices)
            .map(|(a, b)| f64::from(a.distance(*b)))
            .sum();
        (sum + d, count + t.vertices.len())
    });
    Some(PoseNoiseReport {
        true_poses: noisy.iter().map(|(_, t)| t.pose.clone()).collect(),
        mean_vertex_error: (sum / count.max(1) as f64) as f32,
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

/// `annots.npy`, `new_params/`, `new_vertices/`, `lbs/` and, under pose noise, `true_params/` in the
/// authors' layout ([`crate::zju_layout`]).
fn write_arrays(
    dir: &Path,
    body: &Body,
    cameras: &[Camera],
    frames: &[PosedFrame],
) -> Result<(), SynthError> {
    let images: Vec<Vec<String>> = (0..frames.len())
        .map(|f| (0..cameras.len()).map(|v| image_path(v, f)).collect())
        .collect();
    zju_layout::write_annots(&dir.join("annots.npy"), cameras, &images)?;
    frames
        .par_iter()
        .enumerate()
        .map(|(i, frame)| {
            with_params(&frame.pose, |p| {
                zju_layout::write_frame(dir, i, p, &frame.vertices)
            })?;
            match &frame.truth {
                Some(truth) => with_params(&truth.pose, |p| {
                    zju_layout::write_params(&dir.join(format!("true_params/{i}.npy")), p)
                }),
                None => Ok(()),
            }
        })
        .collect::<Result<(), _>>()?;
    zju_layout::write_lbs(
        &dir.join("lbs"),
        &body.skeleton,
        &body.mesh.vertices,
        &body.weights,
        &body.mesh.faces,
    )?;
    Ok(())
}

/// Calls `f` with `pose` as `new_params/<i>.npy` holds it: float64 axis-angles, `Rh`, `Th` (metres) and,
/// as the procedural body has no shape coefficients, ten zeros (SMPL's mean shape).
fn with_params<T>(pose: &Pose, f: impl FnOnce(&zju_layout::FrameParams<'_>) -> T) -> T {
    let poses: Vec<f64> = pose
        .joint_rotations
        .iter()
        .flat_map(|r| r.to_array())
        .map(f64::from)
        .collect();
    f(&zju_layout::FrameParams {
        poses: &poses,
        rh: pose.global.rh.to_array().map(f64::from),
        th: pose.global.th.to_array().map(f64::from),
        shapes: &[0.0; 10],
    })
}
