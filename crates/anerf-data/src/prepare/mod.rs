//! `anerf prepare`: turns a loaded [`Subject`] into what training reads every step — undistorted,
//! resized images and masks, per-frame world bounds, bone transforms and pose-space blend-weight
//! volumes, and the canonical body with its volume — cached on disk under a fingerprint of the inputs.

pub mod cache;
mod mask_band;
pub mod nearest;
pub mod new_pose;
mod progress;
pub mod resize;
pub mod undistort;
pub mod volumes;

use std::path::{Path, PathBuf};

use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{
    Aabb, BoneTransforms, Camera, CanonicalPose, Distortion, Pose, Skeleton,
};
use anerf_core::{FrameId, ViewId};
use glam::Vec3;
use image::{GrayImage, Rgb32FImage, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use self::cache::{entry_dir, read_volume, volume_bytes, Fingerprint};
pub use self::mask_band::edge_band;
pub use self::new_pose::PosedBody;
pub use self::progress::{PrepareProgress, Silent};
pub use self::resize::ImageScale;
use self::resize::{resize_area, resize_nearest, scaled_size};
use self::undistort::UndistortMap;
pub use self::volumes::{compute_volume, NearestMethod, VolumeGrid};
use crate::atomic::write_bytes;
use crate::error::DataError;
use crate::formats::{self, images};
use crate::subject::{DatasetKind, SkinningWeights, Subject};

/// Which frames to prepare: `start..end` (end exclusive, `None` = all) every `step`-th, by position in
/// the dataset's frame list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameSelection {
    pub start: usize,
    pub end: Option<usize>,
    pub step: usize,
}

impl Default for FrameSelection {
    fn default() -> Self {
        Self {
            start: 0,
            end: None,
            step: 1,
        }
    }
}

impl FrameSelection {
    /// The selected frame positions among `n` frames.
    pub fn ids(&self, n: usize) -> Vec<usize> {
        let end = self.end.unwrap_or(n).min(n);
        (self.start..end).step_by(self.step.max(1)).collect()
    }
}

/// Everything `prepare` does, as one plain settings record (saved in the cache's manifest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrepareOptions {
    /// Root of the cache; results go to `<cache_dir>/v2/<fingerprint>/`.
    pub cache_dir: PathBuf,
    /// Image scale (0.5 for ZJU-MoCap's 1024² → 512², 1 for H36M); `K[:2] *= ratio` as the reference.
    pub ratio: ImageScale,
    pub frames: FrameSelection,
    /// Cameras whose images to prepare (`None` = all).
    pub views: Option<Vec<usize>>,
    /// Nearest surface point with barycentric weights (default) or the reference's nearest vertex.
    pub nearest: NearestMethod,
    pub grid: VolumeGrid,
    /// Read the dataset's own `lbs/tbw.npy` and `lbs/bweights/{i}.npy` instead of computing volumes; their
    /// bounds are the reference's (body box ± 0.05 m), so lookups match the reference including its stretch.
    pub dataset_volumes: bool,
    /// Padding of the world box around the posed vertices (metres), the reference's `box_padding`.
    pub box_padding: f32,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            cache_dir: PathBuf::from("cache"),
            ratio: ImageScale::HALF,
            frames: FrameSelection::default(),
            views: None,
            nearest: NearestMethod::Surface,
            grid: VolumeGrid::default(),
            dataset_volumes: false,
            box_padding: 0.05,
        }
    }
}

/// One prepared frame.
#[derive(Debug, Clone)]
pub struct PreparedFrame {
    pub id: FrameId,
    pub file_index: usize,
    pub pose: Pose,
    /// Canonical (T-pose) → pose space, from [`Skeleton::bone_transforms`].
    pub bones: BoneTransforms,
    /// World-space box around the posed vertices, padded by `box_padding` (metres).
    pub bounds: Aabb,
}

/// The canonical (T-pose) body.
#[derive(Debug, Clone)]
pub struct CanonicalBody {
    /// Canonical vertices (metres).
    pub vertices: Vec<Vec3>,
    pub faces: Vec<[u32; 3]>,
    pub weights: SkinningWeights,
    /// Canonical vertices' box ± 0.05 m: outside it the canonical density is zero.
    pub bounds: Aabb,
}

