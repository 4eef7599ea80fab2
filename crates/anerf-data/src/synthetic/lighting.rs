//! How the synthetic body is lit. `BodyFixed` keeps one colour per surface point in every frame and view
//! (a radiance field can learn it exactly); `Studio` fixes point lights in the world, with cast shadows
//! from per-frame shadow maps, Lambert diffuse and Blinn-Phong specular terms, so that shading changes as
//! the body turns and as the camera moves, as it does in a real capture.

use anerf_core::geometry::{Camera, Distortion};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::cameras::look_at;
use super::raster::{DepthMap, Surface};
use super::SynthError;

/// The lighting of a synthetic subject.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Lighting {
    /// One directional light fixed to the body, Lambert only ([`super::appearance::Outfit::colour`]).
    #[default]
    BodyFixed,
    /// Point lights fixed in the world.
    Studio(StudioLights),
}

/// A point light fixed in the world. Its intensity does not fall off with distance (studio lights stand a
/// few metres away, where the falloff across a body is small).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointLight {
    /// World position (metres, z up).
    pub position: Vec3,
    /// Linear RGB intensity.
    pub intensity: Vec3,
}

/// World-fixed lights and the surface's reflectance: colour = albedo · (ambient + Σ vis·I·max(0, n·l))
/// + specular · Σ vis·I·max(0, n·h)^shininess, with `h` the half vector of the light and view directions
/// and `vis` the light's shadow-map visibility.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudioLights {
    pub lights: Vec<PointLight>,
    /// Light reaching every point whatever its orientation and shadows.
    pub ambient: f32,
    /// Weight of the Blinn-Phong lobe (white highlights).
    pub specular: f32,
    /// Blinn-Phong exponent.
    pub shininess: f32,
    /// Side of each light's square shadow map (pixels).
    pub shadow_resolution: u32,
}

impl StudioLights {
    /// A key, a fill and a back light around a subject at the world's origin.
    pub fn three_point() -> Self {
        Self {
            lights: vec![
                PointLight {
                    position: Vec3::new(2.4, -2.2, 2.9),
                    intensity: Vec3::new(0.72, 0.68, 0.6),
                },
                PointLight {
                    position: Vec3::new(-3.0, -1.2, 1.4),
                    intensity: Vec3::new(0.22, 0.26, 0.32),
                },
                PointLight {
                    position: Vec3::new(0.6, 3.2, 2.6),
                    intensity: Vec3::new(0.35, 0.35, 0.35),
                },
            ],
            ambient: 0.22,
            specular: 0.3,
            shininess: 24.0,
            shadow_resolution: 1024,
        }
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        if self.lights.is_empty() || self.lights.len() > 16 {
            return Err(SynthError::invalid(
                "lighting.lights",
                format!("{} lights (expected 1 to 16)", self.lights.len()),
            ));
        }
        for (i, l) in self.lights.iter().enumerate() {
            // The shadow camera looks at the body from the light: it must stand clear of the body and not
            // straight above it (its image axes follow the world's vertical).
            if !(l.position.is_finite() && l.position.truncate().length() >= 1.0) {
                return Err(SynthError::invalid(
                    format!("lighting.lights[{i}].position"),
                    format!(
                        "{} (expected at least 1 m from the vertical axis)",
                        l.position
                    ),
                ));
            }
            if !(l.intensity.is_finite() && l.intensity.min_element() >= 0.0) {
                return Err(SynthError::invalid(
                    format!("lighting.lights[{i}].intensity"),
                    format!("{} (expected non-negative RGB)", l.intensity),
                ));
            }
        }
        SynthError::check_ranges(&[
            ("lighting.ambient", self.ambient, 0.0, 2.0),
            ("lighting.specular", self.specular, 0.0, 2.0),
            ("lighting.shininess", self.shininess, 1.0, 1000.0),
        ])?;
        if !(64..=8192).contains(&self.shadow_resolution) {
            return Err(SynthError::invalid(
                "lighting.shadow_resolution",
                format!("{} (expected 64 to 8192)", self.shadow_resolution),
            ));
        }
        Ok(())
    }

