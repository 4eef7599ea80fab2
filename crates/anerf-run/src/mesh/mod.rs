//! Meshing a run: the canonical mesh with its blend weights, reposed copies, and the reference's posed
//! meshes.

use std::path::{Path, PathBuf};

use anerf_core::geometry::CanonicalPose;
use anerf_core::model::AnimatableNerf;
use anerf_core::FrameId;
use anerf_data::visual_hull::VisualHull;
use anerf_eval::mesh_io::{write_obj, write_ply, MeshView, VertexAttribute};
use anyhow::{bail, Context, Result};

use crate::memory::Work;
use crate::{device, load_trained, open_run, JobOptions};
use anerf_train::experiment::Experiment;

pub mod probe;
mod skinned;
mod surface;

pub use skinned::SkinnedSurface;

pub use surface::{
    canonical_mesh, density_surface, posed_mesh, repose, CanonicalMesh, MeshJob, PosedFrame,
    MESH_CULL_DISTANCE,
};

/// A mesh written as PLY (and OBJ beside it).
#[derive(Debug, Clone)]
pub struct MeshFile {
    pub ply: PathBuf,
    pub vertices: usize,
    pub faces: usize,
}

/// What a mesh job wrote under `<run>/meshes/`.
#[derive(Debug, Clone)]
pub struct MeshFiles {
    /// The canonical mesh, with colours and `w^can` per vertex.
    pub canonical: MeshFile,
    /// The canonical mesh reposed to each `--frames` frame.
    pub reposed: Vec<(FrameId, MeshFile)>,
    /// The reference's posed mesh of each `--posed-frames` frame.
    pub posed: Vec<(FrameId, MeshFile)>,
}

/// The canonical mesh (PLY with colours and `w^can` per vertex, and OBJ) and its reposed copies under
/// `<run>/meshes/`.
pub fn mesh(run_path: &Path, job: &MeshJob, options: &JobOptions) -> Result<MeshFiles> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let device = device(&config, options)?;
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device.clone(), options.progress)?;
    let cm = canonical_surface(&model, &exp, job)?;
    let k = cm.num_joints;
    let columns: Vec<Vec<f32>> = (0..k)
        .map(|j| cm.weights.iter().skip(j).step_by(k).copied().collect())
        .collect();
    let names: Vec<String> = (0..k).map(|j| format!("w{j:02}")).collect();
    let attributes: Vec<VertexAttribute> = names
        .iter()
        .zip(&columns)
        .map(|(name, values)| VertexAttribute { name, values })
        .collect();
    let dir = run.meshes();
    let canonical = MeshView::new(&cm.mesh.vertices, &cm.mesh.faces)
        .with_colors(&cm.colors)
        .with_attributes(&attributes);
    let mut files = MeshFiles {
        canonical: write_mesh(dir.join("canonical.ply"), &canonical)?,
        reposed: Vec::new(),
        posed: Vec::new(),
    };
    for &f in &job.frames {
        let pose = exp
            .frame_pose(&model, FrameId(f))
            .with_context(|| format!("frame {f} (--frames)"))?;
        let bones = exp
            .prepared
            .skeleton
            .bone_transforms(&pose, CanonicalPose::TPose)?;
        let posed = repose(&cm.mesh.vertices, &cm.weights, &bones, &pose.global)?;
        let view = MeshView::new(&posed, &cm.mesh.faces).with_colors(&cm.colors);
        let file = write_mesh(dir.join(format!("frame_{f:06}.ply")), &view)?;
        files.reposed.push((FrameId(f), file));
    }
    for &f in &job.posed_frames {
        let mesh = reference_posed_mesh(&model, &mut exp, FrameId(f), job)
            .with_context(|| format!("the posed mesh of frame {f} (--posed-frames)"))?;
        let view = MeshView::new(&mesh.vertices, &mesh.faces);
        let file = write_mesh(dir.join(format!("posed_frame_{f:06}.ply")), &view)?;
        files.posed.push((FrameId(f), file));
    }
    Ok(files)
}

/// The run's canonical mesh at `job`'s voxel, level and smoothing, with `w^can` at its vertices and the
/// colours the NeRF shows there (the appearance code of the middle training frame; [`probe`]).
pub(crate) fn canonical_surface(
    model: &AnimatableNerf,
    exp: &Experiment,
    job: &MeshJob,
) -> Result<CanonicalMesh> {
    Ok(probed_surface(model, exp, job)?.0)
}

/// [`canonical_surface`] and what each vertex's probe found.
pub(crate) fn probed_surface(
    model: &AnimatableNerf,
    exp: &Experiment,
    job: &MeshJob,
) -> Result<(CanonicalMesh, Vec<probe::SurfaceProbe>)> {
    if !(job.voxel.is_finite() && job.voxel > 0.0) {
        bail!("--voxel {}: expected a positive size in metres", job.voxel);
    }
    let appearance = exp.train_frames.len() / 2;
    let volume = exp.prepared.canonical_volume()?;
    let mut cm = canonical_mesh(
        model,
        exp.canonical(),
        &volume,
        job,
        appearance,
        exp.config.eval.chunk,
        &exp.device,
    )?;
    if job.smooth > 0 {
        let smoothing = anerf_eval::mesh_smooth::Smoothing::taubin(job.smooth);
        cm.mesh.vertices =
            anerf_eval::mesh_smooth::smooth_vertices(&cm.mesh.vertices, &cm.mesh.faces, smoothing)?;
    }
    let probes = probe::probe_along_normals(
        model,
        exp.canonical(),
        &cm.mesh.vertices,
        &cm.mesh.vertex_normals(),
        appearance,
        exp.config.eval.chunk,
    );
    for (colour, p) in cm.colors.iter_mut().zip(&probes) {
        if p.opacity >= probe::PROBE_HIT {
            *colour = p.colour;
        }
    }
    Ok((cm, probes))
}

/// Writes `view` as PLY at `path` and as OBJ beside it.
fn write_mesh(path: PathBuf, view: &MeshView) -> Result<MeshFile> {
    write_ply(&path, view)?;
    write_obj(&path.with_extension("obj"), view)?;
    Ok(MeshFile {
        ply: path,
        vertices: view.positions.len(),
        faces: view.faces.len(),
    })
}

/// The reference's posed mesh of dataset frame `frame`, carved by the training views when `job.carve`.
fn reference_posed_mesh(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    frame: FrameId,
    job: &MeshJob,
) -> Result<anerf_core::mesh::TriMesh> {
    exp.check_renderable(frame, model)?;
    let inputs = exp.frame_inputs(frame)?;
    let hull = if job.carve {
        let radius = VisualHull::reference_radius(exp.config.dataset.ratio.get());
        Some(VisualHull::of_frame(
            &exp.prepared,
            frame,
            &exp.train_views,
            radius,
        )?)
    } else {
        None
    };
    let body = PosedFrame {
        inputs: &inputs,
        volume: &exp.prepared.volume(frame)?,
        bounds: exp.frame_bounds(frame)?,
    };
    posed_mesh(
        model,
        exp.canonical(),
        &body,
        hull.as_ref(),
        job,
        exp.config.eval.chunk,
    )
}
