//! A posed, vertex-coloured triangle mesh drawn into a camera's image: a z-buffer over the pixels whose
//! centre a triangle covers, colours interpolated perspective-correctly. What a real-time engine shows of
//! the exported glb (without lighting), so that the mesh can be scored by the paper's protocol as the NeRF
//! and the baked avatar are; and the same walk over the triangles for a mesh's silhouette alone (pose
//! refinement's body silhouette term).

use anerf_core::geometry::{Camera, PixelConvention};
use anerf_core::mesh::TriMesh;
use glam::{Vec2, Vec3};

/// Vertices nearer the camera than this (metres, along its axis) drop their triangle (no clipping).
const NEAR: f32 = 0.01;

/// The mesh (world-space vertices in metres, faces, per-vertex colours) seen by `camera`: `[H·W]` row-major
/// RGBA, colour on black and alpha 1 where a triangle covers the pixel (pixel `(u, v)` sampled where
/// `convention` puts it). Both windings are drawn.
pub fn rasterize_mesh(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    colours: &[[f32; 3]],
    camera: &Camera,
    convention: PixelConvention,
) -> Vec<[f32; 4]> {
    assert_eq!(vertices.len(), colours.len(), "a colour per vertex");
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut depth = vec![f32::INFINITY; w * h];
    let mut out = vec![[0.0f32; 4]; w * h];
    let projected = project(vertices, camera, convention);
    walk_faces(&projected, faces, w, h, |face, i, edges, area| {
        let l = edges.map(|e| e / area);
        let [za, zb, zc] = face.map(|v| projected[v as usize].expect("a drawn corner").1);
        // Perspective-correct: interpolate 1/z and colour/z.
        let inv = [l[0] / za, l[1] / zb, l[2] / zc];
        let z = 1.0 / (inv[0] + inv[1] + inv[2]);
        if z >= depth[i] {
            return;
        }
        depth[i] = z;
        let colour = face.map(|v| Vec3::from(colours[v as usize]));
        let rgb = (colour[0] * inv[0] + colour[1] * inv[1] + colour[2] * inv[2]) * z;
        out[i] = [rgb.x, rgb.y, rgb.z, 1.0];
    });
    out
}

/// Whether a mesh encloses a volume. Every line of sight from a camera outside a closed, consistently
/// oriented mesh that meets it crosses a face turned toward the camera, so the faces turned away add
/// nothing to its coverage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// Closed, two-manifold and consistently oriented
    /// ([`anerf_core::mesh::EdgeReport::is_watertight`]).
    Closed,
    /// Anything else: every face may cover a pixel the others do not.
    Open,
}

impl Surface {
    /// The kind of `mesh`'s surface, from its edges (a hash of every edge: compute it once per mesh).
    pub fn of(mesh: &TriMesh) -> Self {
        if mesh.edge_report().is_watertight() {
            Self::Closed
        } else {
            Self::Open
        }
    }
}

/// The pixels (`[H·W]` row-major) whose sample point a triangle of the mesh covers, as
/// [`rasterize_mesh`] draws them, without colours or depths: the mesh's silhouette. A [`Surface::Closed`]
/// mesh walks only its faces turned toward the camera (half the work; the camera must be outside it).
pub fn mesh_coverage(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    surface: Surface,
    camera: &Camera,
    convention: PixelConvention,
) -> Vec<bool> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut covered = vec![false; w * h];
    let projected = project(vertices, camera, convention);
    let visit = |_, i, _, _| covered[i] = true;
    match surface {
        Surface::Open => walk_faces(&projected, faces, w, h, visit),
        Surface::Closed => {
            let eye = camera.center();
            let toward = faces.iter().filter(|face| {
                let [a, b, c] = face.map(|v| vertices[v as usize]);
                (b - a).cross(c - a).dot(eye - a) > 0.0
            });
            walk_faces(&projected, toward, w, h, visit)
        }
    }
    covered
}

/// Pixel positions and camera depths (metres) of the vertices; `None` nearer than [`NEAR`].
fn project(
    vertices: &[Vec3],
    camera: &Camera,
    convention: PixelConvention,
) -> Vec<Option<(Vec2, f32)>> {
    vertices
        .iter()
        .map(|&x| {
            let z = camera.world_to_camera(x).z;
            (z > NEAR)
                .then(|| camera.project(x, convention).map(|p| (p, z)))
                .flatten()
        })
        .collect()
}