    /// The lights of one posed frame: a shadow map per light of the posed surface (world space, metres).
    pub fn frame(&self, world: &[Vec3], faces: &[[u32; 3]]) -> LitFrame<'_> {
        let (lo, hi) = world
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let centre = (lo + hi) * 0.5;
        let radius = (hi - lo).length() * 0.5;
        let shadows = self
            .lights
            .iter()
            .map(|l| {
                DepthMap::render(
                    shadow_camera(l.position, centre, radius, self.shadow_resolution),
                    world,
                    faces,
                )
            })
            .collect();
        LitFrame {
            lights: self,
            shadows,
        }
    }
}

/// A pinhole at `light` looking at `centre`, whose square image holds the sphere of `radius` about it.
fn shadow_camera(light: Vec3, centre: Vec3, radius: f32, size: u32) -> Camera {
    let rotation = look_at(light, centre);
    let distance = (centre - light).length();
    // The sphere's silhouette subtends asin(r/d); a 5 % margin keeps it inside the image.
    let half_angle = (radius / distance).clamp(0.0, 0.95).asin() * 1.05;
    let focal = 0.5 * size as f32 / half_angle.tan();
    let c = 0.5 * (size as f32 - 1.0);
    Camera {
        intrinsics: Mat3::from_cols(
            Vec3::new(focal, 0.0, 0.0),
            Vec3::new(0.0, focal, 0.0),
            Vec3::new(c, c, 1.0),
        ),
        rotation,
        translation: -(rotation * light),
        distortion: Distortion::default(),
        width: size,
        height: size,
    }
}

/// The studio lights of one frame with their shadow maps.
pub struct LitFrame<'a> {
    lights: &'a StudioLights,
    shadows: Vec<DepthMap>,
}

impl LitFrame<'_> {
    /// Shaded linear RGB of `surface` with `albedo`, seen from the camera centre `eye` (world, metres).
    pub fn shade(&self, albedo: Vec3, surface: &Surface, eye: Vec3) -> Vec3 {
        let spec = self.lights;
        let (x, n) = (surface.world, surface.world_normal);
        let view = (eye - x).normalize_or_zero();
        let mut diffuse = Vec3::splat(spec.ambient);
        let mut highlight = Vec3::ZERO;
        for (light, map) in spec.lights.iter().zip(&self.shadows) {
            let l = (light.position - x).normalize_or_zero();
            let cosine = n.dot(l);
            if cosine <= 0.0 {
                continue;
            }
            let visibility = map.visibility(x, shadow_bias(map, x));
            if visibility == 0.0 {
                continue;
            }
            diffuse += light.intensity * (visibility * cosine);
            let half = (l + view).normalize_or_zero();
            highlight += light.intensity * (visibility * n.dot(half).max(0.0).powf(spec.shininess));
        }
        albedo * diffuse + highlight * spec.specular
    }

    /// Whether world point `x` is lit by light `i` by its shadow map (visibility above one half).
    pub fn lit_by(&self, i: usize, x: Vec3) -> bool {
        let map = &self.shadows[i];
        map.visibility(x, shadow_bias(map, x)) > 0.5
    }
}

/// Depth tolerance of a shadow-map test at `x` (metres): 3 mm plus two shadow-map pixels' footprint there,
/// so that a surface does not shadow itself.
fn shadow_bias(map: &DepthMap, x: Vec3) -> f32 {
    let depth = map.camera.world_to_camera(x).z;
    0.003 + 2.0 * depth / map.camera.intrinsics.x_axis.x
}

#[cfg(test)]
mod tests {
    use super::super::raster::{render, Scene};
    use super::*;
    use anerf_core::geometry::PixelConvention;
    use anerf_core::mesh::{marching_cubes, ScalarGrid, TriMesh};