/// What the training loop consumes: working-resolution cameras without distortion, frames, the canonical
/// body, and cached images, masks and volumes loaded on demand.
#[derive(Debug, Clone)]
pub struct PreparedSubject {
    pub dir: PathBuf,
    pub name: String,
    pub kind: DatasetKind,
    pub skeleton: Skeleton,
    /// Every camera at the working resolution, `D = 0`.
    pub cameras: Vec<Camera>,
    /// Cameras whose images were prepared.
    pub views: Vec<ViewId>,
    pub frames: Vec<PreparedFrame>,
    pub canonical: CanonicalBody,
    /// The settings the entry was prepared with (new poses get the same volumes and boxes).
    pub options: PrepareOptions,
}

#[derive(Serialize, Deserialize)]
struct FrameEntry {
    id: usize,
    file_index: usize,
    pose: Pose,
    bounds: Aabb,
}

#[derive(Serialize, Deserialize)]
struct Manifest {
    name: String,
    kind: DatasetKind,
    options: PrepareOptions,
    skeleton: Skeleton,
    cameras: Vec<Camera>,
    views: Vec<usize>,
    frames: Vec<FrameEntry>,
    vertices: Vec<Vec3>,
    faces: Vec<[u32; 3]>,
    weights: Vec<f32>,
    canonical_bounds: Aabb,
}

const MANIFEST: &str = "manifest.json";

/// Bits of a prepared mask pixel: on the body, and in the reference's mask-edge band.
const MASK_BODY: u8 = 0x80;
const MASK_EDGE: u8 = 0x40;

fn image_name(frame: usize, view: usize) -> String {
    format!("{frame:06}_{view:02}.png")
}

fn frame_volume_name(frame: usize) -> String {
    format!("volumes/frame_{frame:06}.bwv")
}

const CANONICAL_VOLUME: &str = "volumes/canonical.bwv";

impl PreparedSubject {
    /// Opens a finished cache entry (one whose manifest was written).
    pub fn open(dir: &Path) -> Result<Self, DataError> {
        let path = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&path).map_err(|e| DataError::io(&path, e))?;
        let m: Manifest = serde_json::from_str(&text).map_err(|e| {
            DataError::invalid(&path, format!("not a prepared-subject manifest: {e}"))
        })?;
        let weights = SkinningWeights::new(m.weights, m.skeleton.num_joints())
            .map_err(|e| DataError::invalid(&path, e))?;
        let frames = m
            .frames
            .into_iter()
            .map(|f| {
                let bones = m
                    .skeleton
                    .bone_transforms(&f.pose, CanonicalPose::TPose)
                    .map_err(|e| DataError::invalid(&path, format!("frame {}: {e}", f.id)))?;
                Ok(PreparedFrame {
                    id: FrameId(f.id),
                    file_index: f.file_index,
                    pose: f.pose,
                    bones,
                    bounds: f.bounds,
                })
            })
            .collect::<Result<_, DataError>>()?;
        Ok(Self {
            dir: dir.to_path_buf(),
            name: m.name,
            kind: m.kind,
            skeleton: m.skeleton,
            cameras: m.cameras,
            views: m.views.into_iter().map(ViewId).collect(),
            frames,
            canonical: CanonicalBody {
                vertices: m.vertices,
                faces: m.faces,
                weights,
                bounds: m.canonical_bounds,
            },
            options: m.options,
        })
    }

    /// The prepared frame `id`.
    pub fn frame(&self, id: FrameId) -> Option<&PreparedFrame> {
        self.frames.iter().find(|f| f.id == id)
    }

    /// Frame `id`'s blend-weight volume in pose space.
    pub fn volume(&self, id: FrameId) -> Result<BlendWeightVolume, DataError> {
        read_volume(&self.dir.join(frame_volume_name(id.0)))
    }

    /// The canonical blend-weight volume.
    pub fn canonical_volume(&self) -> Result<BlendWeightVolume, DataError> {
        read_volume(&self.dir.join(CANONICAL_VOLUME))
    }

    /// Undistorted image at the working resolution, channels in `[0, 1]`.
    pub fn image(&self, frame: FrameId, view: ViewId) -> Result<Rgb32FImage, DataError> {
        images::read_rgb(&self.image_path(frame, view))
    }

    /// [`Self::image`] as the cache stores it, 8-bit values (channel = value / 255).
    pub fn image_rgb8(&self, frame: FrameId, view: ViewId) -> Result<RgbImage, DataError> {
        images::read_rgb8(&self.image_path(frame, view))
    }

    fn image_path(&self, frame: FrameId, view: ViewId) -> PathBuf {
        self.dir.join("images").join(image_name(frame.0, view.0))
    }

    /// Undistorted mask at the working resolution: 1 = body, 0 = background.
    pub fn mask(&self, frame: FrameId, view: ViewId) -> Result<GrayImage, DataError> {
        Ok(self.mask_and_edge(frame, view)?.0)
    }

    /// The mask (as [`Self::mask`]) and the reference's mask-edge band (row-major): `dilate − erode` with a
    /// 5×5 kernel on the full-resolution mask, carried through undistortion and resizing with the mask.
    pub fn mask_and_edge(
        &self,
        frame: FrameId,
        view: ViewId,
    ) -> Result<(GrayImage, Vec<bool>), DataError> {
        let mut mask =
            images::read_gray(&self.dir.join("masks").join(image_name(frame.0, view.0)))?;
        let edge = mask.pixels().map(|p| p[0] & MASK_EDGE != 0).collect();
        mask.pixels_mut()
            .for_each(|p| p[0] = u8::from(p[0] & MASK_BODY != 0));
        Ok((mask, edge))
    }
}

