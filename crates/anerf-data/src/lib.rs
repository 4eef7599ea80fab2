//! Data for anerf: the on-disk formats of ZJU-MoCap and Human3.6M (`.npy`, a restricted pickle reader,
//! images and masks), their loaders into one [`Subject`] type, preprocessing caches, ray sampling, and the
//! built-in synthetic subjects.

pub mod atomic;
pub mod error;
pub mod formats;
pub mod info;
pub mod loaders;
pub mod mask_distance;
pub mod motion;
pub mod paths;
pub mod prepare;
pub mod sampler;
pub mod smpl;
pub mod splits;
pub mod subject;
pub mod synthetic;
pub mod visual_hull;
pub mod zju_layout;

pub use error::DataError;
pub use info::{inspect, InspectOptions, Report};
pub use loaders::{load, load_h36m, load_zju_mocap, LoadOptions};
pub use prepare::{prepare, prepare_with, PrepareOptions, PrepareProgress, PreparedSubject};
pub use sampler::{
    draw_step, image_rays, BackgroundPlate, Backgrounds, DrawError, DrawnStep, ImageCache,
    ImageRays, ImageView, MaskEdges, Pixels, Prefetch, RaySampler, SamplerOptions, StepImages,
    StepPlan,
};
pub use subject::{
    BodyModel, DatasetKind, FittedPose, FrameRecord, PosedVertices, SkinningWeights, Subject,
};
