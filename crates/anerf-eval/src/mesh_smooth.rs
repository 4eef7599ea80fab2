//! Smoothing of mesh vertex positions with the uniform ("umbrella") Laplacian: Gaussian smoothing, which
//! shrinks a closed surface a little more each step, and Taubin's λ|μ smoothing, which alternates a
//! shrinking and an inflating step so that the surface keeps its size (Taubin, "A signal processing
//! approach to fair surface design", SIGGRAPH 1995). The supplementary of the paper smooths its extracted
//! meshes with "Gaussian smoothing".

use glam::Vec3;

use crate::error::EvalError;
use crate::mesh_io::MeshView;

/// How to smooth vertex positions; each step moves vertex `i` by `factor · (mean of its neighbours − x_i)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Smoothing {
    /// `iterations` steps with factor `lambda` (0 < λ ≤ 1).
    Gaussian { lambda: f32, iterations: usize },
    /// `iterations` pairs of steps with factors `lambda` (> 0) then `mu` (< −λ).
    Taubin {
        lambda: f32,
        mu: f32,
        iterations: usize,
    },
}

impl Smoothing {
    /// Taubin's usual parameters: λ = 0.5, μ = −0.53 (pass-band frequency 1/λ + 1/μ ≈ 0.11).
    pub fn taubin(iterations: usize) -> Self {
        Smoothing::Taubin {
            lambda: 0.5,
            mu: -0.53,
            iterations,
        }
    }

    fn validate(self) -> Result<(), EvalError> {
        let ok = match self {
            Smoothing::Gaussian { lambda, .. } => lambda > 0.0 && lambda <= 1.0,
            Smoothing::Taubin { lambda, mu, .. } => {
                lambda > 0.0 && lambda <= 1.0 && mu < -lambda && mu >= -1.0
            }
        };
        if ok {
            Ok(())
        } else {
            Err(EvalError::InvalidInput {
                what: "smoothing",
                detail: format!("{self:?}; expected 0 < λ ≤ 1 and, for Taubin, −1 ≤ μ < −λ"),
            })
        }
    }
}

/// Smoothed copies of `positions` (metres; any frame) of the triangle mesh `faces`. Vertices without
/// neighbours stay where they are.
pub fn smooth_vertices(
    positions: &[Vec3],
    faces: &[[u32; 3]],
    smoothing: Smoothing,
) -> Result<Vec<Vec3>, EvalError> {
    smoothing.validate()?;
    MeshView::new(positions, faces).validate()?;
    let neighbours = vertex_neighbours(positions.len(), faces);
    let factors: Vec<f32> = match smoothing {
        Smoothing::Gaussian { lambda, iterations } => vec![lambda; iterations],
        Smoothing::Taubin {
            lambda,
            mu,
            iterations,
        } => [lambda, mu].repeat(iterations),
    };
    let mut current = positions.to_vec();
    for factor in factors {
        current = current
            .iter()
            .zip(&neighbours)
            .map(|(&x, near)| {
                if near.is_empty() {
                    return x;
                }
                let mean =
                    near.iter().map(|&j| current[j as usize]).sum::<Vec3>() / near.len() as f32;
                x + factor * (mean - x)
            })
            .collect();
    }
    Ok(current)
}