/// Prepares `subject` (or reuses the cache entry of identical inputs and options) and opens the result.
pub fn prepare(subject: &Subject, options: &PrepareOptions) -> Result<PreparedSubject, DataError> {
    prepare_with(subject, options, &Silent)
}

/// [`prepare`], telling `progress` how far each phase is.
pub fn prepare_with(
    subject: &Subject,
    options: &PrepareOptions,
    progress: &dyn PrepareProgress,
) -> Result<PreparedSubject, DataError> {
    let frames = options.frames.ids(subject.frames.len());
    let views: Vec<usize> = options
        .views
        .clone()
        .unwrap_or_else(|| (0..subject.cameras.len()).collect());
    let settings = |detail: String| DataError::invalid(&subject.root, detail);
    if frames.is_empty() {
        return Err(settings(format!(
            "frame selection {:?} picks none of the {} frames",
            options.frames,
            subject.frames.len()
        )));
    }
    if let Some(v) = views.iter().find(|&&v| v >= subject.cameras.len()) {
        return Err(settings(format!(
            "view {v} does not exist (the subject has {} cameras)",
            subject.cameras.len()
        )));
    }
    let dir = entry_dir(
        &options.cache_dir,
        &fingerprint(subject, options, &frames, &views)?,
    );
    if dir.join(MANIFEST).is_file() {
        return PreparedSubject::open(&dir);
    }
    let body = &subject.body;
    let cameras: Vec<Camera> = subject
        .cameras
        .iter()
        .map(|c| working_camera(c, options.ratio))
        .collect();
    let lbs = subject.root.join("lbs");

    // The volume of a body whose vertices are `points` (in the volume's frame) into `out` unless there:
    // computed, or read from the dataset's `npy` of it.
    let write_volume = |points: &[Vec3], npy: PathBuf, out: PathBuf| -> Result<(), DataError> {
        if out.is_file() {
            return Ok(());
        }
        let vol = if options.dataset_volumes {
            dataset_volume(&npy, points, options, body.skeleton.num_joints())?
        } else {
            compute_volume(
                points,
                &body.faces,
                &body.weights,
                options.nearest,
                options.grid,
            )
        };
        Ok(write_bytes(&out, &volume_bytes(&vol))?)
    };

    // Per-frame bounds and pose-space volumes, frames in parallel (each volume is parallel too), so that one
    // frame's file is written while others compute.
    progress.start("volumes", frames.len() as u64 + 1);
    let entries = frames
        .par_iter()
        .map(|&f| {
            let rec = &subject.frames[f];
            let world = rec.vertices.read(Some(body.canonical_vertices.len()))?;
            let pose_space: Vec<Vec3> = world
                .iter()
                .map(|&x| rec.pose.global.world_to_pose(x))
                .collect();
            let bounds = Aabb::from_points(world.iter().copied())
                .expect("vertices")
                .padded(options.box_padding);
            write_volume(
                &pose_space,
                lbs.join("bweights").join(format!("{}.npy", rec.file_index)),
                dir.join(frame_volume_name(f)),
            )?;
            progress.advance();
            Ok(FrameEntry {
                id: f,
                file_index: rec.file_index,
                pose: rec.pose.clone(),
                bounds,
            })
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    let canonical_bounds = Aabb::from_points(body.canonical_vertices.iter().copied())
        .expect("vertices")
        .padded(options.box_padding);
    write_volume(
        &body.canonical_vertices,
        lbs.join("tbw.npy"),
        dir.join(CANONICAL_VOLUME),
    )?;
    progress.advance();
    progress.finish();

    // Images and masks, all (frame, view) pairs in parallel.
    let maps: Vec<Option<UndistortMap>> = subject
        .cameras
        .iter()
        .enumerate()
        .map(|(c, cam)| {
            (views.contains(&c) && !cam.distortion.is_identity())
                .then(|| UndistortMap::new(cam.intrinsics, &cam.distortion, cam.width, cam.height))
        })
        .collect();
    let jobs: Vec<(usize, usize)> = frames
        .iter()
        .flat_map(|&f| views.iter().map(move |&v| (f, v)))
        .collect();
    progress.start("images", jobs.len() as u64);
    jobs.par_iter().try_for_each(|&(f, v)| {
        let rec = &subject.frames[f];
        let (raw, work) = (&subject.cameras[v], &cameras[v]);
        let name = image_name(f, v);
        let img_out = dir.join("images").join(&name);
        if !img_out.is_file() {
            let img = images::read_rgb(&rec.images[v])?;
            check_size(&rec.images[v], img.dimensions(), raw)?;
            let img = match &maps[v] {
                Some(m) => m.remap_rgb(&img),
                None => img,
            };
            let img = resize_area(&img, work.width, work.height);
            write_bytes(&img_out, &png_rgb(&img))?;
        }
        let mask_out = dir.join("masks").join(&name);
        if !mask_out.is_file() {
            let mask = images::read_mask(&rec.masks[v])?;
            check_size(&rec.masks[v], mask.dimensions(), raw)?;
            // The reference marks the edge band on the full-resolution mask, before undistorting and
            // resizing; both travel together as the two bits of one image.
            let band = edge_band(&mask);
            let mut both = mask;
            for (p, edge) in both.pixels_mut().zip(band) {
                p[0] = if p[0] != 0 { MASK_BODY } else { 0 } | if edge { MASK_EDGE } else { 0 };
            }
            let both = match &maps[v] {
                Some(m) => m.remap_nearest(&both),
                None => both,
            };
            let both = resize_nearest(&both, work.width, work.height);
            write_bytes(&mask_out, &png_gray(&both))?;
        }
        progress.advance();
        Ok::<(), DataError>(())
    })?;
    progress.finish();

    let manifest = Manifest {
        name: subject.name.clone(),
        kind: subject.kind,
        options: options.clone(),
        skeleton: body.skeleton.clone(),
        cameras,
        views,
        frames: entries,
        vertices: body.canonical_vertices.clone(),
        faces: body.faces.clone(),
        weights: body.weights.as_slice().to_vec(),
        canonical_bounds,
    };
    let json =
        serde_json::to_vec(&manifest).map_err(|e| DataError::invalid(&dir, e.to_string()))?;
    write_bytes(&dir.join(MANIFEST), &json)?;
    PreparedSubject::open(&dir)
}

/// The camera of the undistorted image resized by `ratio`: `D = 0`, `K[:2] *= ratio`, size `int(n · ratio)`.
pub fn working_camera(raw: &Camera, ratio: ImageScale) -> Camera {
    let mut cam = Camera {
        distortion: Distortion::default(),
        ..raw.clone()
    }
    .resized(ratio.get());
    cam.width = scaled_size(raw.width, ratio);
    cam.height = scaled_size(raw.height, ratio);
    cam
}

fn check_size(path: &Path, (w, h): (u32, u32), cam: &Camera) -> Result<(), DataError> {
    if (w, h) != (cam.width, cam.height) {
        return Err(DataError::invalid(
            path,
            format!(
                "is {w}×{h}, expected {}×{} like its camera's first image",
                cam.width, cam.height
            ),
        ));
    }
    Ok(())
}

/// A reference volume file (`(Nx, Ny, Nz, K+1)` float32) with the reference's lookup bounds: the box of
/// `points` padded by 0.05 m.
fn dataset_volume(
    path: &Path,
    points: &[Vec3],
    options: &PrepareOptions,
    joints: usize,
) -> Result<BlendWeightVolume, DataError> {
    let arr = formats::read_npy(path)?;
    let s = arr.shape();
    if s.len() != 4 || s[3] != joints + 1 {
        return Err(DataError::invalid(
            path,
            format!("has shape {s:?}, expected (Nx, Ny, Nz, {})", joints + 1),
        ));
    }
    let bounds = Aabb::from_points(points.iter().copied())
        .expect("vertices")
        .padded(options.grid.padding);
    BlendWeightVolume::new(bounds, [s[0], s[1], s[2]], joints, arr.to_f32())
        .map_err(|e| DataError::invalid(path, e))
}

fn fingerprint(
    subject: &Subject,
    options: &PrepareOptions,
    frames: &[usize],
    views: &[usize],
) -> Result<String, DataError> {
    let mut fp = Fingerprint::default();
    let mut opts = options.clone();
    opts.cache_dir = PathBuf::new();
    fp.add("options", &json(&opts));
    fp.add("name", subject.name.as_bytes());
    fp.add("root", subject.root.to_string_lossy().as_bytes());
    fp.add("cameras", &json(&subject.cameras));
    fp.add("skeleton", &json(&subject.body.skeleton));
    fp.add("vertices", &json(&subject.body.canonical_vertices));
    fp.add("faces", &json(&subject.body.faces));
    fp.add("weights", &json(subject.body.weights.as_slice()));
    fp.add("views", &json(views));
    for &f in frames {
        let rec = &subject.frames[f];
        fp.add("frame", &json(&(f, rec.file_index, &rec.pose)));
        for source in rec.vertices.sources() {
            fp.add_file(source)?;
        }
        for &v in views {
            fp.add_file(&rec.images[v])?;
            fp.add_file(&rec.masks[v])?;
        }
        if options.dataset_volumes {
            fp.add_file(
                &subject
                    .root
                    .join("lbs/bweights")
                    .join(format!("{}.npy", rec.file_index)),
            )?;
        }
    }
    if options.dataset_volumes {
        fp.add_file(&subject.root.join("lbs/tbw.npy"))?;
    }
    Ok(fp.hex())
}

/// JSON bytes of plain data, for fingerprints.
fn json<T: Serialize + ?Sized>(v: &T) -> Vec<u8> {
    serde_json::to_vec(v).expect("plain data serialises")
}

fn png_rgb(img: &Rgb32FImage) -> Vec<u8> {
    let rgb = image::RgbImage::from_fn(img.width(), img.height(), |x, y| {
        image::Rgb(img.get_pixel(x, y).0.map(images::channel_byte))
    });
    encode_png(image::DynamicImage::ImageRgb8(rgb))
}

fn png_gray(img: &GrayImage) -> Vec<u8> {
    encode_png(image::DynamicImage::ImageLuma8(img.clone()))
}

fn encode_png(img: image::DynamicImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}
