//! `anerf render`: an orbit, the novel-pose frames or the poses of pose files, as PNGs, a GIF and an MP4.

use std::path::PathBuf;

use anerf_train::jobs::{self, RenderJob, Rendered};
use anyhow::Result;
use clap::Args;

use crate::cli::Common;

#[derive(Debug, Args)]
pub struct RenderArgs {
    pub run: PathBuf,
    /// Frame to orbit around (a training or novel-pose frame index of the dataset).
    #[arg(long)]
    pub frame: Option<usize>,
    /// Number of orbit views.
    #[arg(long, default_value_t = 36)]
    pub views: usize,
    /// Render the run's novel-pose frames from this camera instead of an orbit.
    #[arg(long, conflicts_with = "poses")]
    pub novel_poses_from_view: Option<usize>,
    /// Render the poses of this pose file, or of every pose file in this folder (`params/{i}.npy` format:
    /// `poses`, `Rh`, `Th`), after fitting their blend-weight codes with the run's `[animate]` settings.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Dataset camera of `--poses` (default: the first training view).
    #[arg(long, requires = "poses")]
    pub view: Option<usize>,
    /// Output image size (width = height) of the orbit; default: the dataset's.
    #[arg(long)]
    pub size: Option<u32>,
    #[command(flatten)]
    pub common: Common,
}

impl RenderArgs {
    fn job(&self) -> RenderJob {
        match (&self.poses, self.novel_poses_from_view) {
            (Some(path), _) => RenderJob::PoseFiles {
                path: path.clone(),
                view: self.view,
            },
            (None, Some(view)) => RenderJob::NovelPoses { view },
            (None, None) => RenderJob::Orbit {
                frame: self.frame,
                views: self.views,
                size: self.size,
            },
        }
    }
}

pub fn run(args: &RenderArgs) -> Result<Rendered> {
    let rendered = jobs::render(&args.run, args.job(), &args.common.options())?;
    print(&rendered);
    Ok(rendered)
}

/// Where the images went.
pub fn print(r: &Rendered) {
    if let Some(mp4) = &r.mp4 {
        println!("wrote {}", mp4.display());
    }
    println!(
        "wrote {} frames to {} and {}",
        r.frames,
        r.dir.display(),
        r.gif.display()
    );
}
