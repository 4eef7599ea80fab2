//! Evaluation and outputs of anerf: PSNR and SSIM with the paper's protocol, image comparison, image and
//! video files, metric reports, and mesh export (PLY, OBJ, skinned glTF).

pub mod compare;
pub mod error;
pub mod gltf_export;
pub mod heatmap;
pub mod images;
pub mod mesh_io;
pub mod mesh_raster;
pub mod mesh_smooth;
pub mod metrics;
pub mod pixels;
pub mod plots;
pub mod report;
pub mod silhouette;
pub mod splat_ply;

pub use compare::{compare_files, Comparison};
pub use error::{EvalError, MetricError};
pub use metrics::ImageMetrics;
pub use pixels::{ImageSize, PixelMask, PixelRect, RgbImageExt};
