//! An indexed triangle mesh with the measurements used to validate it (area, volume, edge topology).

use std::collections::HashMap;

use glam::{DVec3, Vec3};

/// Triangles over shared vertices. Vertices are in metres in whatever frame the producer states;
/// faces are counter-clockwise seen from outside, so `(b − a) × (c − a)` points outwards.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<Vec3>,
    pub faces: Vec<[u32; 3]>,
}

/// How the mesh's edges are shared, for checking that a mesh is closed and consistently oriented.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EdgeReport {
    /// Distinct undirected edges.
    pub edges: usize,
    /// Edges used by exactly one face (holes).
    pub boundary: usize,
    /// Edges used by more than two faces.
    pub non_manifold: usize,
    /// Edges shared by two faces that traverse it in the same direction (orientation flips).
    pub inconsistent: usize,
}

impl EdgeReport {
    /// Closed, two-manifold and consistently oriented: every edge is shared by exactly two faces that
    /// traverse it in opposite directions.
    pub fn is_watertight(&self) -> bool {
        self.boundary == 0 && self.non_manifold == 0 && self.inconsistent == 0
    }
}

impl TriMesh {
    fn corners(&self, f: [u32; 3]) -> [DVec3; 3] {
        f.map(|i| self.vertices[i as usize].as_dvec3())
    }

    /// Total surface area (square metres), accumulated in f64.
    pub fn area(&self) -> f64 {
        self.faces
            .iter()
            .map(|&f| {
                let [a, b, c] = self.corners(f);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Enclosed volume (cubic metres) by the divergence theorem; positive for a closed mesh whose faces
    /// point outwards, meaningless for an open one.
    pub fn signed_volume(&self) -> f64 {
        self.faces
            .iter()
            .map(|&f| {
                let [a, b, c] = self.corners(f);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Counts boundary, non-manifold and inconsistently oriented edges.
    pub fn edge_report(&self) -> EdgeReport {
        // Per undirected edge: (uses in direction lo→hi, uses in direction hi→lo).
        let mut uses: HashMap<(u32, u32), (u32, u32)> =
            HashMap::with_capacity(self.faces.len() * 2);
        for f in &self.faces {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                let e = uses.entry((a.min(b), a.max(b))).or_default();
                if a < b {
                    e.0 += 1
                } else {
                    e.1 += 1
                }
            }
        }
        let mut report = EdgeReport {
            edges: uses.len(),
            boundary: 0,
            non_manifold: 0,
            inconsistent: 0,
        };
        for &(fwd, bwd) in uses.values() {
            match fwd + bwd {
                1 => report.boundary += 1,
                2 if fwd != 1 => report.inconsistent += 1,
                2 => {}
                _ => report.non_manifold += 1,
            }
        }
        report
    }

    /// `V − E + F` (2 for a closed surface of genus 0).
    pub fn euler_characteristic(&self) -> i64 {
        self.vertices.len() as i64 - self.edge_report().edges as i64 + self.faces.len() as i64
    }

    /// Unit vertex normals: area-weighted sums of the adjacent faces' normals (outwards for an outward
    /// oriented mesh); zero for a vertex without faces.
    pub fn vertex_normals(&self) -> Vec<Vec3> {
        let mut n = vec![DVec3::ZERO; self.vertices.len()];
        for &f in &self.faces {
            let [a, b, c] = self.corners(f);
            let face = (b - a).cross(c - a); // length = twice the area
            for i in f {
                n[i as usize] += face;
            }
        }
        n.into_iter()
            .map(|v| v.normalize_or_zero().as_vec3())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit cube's corner `i` has coordinates `(i & 1, i >> 1 & 1, i >> 2 & 1)`.
    fn cube() -> TriMesh {
        let vertices = (0..8)
            .map(|i| Vec3::new((i & 1) as f32, (i >> 1 & 1) as f32, (i >> 2 & 1) as f32))
            .collect();
        let quads = [
            [0, 2, 3, 1], // z = 0, seen from −z
            [4, 5, 7, 6], // z = 1
            [0, 1, 5, 4], // y = 0
            [2, 6, 7, 3], // y = 1
            [0, 4, 6, 2], // x = 0
            [1, 3, 7, 5], // x = 1
        ];
        let faces = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        TriMesh { vertices, faces }
    }

    #[test]
    fn unit_cube_measures() {
        let m = cube();
        assert!((m.area() - 6.0).abs() < 1e-12);
        assert!((m.signed_volume() - 1.0).abs() < 1e-12);
        assert!(m.edge_report().is_watertight());
        assert_eq!(m.euler_characteristic(), 2);
        // The normal of corner 7 points along (1, 1, 1).
        let n = m.vertex_normals()[7];
        assert!(n.x > 0.3 && n.y > 0.3 && n.z > 0.3, "{n}");
    }

    #[test]
    fn holes_and_flips_are_reported() {
        let mut m = cube();
        m.faces.pop();
        let r = m.edge_report();
        assert_eq!((r.boundary, r.inconsistent, r.non_manifold), (3, 0, 0));
        let mut m = cube();
        m.faces[0].swap(1, 2);
        let r = m.edge_report();
        assert!(r.inconsistent >= 2 && !r.is_watertight(), "{r:?}");
        assert!(
            (cube().signed_volume() + {
                let mut f = cube();
                f.faces.iter_mut().for_each(|t| t.swap(1, 2));
                f.signed_volume()
            })
            .abs()
                < 1e-12
        );
    }
}
