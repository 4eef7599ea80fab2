//! Ground-truth images by rasterising the posed mesh: a z-buffer over a supersampled grid, perspective-
//! correct interpolation of canonical and world positions and normals, and exact masks, over black or a
//! backdrop ([`super::backdrop`]). Independent of the NeRF renderer on purpose.
//!
//! The mask is the set of pixels whose square touches the projected surface (conservative coverage,
//! computed exactly per triangle, not from samples), so it holds every pixel with any colour and the
//! projection of every vertex.
//!
//! Pixel `(u, v)` (column, row) covers `[u − ½, u + ½] × [v − ½, v + ½]` in the camera's pixel
//! coordinates, so its centre is the integer point the reference's rays go through. With lens distortion
//! the vertices are projected through it (raw images are distorted) and triangles stay straight between
//! them, which is exact at the vertices and off by the curvature of the distortion across one triangle
//! (measured: at most 0.007 px at edge midpoints for the tiny preset, 64 px with |k1| ≤ 0.03).

use anerf_core::geometry::Camera;
use glam::{Vec2, Vec3};

use super::backdrop::PlateAt;

/// A posed mesh with what is needed to colour it.
pub struct Scene<'a> {
    /// Vertices in world space (metres).
    pub world: &'a [Vec3],
    /// Unit outward normals of the posed surface at the vertices (world space).
    pub world_normals: &'a [Vec3],
    /// Triangles, counter-clockwise seen from outside.
    pub faces: &'a [[u32; 3]],
    /// The same vertices in canonical space, and their canonical normals: the albedo is a function of
    /// these, so it follows the body.
    pub canonical: &'a [Vec3],
    pub normals: &'a [Vec3],
}

/// One visible surface sample, as the rasteriser hands it to the shader.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Canonical position (metres) and unit outward canonical normal.
    pub canonical: Vec3,
    pub canonical_normal: Vec3,
    /// World position (metres) and unit outward normal of the posed surface.
    pub world: Vec3,
    pub world_normal: Vec3,
}

/// One rendered view: 8-bit RGB (row-major, 3 bytes per pixel) and a mask (255 where the pixel's square
/// touches the projected body, 0 elsewhere; on black, colours are exactly 0 outside the mask).
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedView {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    pub mask: Vec<u8>,
}

/// Cameras closer than this to a vertex (metres, along the optical axis) drop its triangles.
const NEAR: f32 = 0.05;

/// The z-buffer of one camera over its `samples × samples` supersampled grid.
struct ZBuffer {
    /// Grid width (image width × samples).
    width: usize,
    /// Inverse camera-space depth (1/metres) of the nearest front face per sample; 0 = empty.
    inverse_depth: Vec<f32>,
    /// Per sample: the face seen and its perspective-correct barycentrics `b1`, `b2` (`u32::MAX` = none).
    hit: Vec<(u32, f32, f32)>,
}