/// For each vertex, the sorted, distinct vertices it shares an edge with.
fn vertex_neighbours(vertices: usize, faces: &[[u32; 3]]) -> Vec<Vec<u32>> {
    let mut neighbours = vec![Vec::new(); vertices];
    for face in faces {
        for k in 0..3 {
            let (a, b) = (face[k], face[(k + 1) % 3]);
            neighbours[a as usize].push(b);
            neighbours[b as usize].push(a);
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    neighbours
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    use super::*;

    /// A unit icosphere: an icosahedron with every triangle split into four `levels` times.
    fn icosphere(levels: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut positions: Vec<Vec3> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .map(|p| Vec3::from_array(p).normalize())
        .to_vec();
        let mut faces = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..levels {
            let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
            let mut midpoint = |a: u32, b: u32, positions: &mut Vec<Vec3>| {
                *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    positions.push((positions[a as usize] + positions[b as usize]).normalize());
                    positions.len() as u32 - 1
                })
            };
            faces = faces
                .iter()
                .flat_map(|&[a, b, c]| {
                    let (ab, bc, ca) = (
                        midpoint(a, b, &mut positions),
                        midpoint(b, c, &mut positions),
                        midpoint(c, a, &mut positions),
                    );
                    [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
                })
                .collect();
        }
        (positions, faces)
    }

    /// Root-mean-square of |x| − radius.
    fn rms_radial_error(positions: &[Vec3], radius: f32) -> f32 {
        (positions
            .iter()
            .map(|p| (p.length() - radius).powi(2))
            .sum::<f32>()
            / positions.len() as f32)
            .sqrt()
    }

    fn mean_radius(positions: &[Vec3]) -> f32 {
        positions.iter().map(|p| p.length()).sum::<f32>() / positions.len() as f32
    }

    #[test]
    fn smoothing_a_noisy_sphere_reduces_its_radial_error_and_taubin_keeps_its_size() {
        // A 0.5 m sphere (2562 vertices, edges of 3 to 4 cm) with uniform radial noise of ±1 cm.
        let radius = 0.5;
        let (unit, faces) = icosphere(4);
        let mut rng = StdRng::seed_from_u64(3);
        let noisy: Vec<Vec3> = unit
            .iter()
            .map(|&u| u * (radius + rng.random_range(-0.01..0.01)))
            .collect();
        let before = rms_radial_error(&noisy, radius);

        let gaussian = smooth_vertices(
            &noisy,
            &faces,
            Smoothing::Gaussian {
                lambda: 0.5,
                iterations: 3,
            },
        )
        .unwrap();
        let taubin = smooth_vertices(&noisy, &faces, Smoothing::taubin(10)).unwrap();
        let (gaussian_error, taubin_error) = (
            rms_radial_error(&gaussian, radius),
            rms_radial_error(&taubin, radius),
        );
        let (gaussian_radius, taubin_radius) = (mean_radius(&gaussian), mean_radius(&taubin));
        println!(
            "RMS radial error: noisy {before:.5} m, Gaussian {gaussian_error:.5} m (mean radius {gaussian_radius:.5} m), \
             Taubin {taubin_error:.5} m (mean radius {taubin_radius:.5} m)"
        );
        assert!(
            gaussian_error < 0.7 * before,
            "Gaussian: {gaussian_error} vs {before}"
        );
        assert!(
            taubin_error < 0.5 * before,
            "Taubin: {taubin_error} vs {before}"
        );
        // Taubin's stated bound: the mean radius moves by less than 0.2 % (1 mm on 0.5 m).
        assert!(
            (taubin_radius - radius).abs() < 0.002 * radius,
            "Taubin mean radius {taubin_radius}"
        );
        // Gaussian smoothing shrinks the sphere, which is why Taubin exists.
        assert!(
            gaussian_radius < taubin_radius,
            "{gaussian_radius} vs {taubin_radius}"
        );
    }

    #[test]
    fn isolated_vertices_stay_and_bad_parameters_are_rejected() {
        let positions = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(5.0, 5.0, 5.0)];
        let faces = [[0, 1, 2]];
        let out = smooth_vertices(
            &positions,
            &faces,
            Smoothing::Gaussian {
                lambda: 1.0,
                iterations: 1,
            },
        )
        .unwrap();
        assert_eq!(out[3], positions[3]);
        // λ = 1 moves a triangle's vertex to the mean of the other two.
        assert!(out[0].abs_diff_eq(Vec3::new(0.5, 0.5, 0.0), 1e-6));
        let bad = Smoothing::Taubin {
            lambda: 0.5,
            mu: -0.4,
            iterations: 1,
        };
        assert!(matches!(
            smooth_vertices(&positions, &faces, bad),
            Err(EvalError::InvalidInput { .. })
        ));
        assert!(smooth_vertices(&positions, &[[0, 1, 9]], Smoothing::taubin(1)).is_err());
    }
}