    /// A pinhole at `centre` looking at the origin, 96² pixels, 40° field.
    fn camera_at(centre: Vec3) -> Camera {
        let rotation = look_at(centre, Vec3::ZERO);
        let focal = 48.0 / 20f32.to_radians().tan();
        Camera {
            intrinsics: Mat3::from_cols(
                Vec3::new(focal, 0.0, 0.0),
                Vec3::new(0.0, focal, 0.0),
                Vec3::new(47.5, 47.5, 1.0),
            ),
            rotation,
            translation: -(rotation * centre),
            distortion: Distortion::default(),
            width: 96,
            height: 96,
        }
    }

    fn sphere(r: f32, h: f32) -> TriMesh {
        let n = (2.0 * r / h) as usize + 5;
        let origin = Vec3::splat(-(n as f32 - 1.0) * h / 2.0);
        let grid = ScalarGrid::from_fn(origin, Vec3::splat(h), [n; 3], |p| p.length() - r).unwrap();
        marching_cubes(&grid, 0.0)
    }

    fn one_light(position: Vec3, specular: f32) -> StudioLights {
        StudioLights {
            lights: vec![PointLight {
                position,
                intensity: Vec3::splat(0.7),
            }],
            ambient: 0.2,
            specular,
            shininess: 8.0,
            shadow_resolution: 512,
        }
    }

    /// Where the ray of pixel `(u, v)` first meets the sphere of radius `r` about the origin.
    fn sphere_hit(camera: &Camera, u: usize, v: usize, r: f32) -> Option<Vec3> {
        let ray = camera.pixel_ray(u as f32, v as f32, PixelConvention::Integer);
        let b = ray.origin.dot(ray.direction);
        let disc = b * b - (ray.origin.length_squared() - r * r);
        (disc > 0.0).then(|| ray.at(-b - disc.sqrt()))
    }

    #[test]
    fn highlights_follow_the_camera_as_blinn_phong_predicts() {
        let r = 0.5;
        let mesh = sphere(r, 0.02);
        let normals = mesh.vertex_normals();
        let scene = Scene {
            world: &mesh.vertices,
            world_normals: &normals,
            faces: &mesh.faces,
            canonical: &mesh.vertices,
            normals: &normals,
        };
        let light = Vec3::new(1.5, -2.5, 1.0);
        let lights = one_light(light, 0.5);
        let lit = lights.frame(&mesh.vertices, &mesh.faces);
        let albedo = Vec3::splat(0.4);
        // The analytic shading of a sphere point (no shadow: a convex body only shades itself).
        let expected = |x: Vec3, eye: Vec3| {
            let (n, l, view) = (
                x.normalize(),
                (light - x).normalize(),
                (eye - x).normalize(),
            );
            let cosine = n.dot(l).max(0.0);
            let lobe = if cosine > 0.0 {
                n.dot((l + view).normalize()).max(0.0).powf(8.0)
            } else {
                0.0
            };
            (0.4 * (0.2 + 0.7 * cosine) + 0.5 * 0.7 * lobe).min(1.0)
        };
        let mut brightest = Vec::new();
        for eye in [Vec3::new(0.0, -3.0, 0.3), Vec3::new(2.6, -1.5, 0.3)] {
            let camera = camera_at(eye);
            let view = render(&camera, &scene, 2, |s| lit.shade(albedo, s, eye), None);
            let (mut checked, mut worst, mut best) = (0, 0.0f32, (0.0f32, Vec3::ZERO));
            for v in 0..96 {
                for u in 0..96 {
                    // Pixels well inside the silhouette, where the surface is far from grazing.
                    if sphere_hit(&camera, u, v, 0.9 * r).is_none() {
                        continue;
                    }
                    let x = sphere_hit(&camera, u, v, r).expect("inside the silhouette");
                    let got = view.rgb[3 * (v * 96 + u)] as f32 / 255.0;
                    let want = expected(x, eye);
                    worst = worst.max((got - want).abs());
                    checked += 1;
                    if got > best.0 {
                        best = (got, x);
                    }
                }
            }
            assert!(checked > 1000, "{checked} pixels");
            assert!(worst < 0.03, "largest error {worst} from camera {eye}");
            brightest.push(best.1);
        }
        // The highlight sits where the normal bisects light and eye, so it moves with the camera.
        for (x, eye) in brightest
            .iter()
            .zip([Vec3::new(0.0, -3.0, 0.3), Vec3::new(2.6, -1.5, 0.3)])
        {
            let half = ((light - *x).normalize() + (eye - *x).normalize()).normalize();
            assert!(
                x.normalize().dot(half) > 0.99,
                "highlight at {x} from {eye}"
            );
        }
        assert!(brightest[0].distance(brightest[1]) > 0.1, "{brightest:?}");
    }