/// Rasterises the front faces of `world`/`faces` (world space, metres) into `camera`'s grid of
/// `samples × samples` points per pixel; with `mask`, also marks every pixel a face touches
/// ([`cover_pixels`], front and back faces).
fn rasterize(
    camera: &Camera,
    world: &[Vec3],
    faces: &[[u32; 3]],
    samples: u32,
    mut mask: Option<&mut [u8]>,
) -> ZBuffer {
    let s = samples as usize;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let (sw, sh) = (w * s, h * s);
    // Per vertex: position in sample-grid units and inverse depth (0 = unusable).
    let projected: Vec<(Vec2, f32)> = world
        .iter()
        .map(|&x| {
            let z = camera.world_to_camera(x).z;
            match camera.project_distorted(x) {
                Some(px) if z > NEAR => ((px + Vec2::splat(0.5)) * samples as f32, 1.0 / z),
                _ => (Vec2::ZERO, 0.0),
            }
        })
        .collect();
    let mut depth = vec![0.0f32; sw * sh];
    let mut hit = vec![(u32::MAX, 0.0f32, 0.0f32); sw * sh];
    for (fi, f) in faces.iter().enumerate() {
        let [(p0, iz0), (p1, iz1), (p2, iz2)] = f.map(|i| projected[i as usize]);
        if iz0 == 0.0 || iz1 == 0.0 || iz2 == 0.0 {
            continue;
        }
        if let Some(mask) = mask.as_deref_mut() {
            // Back faces too: for a closed mesh their union is the same silhouette, and every vertex is
            // then covered by a face it belongs to.
            cover_pixels(
                mask,
                w,
                h,
                [p0, p1, p2].map(|p| p / samples as f32 - Vec2::splat(0.5)),
            );
        }
        let area = (p1 - p0).perp_dot(p2 - p0);
        // Image y points down, so a face turned towards the camera has negative area; the mesh is
        // closed, so back faces are always hidden behind front faces.
        if area >= 0.0 || !area.is_finite() {
            continue;
        }
        let lo = p0.min(p1).min(p2);
        let hi = p0.max(p1).max(p2);
        let (x0, x1) = (
            (lo.x - 0.5).ceil().max(0.0) as usize,
            ((hi.x - 0.5).floor() + 1.0).clamp(0.0, sw as f32) as usize,
        );
        let (y0, y1) = (
            (lo.y - 0.5).ceil().max(0.0) as usize,
            ((hi.y - 0.5).floor() + 1.0).clamp(0.0, sh as f32) as usize,
        );
        for y in y0..y1 {
            for x in x0..x1 {
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let b0 = (p2 - p1).perp_dot(p - p1) / area;
                let b1 = (p0 - p2).perp_dot(p - p2) / area;
                let b2 = 1.0 - b0 - b1;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                // 1/z is affine in screen space; attributes are affine after division by z.
                let iz = b0 * iz0 + b1 * iz1 + b2 * iz2;
                let i = y * sw + x;
                if iz > depth[i] {
                    depth[i] = iz;
                    hit[i] = (fi as u32, b1 * iz1 / iz, b2 * iz2 / iz);
                }
            }
        }
    }
    ZBuffer {
        width: sw,
        inverse_depth: depth,
        hit,
    }
}

/// Renders `scene` seen by `camera` with `samples × samples` samples per pixel, colouring each visible
/// sample with `shade` (linear RGB, clamped to `[0, 1]`), each other sample with `backdrop` (the same
/// camera's and `samples`; black without one) and averaging.
pub fn render(
    camera: &Camera,
    scene: &Scene,
    samples: u32,
    shade: impl Fn(&Surface) -> Vec3,
    backdrop: Option<PlateAt>,
) -> RenderedView {
    let s = samples as usize;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut mask = vec![0u8; w * h];
    let z = rasterize(camera, scene.world, scene.faces, samples, Some(&mut mask));
    let mut rgb = vec![0u8; w * h * 3];
    let weight = 1.0 / (s * s) as f32;
    let lerp = |values: &[Vec3], [i0, i1, i2]: [usize; 3], b: Vec3| {
        values[i0] * b.x + values[i1] * b.y + values[i2] * b.z
    };
    for v in 0..h {
        for u in 0..w {
            let mut sum = Vec3::ZERO;
            let mut covered = false;
            for sy in 0..s {
                for sx in 0..s {
                    let (fi, b1, b2) = z.hit[(v * s + sy) * z.width + u * s + sx];
                    if fi == u32::MAX {
                        if let Some(plate) = backdrop {
                            covered = true;
                            sum += plate.at(u * s + sx, v * s + sy);
                        }
                        continue;
                    }
                    covered = true;
                    let corners = scene.faces[fi as usize].map(|i| i as usize);
                    let b = Vec3::new(1.0 - b1 - b2, b1, b2);
                    let surface = Surface {
                        canonical: lerp(scene.canonical, corners, b),
                        canonical_normal: lerp(scene.normals, corners, b).normalize_or_zero(),
                        world: lerp(scene.world, corners, b),
                        world_normal: lerp(scene.world_normals, corners, b).normalize_or_zero(),
                    };
                    sum += shade(&surface).clamp(Vec3::ZERO, Vec3::ONE);
                }
            }
            if covered {
                let i = v * w + u;
                let c = sum * weight * 255.0;
                rgb[3 * i..3 * i + 3].copy_from_slice(&[c.x, c.y, c.z].map(|x| x.round() as u8));
            }
        }
    }
    RenderedView {
        width: camera.width,
        height: camera.height,
        rgb,
        mask,
    }
}

