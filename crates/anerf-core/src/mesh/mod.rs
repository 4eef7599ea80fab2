//! Triangle meshes and their extraction from scalar grids by marching cubes (synthetic bodies, mesh
//! export of trained models).

pub mod marching_cubes;
mod trimesh;

pub use marching_cubes::{marching_cubes, ScalarGrid};
pub use trimesh::{EdgeReport, TriMesh};