    #[test]
    fn shadows_fall_where_the_occluder_blocks_the_light() {
        // A floor at z = 0 (two faces, facing up) under a ball of radius 0.3 centred 0.6 m above it.
        let (c, r) = (Vec3::new(0.0, 0.0, 0.6), 0.3);
        let ball = sphere(r, 0.03);
        let mut world: Vec<Vec3> = ball.vertices.iter().map(|&p| p + c).collect();
        let mut faces = ball.faces.clone();
        let base = world.len() as u32;
        world.extend([
            Vec3::new(-2.0, -2.0, 0.0),
            Vec3::new(2.0, -2.0, 0.0),
            Vec3::new(2.0, 2.0, 0.0),
            Vec3::new(-2.0, 2.0, 0.0),
        ]);
        faces.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        let light = Vec3::new(1.2, -0.8, 2.4);
        let lights = one_light(light, 0.0);
        let lit = lights.frame(&world, &faces);
        let (mut shadowed, mut checked) = (0, 0);
        for i in 0..=60 {
            for j in 0..=60 {
                let x = Vec3::new(-1.5 + 0.05 * i as f32, -1.5 + 0.05 * j as f32, 0.0);
                // The segment from x to the light passes the ball's centre at distance `d`.
                let dir = (light - x).normalize();
                let t = (c - x).dot(dir).max(0.0);
                let d = (x + dir * t).distance(c);
                if (d - r).abs() < 0.03 {
                    continue; // too close to the shadow's edge for a sharp answer
                }
                checked += 1;
                let blocked = d < r;
                shadowed += blocked as usize;
                assert_eq!(lit.lit_by(0, x), !blocked, "floor point {x}: d = {d}");
            }
        }
        assert!(shadowed > 40 && checked > 3000, "{shadowed} of {checked}");
        // In a rendered view a shadowed floor point gets the ambient light alone.
        let normals: Vec<Vec3> = (0..world.len())
            .map(|v| {
                if v < base as usize {
                    (world[v] - c).normalize()
                } else {
                    Vec3::Z
                }
            })
            .collect();
        let scene = Scene {
            world: &world,
            world_normals: &normals,
            faces: &faces,
            canonical: &world,
            normals: &normals,
        };
        let shadow_centre = {
            // Where the ray from the light through the ball's centre meets the floor.
            let dir = c - light;
            light + dir * (-light.z / dir.z)
        };
        let eye = Vec3::new(-2.0, -2.5, 2.0);
        let camera = camera_at(eye);
        let view = render(&camera, &scene, 1, |s| lit.shade(Vec3::ONE, s, eye), None);
        let p = camera
            .project(shadow_centre, PixelConvention::Integer)
            .unwrap()
            .round();
        let got = view.rgb[3 * (p.y as usize * 96 + p.x as usize)];
        assert_eq!(
            got,
            (0.2f32 * 255.0).round() as u8,
            "shadow at {shadow_centre}"
        );
        // A floor point in the light, which the ball hides neither from the light nor from the camera.
        let open = Vec3::new(0.6, -0.6, 0.0);
        let q = camera
            .project(open, PixelConvention::Integer)
            .unwrap()
            .round();
        let cosine = (light - open).normalize().z;
        let want = ((0.2 + 0.7 * cosine) * 255.0).round();
        let got = view.rgb[3 * (q.y as usize * 96 + q.x as usize)] as f32;
        assert!((got - want).abs() <= 1.0, "lit floor {got} vs {want}");
    }
}