/// Calls `visit(face, pixel index, edge values, twice the signed area)` for every pixel of a `w × h` image
/// whose sample point a face covers (either winding; faces with a corner behind the near plane are
/// skipped). The edge values over the area are the pixel's screen-space barycentrics.
fn walk_faces<'f>(
    projected: &[Option<(Vec2, f32)>],
    faces: impl IntoIterator<Item = &'f [u32; 3]>,
    w: usize,
    h: usize,
    mut visit: impl FnMut([u32; 3], usize, [f32; 3], f32),
) {
    for &face in faces {
        let corners = face.map(|i| projected[i as usize]);
        let [Some((a, _)), Some((b, _)), Some((c, _))] = corners else {
            continue;
        };
        let area = edge(a, b, c);
        if area.abs() < 1e-12 {
            continue;
        }
        let lo = a.min(b).min(c).ceil().max(Vec2::ZERO);
        let hi = a
            .max(b)
            .max(c)
            .floor()
            .min(Vec2::new(w as f32 - 1.0, h as f32 - 1.0));
        if lo.x > hi.x || lo.y > hi.y {
            continue;
        }
        for y in lo.y as usize..=hi.y as usize {
            for x in lo.x as usize..=hi.x as usize {
                let p = Vec2::new(x as f32, y as f32);
                // Inside where every edge value has the area's sign, for either winding.
                let edges = [edge(b, c, p), edge(c, a, p), edge(a, b, p)];
                if !edges.iter().any(|&e| e * area < 0.0) {
                    visit(face, y * w + x, edges, area);
                }
            }
        }
    }
}

