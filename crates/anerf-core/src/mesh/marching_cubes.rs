//! Marching cubes with a case table derived once from a single rule, which makes every output watertight.
//!
//! For each of the 256 corner sign patterns the table holds the iso-contour on the cube's six faces,
//! chained into closed loops. A face's contour depends only on that face's four corners, and ambiguous
//! faces (diagonal corners inside) are always resolved the same way (the inside corners are separated),
//! so two cubes sharing a face agree on it. Loops are triangulated as fans whose diagonals never lie in a
//! cube face; a loop where no such fan exists gets a centre vertex instead. Together this makes every
//! edge shared by exactly two triangles with opposite directions.

use std::sync::OnceLock;

use glam::Vec3;
use thiserror::Error;

use super::TriMesh;

/// Errors of [`ScalarGrid::new`].
#[derive(Debug, Error, Clone, PartialEq)]
pub enum GridError {
    #[error("grid of {dims:?} nodes needs {expected} values, got {got}")]
    WrongLength {
        dims: [usize; 3],
        expected: usize,
        got: usize,
    },
    #[error("grid needs at least 2 nodes per axis and a positive finite spacing, got {dims:?} and {spacing}")]
    Degenerate { dims: [usize; 3], spacing: Vec3 },
    #[error("grid value {index} is not finite ({value})")]
    NonFinite { index: usize, value: f32 },
}

/// Samples of a scalar field on a regular grid: node `(i, j, k)` sits at `origin + spacing ⊙ (i, j, k)`
/// (metres, in whatever frame the caller states) and is stored at `values[(i·ny + j)·nz + k]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarGrid {
    origin: Vec3,
    spacing: Vec3,
    dims: [usize; 3],
    values: Vec<f32>,
}

impl ScalarGrid {
    /// Validates the dimensions, the spacing and that every value is finite.
    pub fn new(
        origin: Vec3,
        spacing: Vec3,
        dims: [usize; 3],
        values: Vec<f32>,
    ) -> Result<Self, GridError> {
        if dims.iter().any(|&d| d < 2)
            || !spacing.is_finite()
            || spacing.min_element() <= 0.0
            || !origin.is_finite()
        {
            return Err(GridError::Degenerate { dims, spacing });
        }
        let expected = dims.iter().product::<usize>();
        if values.len() != expected {
            return Err(GridError::WrongLength {
                dims,
                expected,
                got: values.len(),
            });
        }
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(GridError::NonFinite {
                index,
                value: values[index],
            });
        }
        Ok(Self {
            origin,
            spacing,
            dims,
            values,
        })
    }

    /// Samples `field` at every node.
    pub fn from_fn(
        origin: Vec3,
        spacing: Vec3,
        dims: [usize; 3],
        field: impl Fn(Vec3) -> f32,
    ) -> Result<Self, GridError> {
        let mut values = Vec::with_capacity(dims.iter().product());
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    values.push(field(
                        origin + spacing * Vec3::new(i as f32, j as f32, k as f32),
                    ));
                }
            }
        }
        Self::new(origin, spacing, dims, values)
    }

    /// Node counts along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    fn index(&self, n: [usize; 3]) -> usize {
        (n[0] * self.dims[1] + n[1]) * self.dims[2] + n[2]
    }

    fn position(&self, n: [usize; 3]) -> Vec3 {
        self.origin + self.spacing * Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32)
    }
}

/// The iso-surface `value = iso` of `grid`, with faces counter-clockwise seen from the side where the
/// values are larger (for a signed distance, negative inside, the normals point outwards). Nodes with
/// `value < iso` are inside. Every edge is shared by two faces except where the surface leaves the grid;
/// when all boundary nodes are outside, the mesh is closed. Vertices on grid edges are shared by all
/// adjacent cubes; the few loops that cannot be fanned get one extra vertex at their centre.
pub fn marching_cubes(grid: &ScalarGrid, iso: f32) -> TriMesh {
    let table = case_table();
    let [nx, ny, nz] = grid.dims;
    let mut edge_vertex = vec![[u32::MAX; 3]; grid.values.len()];
    let mut mesh = TriMesh::default();
    let mut ids = Vec::with_capacity(12);
    for i in 0..nx - 1 {
        for j in 0..ny - 1 {
            for k in 0..nz - 1 {
                let node = |c: usize| [i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)];
                let value = |c: usize| grid.values[grid.index(node(c))];
                let case = (0..8)
                    .filter(|&c| value(c) < iso)
                    .fold(0, |acc, c| acc | 1 << c);
                for poly in &table[case] {
                    ids.clear();
                    for &e in &poly.edges {
                        let (a, b) = EDGES[e as usize];
                        let axis = e as usize / 4;
                        let slot = &mut edge_vertex[grid.index(node(a))][axis];
                        if *slot == u32::MAX {
                            let (fa, fb) = (value(a), value(b));
                            let t = ((iso - fa) / (fb - fa)).clamp(0.0, 1.0);
                            let (pa, pb) = (grid.position(node(a)), grid.position(node(b)));
                            *slot = mesh.vertices.len() as u32;
                            mesh.vertices.push(pa + (pb - pa) * t);
                        }
                        ids.push(*slot);
                    }
                    let n = ids.len();
                    match poly.apex {
                        Some(r) => {
                            for s in 1..n - 1 {
                                mesh.faces
                                    .push([ids[r], ids[(r + s) % n], ids[(r + s + 1) % n]]);
                            }
                        }
                        None => {
                            let centre =
                                ids.iter().map(|&v| mesh.vertices[v as usize]).sum::<Vec3>()
                                    / n as f32;
                            let c = mesh.vertices.len() as u32;
                            mesh.vertices.push(centre);
                            for s in 0..n {
                                mesh.faces.push([c, ids[s], ids[(s + 1) % n]]);
                            }
                        }
                    }
                }
            }
        }
    }
    mesh
}