/// The depth of the nearest front face seen by a pinhole camera (no distortion), per pixel: a light's
/// shadow map.
#[derive(Debug, Clone)]
pub struct DepthMap {
    pub camera: Camera,
    /// Row-major inverse camera-space depth (1/metres); 0 where no surface is seen.
    inverse_depth: Vec<f32>,
}

impl DepthMap {
    /// Rasterises the front faces of a mesh (world space, metres) at one sample per pixel.
    pub fn render(camera: Camera, world: &[Vec3], faces: &[[u32; 3]]) -> Self {
        let z = rasterize(&camera, world, faces, 1, None);
        Self {
            camera,
            inverse_depth: z.inverse_depth,
        }
    }

    /// Camera-space depth (metres) of the nearest surface through pixel `(u, v)`; `None` where the pixel is
    /// empty or outside the image.
    pub fn depth(&self, u: i64, v: i64) -> Option<f32> {
        let (w, h) = (self.camera.width as i64, self.camera.height as i64);
        if !(0..w).contains(&u) || !(0..h).contains(&v) {
            return None;
        }
        let iz = self.inverse_depth[(v * w + u) as usize];
        (iz > 0.0).then(|| 1.0 / iz)
    }

    /// The fraction of the 3×3 pixels around world point `x`'s projection whose nearest surface is not
    /// in front of `x` by more than `bias` metres (percentage-closer filtering): 1 lit, 0 in shadow.
    pub fn visibility(&self, x: Vec3, bias: f32) -> f32 {
        let z = self.camera.world_to_camera(x).z;
        let Some(p) = self.camera.project_distorted(x).filter(|_| z > NEAR) else {
            return 1.0;
        };
        let (u, v) = (p.x.round() as i64, p.y.round() as i64);
        let mut lit = 0;
        for dv in -1..=1 {
            for du in -1..=1 {
                if self.depth(u + du, v + dv).is_none_or(|d| z <= d + bias) {
                    lit += 1;
                }
            }
        }
        lit as f32 / 9.0
    }
}

