//! What the cameras see behind the body. Black is the NeRF's convention and every earlier subject's; a
//! room is what a capture shows: a mask's wrong labels then cover colours that no body colour explains
//! and that differ from view to view, as on a real capture, instead of the black a faint shell around the
//! body gives for free (docs/QUALITY.md, "Mask edges").
//!
//! The room is fixed in the world (z up, floor at `z = 0`, metres), so each camera sees the same backdrop
//! in every frame, as a static capture rig does; the masks stay the body's exact coverage. The busy room
//! adds screens whose pictures change every frame, a backdrop that no one still image describes (a
//! monitor, people passing), where a capture's background must be left unknown.

use anerf_core::geometry::{Camera, Ray};
use anerf_core::named::Named;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::rng::SplitMix64;

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
    /// The room with a screen on every third wall panel (between 0.9 and 2.4 m high) showing a new flat
    /// colour in every frame.
    BusyRoom,
}

impl Named for Backdrop {
    const KIND: &'static str = "backdrop";

    fn all() -> &'static [Self] {
        &[Backdrop::Black, Backdrop::Room, Backdrop::BusyRoom]
    }

    fn name(self) -> &'static str {
        match self {
            Backdrop::Black => "black",
            Backdrop::Room => "room",
            Backdrop::BusyRoom => "busy-room",
        }
    }
}

anerf_core::by_name!(Backdrop);

/// What lies behind one point of the image.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Behind {
    /// A colour that stays (linear RGB in `[0, 1]`).
    Still(Vec3),
    /// Screen number `n` (its wall panel), whose colour changes every frame.
    Screen(usize),
}

impl Behind {
    /// Its colour in frame `frame`.
    fn colour(self, frame: usize) -> Vec3 {
        match self {
            Behind::Still(colour) => colour,
            Behind::Screen(n) => screen(n, frame),
        }
    }
}

/// The backdrop behind every point of a camera's supersampled grid, computed once per camera (only the
/// screens change from frame to frame).
pub struct Plate {
    /// Grid width (image width × samples per axis).
    width: usize,
    /// Per grid point, row-major.
    points: Vec<Behind>,
}

impl Plate {
    /// The plate as frame `frame` shows it.
    pub fn at_frame(&self, frame: usize) -> PlateAt<'_> {
        PlateAt { plate: self, frame }
    }
}

/// A camera's plate in one frame.
#[derive(Clone, Copy)]
pub struct PlateAt<'a> {
    plate: &'a Plate,
    frame: usize,
}

impl PlateAt<'_> {
    /// The colour behind grid point `(x, y)` (linear RGB in `[0, 1]`).
    pub fn at(&self, x: usize, y: usize) -> Vec3 {
        self.plate.points[y * self.plate.width + x].colour(self.frame)
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
        let points = (0..width * height)
            .map(|i| self.behind(&camera.raw_pixel_ray(point(i))))
            .collect();
        Some(Plate { width, points })
    }

    /// Linear RGB in `[0, 1]` seen along `ray` (world space, metres) in frame `frame` where no body is
    /// in the way.
    pub fn colour(self, ray: &Ray, frame: usize) -> Vec3 {
        self.behind(ray).colour(frame)
    }

    fn behind(self, ray: &Ray) -> Behind {
        match self {
            Backdrop::Black => Behind::Still(Vec3::ZERO),
            Backdrop::Room => room(ray, false),
            Backdrop::BusyRoom => room(ray, true),
        }
    }
}

/// Every this many wall panels, starting at panel 1, holds a screen in the busy room, between these
/// heights (metres).
const SCREEN_EVERY: usize = 3;
const SCREEN_HEIGHTS: (f32, f32) = (0.9, 2.4);
/// The key of the screens' colour streams.
const SCREEN_SALT: u64 = 0x5C2E_E45;

