//! `anerf render`: an orbit, the novel-pose frames or a motion, as PNGs, a GIF and an MP4.

use std::path::PathBuf;

use anerf_run::{MotionCamera, RenderJob, Rendered};
use anyhow::Result;
use clap::Args;

use crate::args::{AvatarArgs, Common, MotionArgs};

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
    #[arg(long, conflicts_with = "motion")]
    pub novel_poses_from_view: Option<usize>,
    /// Drive the avatar with a motion (its stage-2 field is fitted with the run's `[animate]` settings and
    /// stored in `<run>/motions/` unless stored already; see `anerf animate --motion`).
    #[command(flatten)]
    pub motion: MotionArgs,
    /// Dataset camera of `--motion` (default: the first training view).
    #[arg(long, requires = "motion", conflicts_with = "orbit")]
    pub view: Option<usize>,
    /// Render `--motion` from the first training view's camera circling the body once.
    #[arg(long, requires = "motion")]
    pub orbit: bool,
    /// Output image size (width = height) of an orbit or a motion; default: the dataset's.
    #[arg(long)]
    pub size: Option<u32>,
    #[command(flatten)]
    pub avatar: AvatarArgs,
    #[command(flatten)]
    pub common: Common,
}

impl RenderArgs {
    fn job(&self) -> RenderJob {
        match (self.motion.request(), self.novel_poses_from_view) {
            (Some(request), _) => RenderJob::Motion {
                request,
                camera: if self.orbit {
                    MotionCamera::Orbit
                } else {
                    MotionCamera::View(self.view)
                },
                size: self.size,
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
    let rendered = anerf_run::render(
        &args.run,
        args.job(),
        args.avatar.avatar(),
        &args.common.options(),
    )?;
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