/// Sets to 255 every pixel of `mask` (`w × h`) whose closed square `[u ± ½] × [v ± ½]` meets the closed
/// triangle `t` (pixel coordinates), by separating axes: the two image axes (bounding boxes) and the
/// triangle's three edge normals.
fn cover_pixels(mask: &mut [u8], w: usize, h: usize, t: [Vec2; 3]) {
    let area = (t[1] - t[0]).perp_dot(t[2] - t[0]);
    if area == 0.0 || !area.is_finite() {
        return; // degenerate: its points belong to the neighbouring faces
    }
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    let (u0, u1) = (
        (lo.x - 0.5).ceil().max(0.0),
        (hi.x + 0.5).floor().min(w as f32 - 1.0),
    );
    let (v0, v1) = (
        (lo.y - 0.5).ceil().max(0.0),
        (hi.y + 0.5).floor().min(h as f32 - 1.0),
    );
    if u0 > u1 || v0 > v1 {
        return;
    }
    // Edge k runs t[k] → t[k+1]; `inward[k] · (p − t[k]) ≥ 0` inside.
    let inward: [Vec2; 3] = std::array::from_fn(|k| (t[(k + 1) % 3] - t[k]).perp() * area.signum());
    for v in v0 as usize..=v1 as usize {
        for u in u0 as usize..=u1 as usize {
            let c = Vec2::new(u as f32, v as f32);
            let separated = (0..3).any(|k| {
                // The square's corner furthest along the inward normal.
                let corner =
                    c + Vec2::new(0.5f32.copysign(inward[k].x), 0.5f32.copysign(inward[k].y));
                inward[k].dot(corner - t[k]) < 0.0
            });
            if !separated {
                mask[v * w + u] = 255;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_core::geometry::Distortion;
    use anerf_core::mesh::{marching_cubes, ScalarGrid};
    use glam::Mat3;

    fn camera(distortion: [f32; 5]) -> Camera {
        // At (0, −3, 0) looking along +y, z up.
        let rotation = Mat3::from_cols(Vec3::X, -Vec3::Z, Vec3::Y).transpose();
        Camera {
            intrinsics: Mat3::from_cols(
                Vec3::new(100.0, 0.0, 0.0),
                Vec3::new(0.0, 100.0, 0.0),
                Vec3::new(31.5, 32.0, 1.0),
            ),
            rotation,
            translation: -(rotation * Vec3::new(0.0, -3.0, 0.0)),
            distortion: Distortion(distortion),
            width: 64,
            height: 64,
        }
    }

    /// A marching-cubes sphere about the origin whose canonical space is its world space.
    struct Sphere {
        mesh: anerf_core::mesh::TriMesh,
        normals: Vec<Vec3>,
    }

    impl Sphere {
        fn new(r: f32) -> Self {
            let h = 0.05;
            let n = (2.0 * r / h) as usize + 5;
            let origin = Vec3::splat(-(n as f32 - 1.0) * h / 2.0);
            let grid =
                ScalarGrid::from_fn(origin, Vec3::splat(h), [n; 3], |p| p.length() - r).unwrap();
            let mesh = marching_cubes(&grid, 0.0);
            let normals = mesh.vertex_normals();
            Self { mesh, normals }
        }

        fn scene(&self) -> Scene<'_> {
            Scene {
                world: &self.mesh.vertices,
                world_normals: &self.normals,
                faces: &self.mesh.faces,
                canonical: &self.mesh.vertices,
                normals: &self.normals,
            }
        }
    }

    #[test]
    fn a_sphere_covers_the_disc_it_projects_to() {
        let r = 0.6;
        let sphere = Sphere::new(r);
        let scene = sphere.scene();
        let cam = camera([0.0; 5]);
        let view = render(&cam, &scene, 4, |_| Vec3::ONE, None);
        // The silhouette of a sphere at distance d seen by a pinhole is a disc of radius f·r/√(d² − r²).
        let radius = 100.0 * r / (9.0f32 - r * r).sqrt();
        let centre = Vec2::new(31.5, 32.0);
        let mut coverage = 0.0;
        for v in 0..64 {
            for u in 0..64 {
                let d = (Vec2::new(u as f32, v as f32) - centre).length();
                let i = v * 64 + u;
                if d < radius - 1.5 {
                    assert_eq!(
                        (view.mask[i], view.rgb[3 * i]),
                        (255, 255),
                        "inside at {u},{v}"
                    );
                }
                if d > radius + 1.0 {
                    assert_eq!(
                        (view.mask[i], view.rgb[3 * i]),
                        (0, 0),
                        "outside at {u},{v}"
                    );
                }
                coverage += view.rgb[3 * i] as f32 / 255.0;
            }
        }
        // Anti-aliased coverage adds up to the disc's area (the mesh's chords shrink it slightly).
        let area = std::f32::consts::PI * radius * radius;
        assert!((coverage / area - 1.0).abs() < 0.02, "{coverage} vs {area}");
    }

    #[test]
    fn nearer_surfaces_hide_farther_ones() {
        // The visible part of a sphere seen from distance 3 is the cap y < −r²/3 facing the camera.
        let sphere = Sphere::new(0.6);
        let scene = sphere.scene();
        let view = render(
            &camera([0.0; 5]),
            &scene,
            1,
            |s| Vec3::splat(0.5 - s.canonical.y),
            None,
        );
        let mut seen = 0;
        for i in 0..64 * 64 {
            if view.rgb[3 * i] > 0 {
                seen += 1;
                assert!(
                    view.rgb[3 * i] as f32 >= 255.0 * (0.5 + 0.6 * 0.6 / 3.0) - 8.0,
                    "back of the sphere at {i}"
                );
            }
        }
        assert!(seen > 300, "{seen}");
    }

    #[test]
    fn interpolation_is_perspective_correct() {
        // A floor 0.5 m below the camera, receding from 1 m to 20 m: each pixel below the horizon must see
        // the floor point its ray hits, whose depth an affine interpolation would get badly wrong.
        let world = [
            Vec3::new(-3.0, -2.0, -0.5),
            Vec3::new(3.0, -2.0, -0.5),
            Vec3::new(3.0, 17.0, -0.5),
            Vec3::new(-3.0, 17.0, -0.5),
        ];
        let faces = [[0, 1, 2], [0, 2, 3]];
        let normals = [Vec3::Z; 4];
        let scene = Scene {
            world: &world,
            world_normals: &normals,
            faces: &faces,
            canonical: &world,
            normals: &normals,
        };
        let cam = camera([0.0; 5]);
        let view = render(
            &cam,
            &scene,
            1,
            |s| Vec3::splat((s.canonical.y + 3.0) / 20.0),
            None,
        );
        let mut checked = 0;
        for v in 40..64 {
            for u in [10, 31, 50] {
                let ray = cam.pixel_ray(
                    u as f32,
                    v as f32,
                    anerf_core::geometry::PixelConvention::Integer,
                );
                let t = (-0.5 - ray.origin.z) / ray.direction.z;
                let expected = (ray.at(t).y + 3.0) / 20.0 * 255.0;
                let got = view.rgb[3 * (v * 64 + u)] as f32;
                assert!(
                    (got - expected).abs() <= 1.0,
                    "pixel {u},{v}: {got} vs {expected}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 72);
    }

    #[test]
    fn distorted_views_put_vertices_inside_the_mask() {
        let sphere = Sphere::new(0.5);
        let scene = sphere.scene();
        let cam = camera([-0.2, 0.05, 0.003, -0.002, 0.0]);
        let view = render(&cam, &scene, 3, |_| Vec3::ONE, None);
        let plain = render(&camera([0.0; 5]), &scene, 3, |_| Vec3::ONE, None);
        assert_ne!(view.mask, plain.mask, "distortion changed nothing");
        for &x in &sphere.mesh.vertices {
            let p = cam.project_distorted(x).unwrap().round();
            assert_eq!(
                view.mask[p.y as usize * 64 + p.x as usize],
                255,
                "{x} -> {p}"
            );
        }
        // The mask is tight: it holds the pixels with colour plus at most a one-pixel rim.
        let coloured = view.rgb.chunks(3).filter(|c| c[0] > 0).count();
        let masked = view.mask.iter().filter(|&&m| m > 0).count();
        assert!(view
            .rgb
            .chunks(3)
            .zip(&view.mask)
            .all(|(c, &m)| c[0] == 0 || m == 255));
        let rim = 2.0 * std::f32::consts::PI * 100.0 * 0.5 / 3.0 + 8.0;
        assert!(
            masked >= coloured && ((masked - coloured) as f32) < 1.5 * rim,
            "{masked} vs {coloured}"
        );
    }

    #[test]
    fn a_backdrop_fills_the_uncovered_samples_and_changes_nothing_else() {
        use super::super::backdrop::Backdrop;
        let sphere = Sphere::new(0.5);
        let scene = sphere.scene();
        let cam = camera([-0.2, 0.05, 0.003, -0.002, 0.0]);
        let samples = 3;
        let plate = Backdrop::Room.plate(&cam, samples).unwrap();
        let plain = render(&cam, &scene, samples, |_| Vec3::ONE, None);
        let view = render(
            &cam,
            &scene,
            samples,
            |_| Vec3::ONE,
            Some(plate.at_frame(0)),
        );
        assert_eq!(view.mask, plain.mask);
        let (mut empty, mut full, mut partial) = (0, 0, 0);
        for v in 0..64 {
            for u in 0..64 {
                let i = v * 64 + u;
                let (got, body) = (&view.rgb[3 * i..3 * i + 3], &plain.rgb[3 * i..3 * i + 3]);
                if plain.mask[i] == 0 {
                    // Every sample sees the room: the mean of its colour along the samples' raw rays.
                    let mut mean = Vec3::ZERO;
                    for sy in 0..samples {
                        for sx in 0..samples {
                            let at = Vec2::new(
                                u as f32 + (sx as f32 + 0.5) / samples as f32 - 0.5,
                                v as f32 + (sy as f32 + 0.5) / samples as f32 - 0.5,
                            );
                            mean += Backdrop::Room.colour(&cam.raw_pixel_ray(at), 0) / 9.0;
                        }
                    }
                    let want = (mean * 255.0).round();
                    assert_eq!([got[0], got[1], got[2]], want.to_array().map(|c| c as u8));
                    assert!(want.max_element() > 0.0, "the room is black at {u},{v}");
                    empty += 1;
                } else if body == [255; 3] {
                    assert_eq!(got, body, "a covered pixel changed at {u},{v}");
                    full += 1;
                } else {
                    // Partly covered: the body's share plus some of the room's.
                    assert!(got.iter().zip(body).all(|(g, b)| g >= b), "{u},{v}");
                    partial += 1;
                }
            }
        }
        assert!(
            empty > 1000 && full > 500 && partial > 50,
            "{empty} {full} {partial}"
        );
    }
}