/// Twice the signed area of triangle `(a, b, p)`.
fn edge(a: Vec2, b: Vec2, p: Vec2) -> f32 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Mat3;

    /// A camera at the origin looking down +z with focal length `f` and principal point at the centre.
    fn camera(f: f32, size: u32) -> Camera {
        let c = size as f32 / 2.0;
        Camera::from_rows(
            [[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]],
            Mat3::IDENTITY.to_cols_array_2d(),
            [0.0; 3],
            [0.0; 5],
            size,
            size,
        )
        .unwrap()
    }

    /// A square facing the camera covers exactly the pixels inside its projection, with its colour.
    #[test]
    fn a_square_covers_its_projection_and_the_nearer_one_wins() {
        let cam = camera(20.0, 32);
        // A 1 m square at 2 m: 10 px wide around the centre (16 ± 5).
        let square = |z: f32, half: f32| {
            vec![
                Vec3::new(-half, -half, z),
                Vec3::new(half, -half, z),
                Vec3::new(half, half, z),
                Vec3::new(-half, half, z),
            ]
        };
        let mut vertices = square(2.0, 0.5);
        vertices.extend(square(1.0, 0.1)); // a smaller, nearer square in front: 4 px wide (16 ± 2)
        let faces = vec![[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]];
        let mut colours = vec![[1.0, 0.0, 0.0]; 4];
        colours.extend(vec![[0.0, 0.0, 1.0]; 4]);
        let image = rasterize_mesh(&vertices, &faces, &colours, &cam, PixelConvention::Integer);
        for y in 0..32 {
            for x in 0..32 {
                let p = image[y * 32 + x];
                let inside = |r: f32| {
                    (16.0 - r..=16.0 + r).contains(&(x as f32))
                        && (16.0 - r..=16.0 + r).contains(&(y as f32))
                };
                let want = if inside(2.0) {
                    [0.0, 0.0, 1.0, 1.0]
                } else if inside(5.0) {
                    [1.0, 0.0, 0.0, 1.0]
                } else {
                    [0.0; 4]
                };
                for k in 0..4 {
                    assert!(
                        (p[k] - want[k]).abs() < 1e-5,
                        "pixel ({x}, {y}): {p:?}, expected {want:?}"
                    );
                }
            }
        }
    }

    /// The coverage is the drawn image's alpha, for a mesh with faces of both windings, overlapping and
    /// partly off the image.
    #[test]
    fn the_coverage_is_where_the_mesh_is_drawn() {
        let cam = camera(20.0, 32);
        let vertices = vec![
            Vec3::new(-0.3, -0.4, 1.5),
            Vec3::new(0.9, -0.2, 1.2),
            Vec3::new(0.1, 0.6, 2.0),
            Vec3::new(-0.8, 0.5, 1.0),
            Vec3::new(0.0, 0.0, -1.0),
        ];
        let faces = vec![[0, 1, 2], [0, 3, 2], [1, 3, 0], [0, 1, 4]];
        let colours = vec![[0.5, 0.5, 0.5]; vertices.len()];
        let drawn = rasterize_mesh(&vertices, &faces, &colours, &cam, PixelConvention::Center);
        let covered = mesh_coverage(
            &vertices,
            &faces,
            Surface::Open,
            &cam,
            PixelConvention::Center,
        );
        assert_eq!(
            covered,
            drawn.iter().map(|p| p[3] > 0.0).collect::<Vec<_>>()
        );
        assert!(covered.iter().filter(|&&c| c).count() > 50);
    }

    /// A torus about the z axis (radii 0.5 and 0.2 m) turned `tilt` radians about x and centred at
    /// `centre`, `n × m` quads split in two, wound consistently.
    fn torus(centre: Vec3, tilt: f32, n: u32, m: u32) -> TriMesh {
        let turn = glam::Quat::from_rotation_x(tilt);
        let mut vertices = Vec::new();
        for i in 0..n {
            for j in 0..m {
                let (t, p) = (
                    std::f32::consts::TAU * i as f32 / n as f32,
                    std::f32::consts::TAU * j as f32 / m as f32,
                );
                let ring = 0.5 + 0.2 * p.cos();
                vertices
                    .push(centre + turn * Vec3::new(ring * t.cos(), ring * t.sin(), 0.2 * p.sin()));
            }
        }
        let at = |i: u32, j: u32| (i % n) * m + j % m;
        let faces = (0..n)
            .flat_map(|i| (0..m).map(move |j| (i, j)))
            .flat_map(|(i, j)| {
                [
                    [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                    [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                ]
            })
            .collect();
        TriMesh { vertices, faces }
    }

    /// A closed mesh's coverage from its faces turned toward the camera equals that of all its faces, with
    /// lines of sight crossing it up to four times (a tilted torus, its hole in view) and with its faces
    /// wound either way; a mesh with a hole is not closed.
    #[test]
    fn a_closed_mesh_is_covered_by_its_faces_toward_the_camera() {
        // A camera away from the origin, turned, so that the faces' side is judged from its own centre.
        let turn = Mat3::from_rotation_y(0.3);
        let t = Vec3::new(0.6, 0.1, 0.4);
        let cam = Camera::from_rows(
            [[90.0, 0.0, 32.0], [0.0, 90.0, 32.0], [0.0, 0.0, 1.0]],
            turn.transpose().to_cols_array_2d(),
            t.to_array(),
            [0.0; 5],
            64,
            64,
        )
        .unwrap();
        let centre = turn.transpose() * (Vec3::new(0.05, -0.1, 2.5) - t);
        assert!((cam.world_to_camera(centre) - Vec3::new(0.05, -0.1, 2.5)).length() < 1e-5);
        for tilt in [0.3f32, 1.0, 1.4] {
            let mut mesh = torus(centre, tilt, 24, 12);
            assert_eq!(Surface::of(&mesh), Surface::Closed);
            for _ in 0..2 {
                let all = mesh_coverage(
                    &mesh.vertices,
                    &mesh.faces,
                    Surface::Open,
                    &cam,
                    PixelConvention::Center,
                );
                let culled = mesh_coverage(
                    &mesh.vertices,
                    &mesh.faces,
                    Surface::Closed,
                    &cam,
                    PixelConvention::Center,
                );
                assert_eq!(culled, all, "tilt {tilt}");
                let count = all.iter().filter(|&&c| c).count();
                assert!(count > 600, "tilt {tilt}: {count} pixels covered");
                for face in &mut mesh.faces {
                    face.swap(1, 2);
                }
            }
            mesh.faces.pop();
            assert_eq!(Surface::of(&mesh), Surface::Open);
        }
    }

    /// Colour along a slanted triangle follows the surface (perspective-correct), not the screen: a linear
    /// colour ramp in depth reads, at each pixel, the ramp's value at the point that pixel's ray meets.
    #[test]
    fn colours_interpolate_perspective_correctly() {
        let cam = camera(20.0, 32);
        // A plane slanting from z = 1 (bottom edge, y = -0.5) to z = 3 (top edge, y = 0.5... in camera y).
        let vertices = vec![
            Vec3::new(-0.4, -0.5, 1.0),
            Vec3::new(0.4, -0.5, 1.0),
            Vec3::new(0.0, 0.5, 3.0),
        ];
        // The colour's red channel is z − 1: 0 at the near edge, 2 at the far apex.
        let colours = vec![[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let image = rasterize_mesh(
            &vertices,
            &[[0, 1, 2]],
            &colours,
            &cam,
            PixelConvention::Integer,
        );
        let mut checked = 0;
        for y in 0..32usize {
            let x = 16usize;
            let p = image[y * 32 + x];
            if p[3] == 0.0 {
                continue;
            }
            // The pixel's ray (0, (y − 16)/20, 1)·t meets the plane y = −0.5 + (z − 1)/2 at
            // t·v = −0.5 + (t − 1)/2 with v = (y − 16)/20, so t = 1 / (1 − 2v) · ... solved below.
            let v = (y as f32 - 16.0) / 20.0;
            let t = (-0.5 - 0.5) / (v - 0.5);
            assert!(
                (p[0] - (t - 1.0)).abs() < 1e-3,
                "row {y}: red {}, depth {t}",
                p[0]
            );
            checked += 1;
        }
        assert!(checked > 5, "the triangle covers the centre column");
    }
}
