//! What the cameras see behind the body. Black is the NeRF's convention and every earlier subject's; a
//! room is what a capture shows: a mask's wrong labels then cover colours that no body colour explains
//! and that differ from view to view, as on a real capture, instead of the black a faint shell around the
//! body gives for free (docs/QUALITY.md, "Mask edges").
//!
//! The room is fixed in the world (z up, floor at `z = 0`, metres), so each camera sees the same backdrop
//! in every frame, as a static capture rig does; the masks stay the body's exact coverage.

use anerf_core::geometry::{Camera, Ray};
use anerf_core::named::Named;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// What lies behind the body in a synthetic subject's images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backdrop {
    /// Nothing: colours are exactly 0 outside the body's coverage.
    #[default]
    Black,
    /// A round studio about the world's `z` axis: a tiled floor, a wall of coloured, textured panels and
    /// a grey ceiling.
    Room,
}

impl Named for Backdrop {
    const KIND: &'static str = "backdrop";

    fn all() -> &'static [Self] {
        &[Backdrop::Black, Backdrop::Room]
    }

    fn name(self) -> &'static str {
        match self {
            Backdrop::Black => "black",
            Backdrop::Room => "room",
        }
    }
}

anerf_core::by_name!(Backdrop);

/// The backdrop behind every point of a camera's supersampled grid, computed once per camera (it does
/// not change from frame to frame).
pub struct Plate {
    /// Grid width (image width × samples per axis).
    width: usize,
    /// Linear RGB in `[0, 1]` per grid point, row-major.
    colours: Vec<Vec3>,
}

impl Plate {
    /// The colour behind grid point `(x, y)`.
    pub fn at(&self, x: usize, y: usize) -> Vec3 {
        self.colours[y * self.width + x]
    }
}

impl Backdrop {
    /// The backdrop of `camera`'s grid of `samples × samples` points per pixel (the rasteriser's: point
    /// `(x, y)` lies at raw-image pixel `((x + ½) / samples − ½, (y + ½) / samples − ½)`, integer
    /// convention); `None` for [`Backdrop::Black`].
    pub fn plate(self, camera: &Camera, samples: u32) -> Option<Plate> {
        if self == Backdrop::Black {
            return None;
        }
        let s = samples as usize;
        let (width, height) = (camera.width as usize * s, camera.height as usize * s);
        let point = |i: usize| {
            let grid = Vec2::new((i % width) as f32 + 0.5, (i / width) as f32 + 0.5);
            grid / samples as f32 - Vec2::splat(0.5)
        };
        let colours = (0..width * height)
            .map(|i| self.colour(&camera.raw_pixel_ray(point(i))))
            .collect();
        Some(Plate { width, colours })
    }

    /// Linear RGB in `[0, 1]` seen along `ray` (world space, metres) where no body is in the way.
    pub fn colour(self, ray: &Ray) -> Vec3 {
        match self {
            Backdrop::Black => Vec3::ZERO,
            Backdrop::Room => room(ray),
        }
    }
}

/// Radius of the room's wall about the world's `z` axis (metres; at least twice the camera's distance
/// from the axis, so the wall is behind the body in every view) and the ceiling's height.
const WALL_RADIUS: f32 = 6.0;
const CEILING: f32 = 3.2;
/// Floor tiles' side and the grout between them (metres).
const TILE: f32 = 0.5;
const GROUT: f32 = 0.015;
/// The wall's panels: how many around the room, and their colours in turn (muted, as a studio's).
const PANELS: usize = 18;
const PALETTE: [[f32; 3]; 6] = [
    [0.55, 0.50, 0.42],
    [0.30, 0.38, 0.48],
    [0.45, 0.52, 0.40],
    [0.62, 0.60, 0.58],
    [0.50, 0.35, 0.30],
    [0.25, 0.28, 0.30],
];