/// Screen `n`'s flat colour in frame `frame`: each channel uniform in `[0.1, 0.9)`, drawn anew for every
/// frame.
fn screen(n: usize, frame: usize) -> Vec3 {
    let mut rng = SplitMix64::keyed(n as u64, SCREEN_SALT, frame as u64);
    Vec3::new(
        rng.range(0.1, 0.9),
        rng.range(0.1, 0.9),
        rng.range(0.1, 0.9),
    )
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
/// the ceiling; with `screens`, the busy room's.
fn room(ray: &Ray, screens: bool) -> Behind {
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
        Behind::Still(floor(o + d * (-o.z / d.z)))
    } else if z > CEILING {
        Behind::Still(Vec3::splat(0.72))
    } else {
        wall(o + d * t_wall, screens)
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

/// Panels of the palette's colours around the room, a dark skirting board, and a fine woven texture; with
/// `screens`, a screen on every [`SCREEN_EVERY`]th panel.
fn wall(p: Vec3, screens: bool) -> Behind {
    if p.z < 0.3 {
        return Behind::Still(Vec3::splat(0.12));
    }
    let turn = (p.y.atan2(p.x) / std::f32::consts::TAU).rem_euclid(1.0);
    let panel = ((turn * PANELS as f32) as usize).min(PANELS - 1);
    let (low, high) = SCREEN_HEIGHTS;
    if screens && panel % SCREEN_EVERY == 1 && (low..high).contains(&p.z) {
        return Behind::Screen(panel);
    }
    let base = Vec3::from(PALETTE[(panel * 5) % PALETTE.len()]);
    let texture = 0.85 + 0.15 * (turn * 400.0).sin() * (p.z * 25.0).sin();
    Behind::Still(base * texture)
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
        let tile = Backdrop::Room.colour(&ray(eye, Vec3::new(0.25, 0.25, 0.0)), 0);
        assert!(tile.x > tile.z && (0.25..0.5).contains(&tile.x), "{tile}");
        // Straight across the room at eye height: the wall at (−6, 0), half a turn round, panel 9 of 18,
        // whose colour is the palette's (9·5) mod 6 = 3rd, times a texture between 0.7 and 1.
        let across = Backdrop::Room.colour(&ray(eye, Vec3::new(-1.0, 0.0, 1.2)), 0);
        let ratio = across / Vec3::from(PALETTE[3]);
        assert!(
            ratio.min_element() >= 0.7 && ratio.max_element() <= 1.0,
            "{across}"
        );
        assert!((ratio - Vec3::splat(ratio.x)).abs().max_element() < 1e-5);
        // Low on the wall: the skirting board.
        let low = Backdrop::Room.colour(&ray(eye, Vec3::new(-6.0, 0.0, 0.2)), 0);
        assert_eq!(low, Vec3::splat(0.12));
        // Steeply up: the ceiling.
        assert_eq!(
            Backdrop::Room.colour(&ray(eye, Vec3::new(2.5, 0.0, 3.0)), 0),
            Vec3::splat(0.72)
        );
        assert_eq!(Backdrop::Black.colour(&ray(eye, Vec3::ZERO), 0), Vec3::ZERO);
    }

    /// The busy room is the room but on its screens (panels 1, 4, 7, …, between 0.9 and 2.4 m), which
    /// change from frame to frame.
    #[test]
    fn the_busy_rooms_screens_change_every_frame_and_nothing_else_does() {
        let eye = Vec3::new(0.0, 0.0, 1.5);
        let at = |degrees: f32, z: f32| {
            let a = degrees.to_radians();
            ray(eye, Vec3::new(6.0 * a.cos(), 6.0 * a.sin(), z))
        };
        // Panel 1 spans 20°–40°, panel 0 0°–20°, panel 2 40°–60°.
        for (toward, screen) in [
            (at(30.0, 1.5), true),
            (at(30.0, 2.6), false),
            (at(30.0, 0.8), false),
            (at(10.0, 1.5), false),
            (at(50.0, 1.5), false),
            (at(90.0, 1.5), true),
            (ray(eye, Vec3::new(1.0, 1.0, 0.0)), false),
        ] {
            let frames: Vec<Vec3> = (0..4)
                .map(|f| Backdrop::BusyRoom.colour(&toward, f))
                .collect();
            if screen {
                assert!(frames
                    .windows(2)
                    .all(|w| (w[0] - w[1]).abs().max_element() > 1e-3));
                assert!(frames
                    .iter()
                    .all(|c| c.min_element() >= 0.1 && c.max_element() < 0.9));
            } else {
                assert!(frames
                    .iter()
                    .all(|&c| c == Backdrop::Room.colour(&toward, 0)));
            }
        }
    }

    #[test]
    fn backdrops_parse_by_name() {
        assert_eq!("room".parse::<Backdrop>().unwrap(), Backdrop::Room);
        let err = "wall".parse::<Backdrop>().unwrap_err().to_string();
        assert!(err.contains("black, room, busy-room"), "{err}");
    }
}