/// Cube corner `c` is the node offset `(c & 1, c >> 1 & 1, c >> 2 & 1)`. Edge `e` joins corners
/// `EDGES[e]` (lower corner first) along axis `e / 4`.
const EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// One contour loop of a case: the cube edges it crosses, in order, and the fan apex (position in
/// `edges`), or `None` for a centre-vertex fan.
#[derive(Debug, Clone)]
struct Polygon {
    edges: Vec<u8>,
    apex: Option<usize>,
}

fn case_table() -> &'static [Vec<Polygon>; 256] {
    static TABLE: OnceLock<[Vec<Polygon>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(case_polygons))
}

fn corner_point(c: usize) -> Vec3 {
    Vec3::new((c & 1) as f32, (c >> 1 & 1) as f32, (c >> 2 & 1) as f32)
}

fn edge_between(a: usize, b: usize) -> usize {
    let key = (a.min(b), a.max(b));
    EDGES
        .iter()
        .position(|&e| e == key)
        .expect("corners of a face side are cube neighbours")
}

fn edge_midpoint(e: usize) -> Vec3 {
    let (a, b) = EDGES[e];
    (corner_point(a) + corner_point(b)) * 0.5
}

/// The faces (axis, side) that contain edge `e`.
fn edge_faces(e: usize) -> [(usize, usize); 2] {
    let axis = e / 4;
    let corner = EDGES[e].0;
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    [(u, corner >> u & 1), (v, corner >> v & 1)]
}

fn share_a_face(a: usize, b: usize) -> bool {
    let fb = edge_faces(b);
    edge_faces(a).iter().any(|f| fb.contains(f))
}