/// The room seen along `ray`: the wall where the ray meets it between floor and ceiling, else the floor or
/// the ceiling.
fn room(ray: &Ray) -> Vec3 {
    let (o, d) = (ray.origin, ray.direction);
    let radius = WALL_RADIUS.max(2.0 * o.truncate().length());
    // The wall: |o.xy + t·d.xy| = radius, the root ahead of an origin inside the room.
    let a = d.truncate().length_squared();
    let t_wall = if a > 1e-12 {
        let b = o.truncate().dot(d.truncate());
        let c = o.truncate().length_squared() - radius * radius;
        (-b + (b * b - a * c).max(0.0).sqrt()) / a
    } else {
        f32::INFINITY
    };
    let z = o.z + t_wall * d.z;
    if z < 0.0 {
        floor(o + d * (-o.z / d.z))
    } else if z > CEILING {
        Vec3::splat(0.72)
    } else {
        wall(o + d * t_wall)
    }
}

/// A checkerboard of warm grey tiles with dark grout and a slow variation of brightness.
fn floor(p: Vec3) -> Vec3 {
    let cell = (p.truncate() / TILE).floor();
    let within = p.truncate() / TILE - cell;
    let grout = GROUT / TILE;
    if within.min_element() < grout || within.max_element() > 1.0 - grout {
        return Vec3::splat(0.15);
    }
    let parity = (cell.x + cell.y).rem_euclid(2.0);
    let grey = if parity < 1.0 { 0.30 } else { 0.42 };
    let slow = 1.0 + 0.1 * (1.3 * p.x).sin() * (0.9 * p.y).sin();
    Vec3::new(1.0, 0.95, 0.85) * grey * slow
}

/// Panels of the palette's colours around the room, a dark skirting board, and a fine woven texture.
fn wall(p: Vec3) -> Vec3 {
    if p.z < 0.3 {
        return Vec3::splat(0.12);
    }
    let turn = (p.y.atan2(p.x) / std::f32::consts::TAU).rem_euclid(1.0);
    let panel = ((turn * PANELS as f32) as usize).min(PANELS - 1);
    let base = Vec3::from(PALETTE[(panel * 5) % PALETTE.len()]);
    let texture = 0.85 + 0.15 * (turn * 400.0).sin() * (p.z * 25.0).sin();
    base * texture
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(origin: Vec3, toward: Vec3) -> Ray {
        Ray {
            origin,
            direction: (toward - origin).normalize(),
        }
    }

    #[test]
    fn the_room_is_floor_below_the_horizon_wall_ahead_and_ceiling_above() {
        let eye = Vec3::new(3.0, 0.0, 1.2);
        // Looking down at a tile's middle: a tile's grey, warm-tinted.
        let tile = Backdrop::Room.colour(&ray(eye, Vec3::new(0.25, 0.25, 0.0)));
        assert!(tile.x > tile.z && (0.25..0.5).contains(&tile.x), "{tile}");
        // Straight across the room at eye height: the wall at (−6, 0), half a turn round, panel 9 of 18,
        // whose colour is the palette's (9·5) mod 6 = 3rd, times a texture between 0.7 and 1.
        let across = Backdrop::Room.colour(&ray(eye, Vec3::new(-1.0, 0.0, 1.2)));
        let ratio = across / Vec3::from(PALETTE[3]);
        assert!(
            ratio.min_element() >= 0.7 && ratio.max_element() <= 1.0,
            "{across}"
        );
        assert!((ratio - Vec3::splat(ratio.x)).abs().max_element() < 1e-5);
        // Low on the wall: the skirting board.
        let low = Backdrop::Room.colour(&ray(eye, Vec3::new(-6.0, 0.0, 0.2)));
        assert_eq!(low, Vec3::splat(0.12));
        // Steeply up: the ceiling.
        assert_eq!(
            Backdrop::Room.colour(&ray(eye, Vec3::new(2.5, 0.0, 3.0))),
            Vec3::splat(0.72)
        );
        assert_eq!(Backdrop::Black.colour(&ray(eye, Vec3::ZERO)), Vec3::ZERO);
    }

    #[test]
    fn backdrops_parse_by_name() {
        assert_eq!("room".parse::<Backdrop>().unwrap(), Backdrop::Room);
        let err = "wall".parse::<Backdrop>().unwrap_err().to_string();
        assert!(err.contains("black, room"), "{err}");
    }
}