fn case_polygons(case: usize) -> Vec<Polygon> {
    let inside = |c: usize| case >> c & 1 == 1;
    // Oriented contour segments on the six faces: next[a] = b.
    let mut next = [usize::MAX; 12];
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2 {
            let q: [usize; 4] =
                [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(bu, bv)| side << axis | bu << u | bv << v);
            let e = |i: usize| edge_between(q[i], q[(i + 1) % 4]);
            let crossing: Vec<usize> = (0..4)
                .filter(|&i| inside(q[i]) != inside(q[(i + 1) % 4]))
                .map(e)
                .collect();
            let segments = match crossing.len() {
                2 => vec![(crossing[0], crossing[1])],
                // Ambiguous face: cut off each inside corner on its own.
                4 if inside(q[0]) => vec![(e(3), e(0)), (e(1), e(2))],
                4 => vec![(e(0), e(1)), (e(2), e(3))],
                _ => vec![],
            };
            let mut normal = Vec3::ZERO;
            normal[axis] = if side == 1 { 1.0 } else { -1.0 };
            for (a, b) in segments {
                // Orient a→b so that normal × (b − a) points away from the inside corners.
                let (ma, mb) = (edge_midpoint(a), edge_midpoint(b));
                let corner = EDGES[a].0;
                let s = normal.cross(mb - ma).dot(corner_point(corner) - ma);
                let (from, to) = if inside(corner) == (s < 0.0) {
                    (a, b)
                } else {
                    (b, a)
                };
                debug_assert_eq!(
                    next[from],
                    usize::MAX,
                    "case {case}: edge {from} starts two segments"
                );
                next[from] = to;
            }
        }
    }
    let mut used = [false; 12];
    let mut polygons = Vec::new();
    for start in 0..12 {
        if next[start] == usize::MAX || used[start] {
            continue;
        }
        let mut edges = Vec::new();
        let mut e = start;
        while !used[e] {
            used[e] = true;
            edges.push(e as u8);
            e = next[e];
        }
        debug_assert_eq!(e, start, "case {case}: contour does not close");
        let n = edges.len();
        let apex = (0..n).find(|&r| {
            (2..n - 1).all(|s| !share_a_face(edges[r] as usize, edges[(r + s) % n] as usize))
        });
        polygons.push(Polygon { edges, apex });
    }
    polygons
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere_mesh(radius: f32, spacing: f32) -> TriMesh {
        let n = (2.0 * (radius + 2.0 * spacing) / spacing).ceil() as usize + 1;
        let origin = Vec3::splat(-(radius + 2.0 * spacing)) + Vec3::new(0.0013, -0.0021, 0.0007);
        let grid = ScalarGrid::from_fn(origin, Vec3::splat(spacing), [n; 3], |p| {
            p.length() - radius
        })
        .unwrap();
        marching_cubes(&grid, 0.0)
    }

    #[test]
    fn sphere_is_closed_and_measures_right() {
        // Vertices lie on the sphere up to the linear-interpolation error, and faces are chords, so area
        // and volume approach 4πr² and 4/3πr³ from below with an error O((h/r)²).
        let r = 0.5f64;
        for (h, bound) in [(0.1, 0.03), (0.05, 0.008), (0.025, 0.002)] {
            let mesh = sphere_mesh(r as f32, h as f32);
            let report = mesh.edge_report();
            assert!(report.is_watertight(), "h = {h}: {report:?}");
            assert_eq!(mesh.euler_characteristic(), 2, "h = {h}");
            let area = 4.0 * std::f64::consts::PI * r * r;
            let volume = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
            let (ea, ev) = (
                1.0 - mesh.area() / area,
                1.0 - mesh.signed_volume() / volume,
            );
            println!(
                "h = {h}: {} vertices, relative area error {ea:.5}, volume error {ev:.5}",
                mesh.vertices.len()
            );
            assert!(
                ea.abs() < bound && ev.abs() < bound,
                "h = {h}: area error {ea}, volume error {ev}"
            );
            for v in &mesh.vertices {
                assert!(
                    (v.length() as f64 - r).abs() < 0.5 * h * h / r + 1e-5,
                    "{v}"
                );
            }
        }
    }

    /// A field whose sign changes from node to node exercises every case, ambiguous faces included.
    #[test]
    fn random_fields_give_watertight_meshes() {
        let mut state = 0x1234_5678_9abc_def0u64;
        let mut rand = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        for _ in 0..20 {
            let n = 9;
            let mut values = Vec::with_capacity(n * n * n);
            for i in 0..n {
                for j in 0..n {
                    for k in 0..n {
                        let border = [i, j, k].iter().any(|&c| c == 0 || c == n - 1);
                        values.push(if border { 1.0 } else { rand() });
                    }
                }
            }
            let grid = ScalarGrid::new(Vec3::ZERO, Vec3::ONE, [n; 3], values).unwrap();
            let mesh = marching_cubes(&grid, 0.0);
            let report = mesh.edge_report();
            assert!(report.is_watertight(), "{report:?}");
            assert!(mesh.signed_volume() > 0.0);
        }
    }

    #[test]
    fn every_case_closes_into_loops_covering_its_crossings() {
        for case in 0..256 {
            let crossed = EDGES
                .iter()
                .filter(|&&(a, b)| (case >> a & 1) != (case >> b & 1))
                .count();
            let covered: usize = case_table()[case].iter().map(|p| p.edges.len()).sum();
            assert_eq!(crossed, covered, "case {case}");
        }
        // Most loops fan without a centre vertex.
        let fans = case_table()
            .iter()
            .flatten()
            .filter(|p| p.apex.is_some())
            .count();
        let all = case_table().iter().flatten().count();
        assert!(fans * 10 > all * 9, "{fans} of {all}");
    }

    #[test]
    fn invalid_grids_are_rejected() {
        assert!(matches!(
            ScalarGrid::new(Vec3::ZERO, Vec3::ONE, [2, 2, 2], vec![0.0; 7]),
            Err(GridError::WrongLength { .. })
        ));
        assert!(matches!(
            ScalarGrid::new(Vec3::ZERO, Vec3::ONE, [1, 2, 2], vec![0.0; 4]),
            Err(GridError::Degenerate { .. })
        ));
        let mut v = vec![0.0; 8];
        v[5] = f32::NAN;
        assert!(matches!(
            ScalarGrid::new(Vec3::ZERO, Vec3::ONE, [2, 2, 2], v),
            Err(GridError::NonFinite { index: 5, .. })
        ));
    }
}
