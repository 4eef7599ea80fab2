//! The body's colours: clothing regions with stripes and patterns, a face, hands and shoes, as a function
//! of the canonical position, shaded by a light fixed to the body so that every surface point keeps one
//! colour in every frame and view (a radiance field can learn it exactly).

use glam::Vec3;

use super::body::{joint::*, BodyShape};

/// Colours of the procedural outfit, evaluated at canonical points (metres).
#[derive(Debug, Clone)]
pub struct Outfit {
    joints: [Vec3; 24],
    /// Unit direction towards the light, canonical space.
    light: Vec3,
}

/// Fraction of the light that reaches surfaces facing away from it.
const AMBIENT: f32 = 0.45;

const SKIN: Vec3 = Vec3::new(0.87, 0.66, 0.52);
const HAIR: Vec3 = Vec3::new(0.22, 0.13, 0.07);
const SHIRT_A: Vec3 = Vec3::new(0.85, 0.2, 0.15);
const SHIRT_B: Vec3 = Vec3::new(0.95, 0.92, 0.85);
const SHIRT_BACK: Vec3 = Vec3::new(0.15, 0.5, 0.3);
const EMBLEM: Vec3 = Vec3::new(0.98, 0.8, 0.1);
const DENIM: Vec3 = Vec3::new(0.2, 0.3, 0.6);
const SEAM: Vec3 = Vec3::new(0.9, 0.9, 0.9);
const BELT: Vec3 = Vec3::new(0.35, 0.2, 0.1);
const BUCKLE: Vec3 = Vec3::new(0.85, 0.75, 0.3);
const SHOE_L: Vec3 = Vec3::new(0.1, 0.1, 0.12);
const SHOE_R: Vec3 = Vec3::new(0.45, 0.1, 0.45);
const SOLE: Vec3 = Vec3::new(0.95, 0.95, 0.95);
const EYE_WHITE: Vec3 = Vec3::new(0.97, 0.97, 0.97);
const IRIS: Vec3 = Vec3::new(0.1, 0.25, 0.45);
const LIPS: Vec3 = Vec3::new(0.75, 0.25, 0.25);

impl Outfit {
    pub fn new(shape: &BodyShape) -> Self {
        Self {
            joints: shape.rest_joints(),
            light: Vec3::new(0.35, 0.8, 0.5).normalize(),
        }
    }

    /// Shaded colour (linear RGB in `[0, 1]`) of the surface point `p` with outward normal `n`, both
    /// canonical.
    pub fn colour(&self, p: Vec3, n: Vec3) -> Vec3 {
        self.albedo(p) * (AMBIENT + (1.0 - AMBIENT) * n.dot(self.light).max(0.0))
    }

    /// The unshaded colour at canonical point `p`.
    pub fn albedo(&self, p: Vec3) -> Vec3 {
        let j = &self.joints;
        let side = if p.x >= 0.0 { 1.0 } else { -1.0 };
        let (shoulder, elbow, wrist) = if side > 0.0 {
            (j[L_SHOULDER], j[L_ELBOW], j[L_WRIST])
        } else {
            (j[R_SHOULDER], j[R_ELBOW], j[R_WRIST])
        };
        let ax = p.x.abs();
        let waist = j[PELVIS].y + 0.03;
        let ankle = j[L_ANKLE].y;
        let head = j[HEAD];
        if p.y > j[NECK].y + 0.02 && ax < 0.13 && p.y > shoulder.y + 0.04 {
            return self.head(p - (head + Vec3::new(0.0, 0.10, 0.015)));
        }
        if ax > wrist.x.abs() - 0.01 || (ax > elbow.x.abs() + 0.04 && p.y > waist) {
            return SKIN; // hands and forearms
        }
        if ax > shoulder.x.abs() + 0.02 && p.y > waist {
            // Sleeves: rings along the arm, and a band on the left arm only.
            let band = side > 0.0 && (ax - shoulder.x.abs() - 0.12).abs() < 0.02;
            return if band {
                EMBLEM
            } else {
                stripes(ax, 0.05, SHIRT_A, SHIRT_B)
            };
        }
        if p.y > j[NECK].y - 0.02 {
            return SKIN; // neck
        }
        if p.y > waist + 0.03 {
            if p.z < -0.04 {
                // The back: a checker of two colours.
                let c = ((p.x / 0.06).floor() + (p.y / 0.06).floor()) as i32;
                return if c.rem_euclid(2) == 0 {
                    SHIRT_BACK
                } else {
                    SHIRT_B
                };
            }
            let emblem = Vec3::new(0.07, j[SPINE3].y + 0.04, 0.0);
            if p.z > 0.0 && (p.truncate() - emblem.truncate()).length() < 0.035 {
                return EMBLEM;
            }
            return stripes(p.y, 0.06, SHIRT_A, SHIRT_B);
        }
        if p.y > waist {
            return if p.z > 0.05 && p.x.abs() < 0.03 {
                BUCKLE
            } else {
                BELT
            };
        }
        if p.y > ankle + 0.01 {
            // Trousers with a light seam down the outer side of each leg and a back pocket.
            let hip = j[L_HIP].x.abs();
            if ax > hip + 0.045 && p.z.abs() < 0.015 && p.y < waist - 0.08 {
                return SEAM;
            }
            if p.z < -0.07 && (ax - hip).abs() < 0.04 && p.y < waist - 0.04 && p.y > waist - 0.13 {
                return DENIM * 0.6;
            }
            return DENIM;
        }
        if p.y < j[L_FOOT].y - 0.02 {
            return SOLE;
        }
        if side > 0.0 {
            SHOE_L
        } else {
            SHOE_R
        }
    }

    /// The head, `q` relative to the skull's centre: hair at the back and top, a face in front.
    fn head(&self, q: Vec3) -> Vec3 {
        if q.z < -0.01 || q.y > 0.06 + 0.03 * q.z.max(0.0) / 0.1 {
            return HAIR;
        }
        if q.z < 0.05 {
            return SKIN; // sides of the face, ears' place
        }
        let (x, y) = (q.x.abs(), q.y);
        let eye = (x - 0.032).hypot((y - 0.01) * 1.4);
        if eye < 0.009 {
            return IRIS;
        }
        if eye < 0.017 {
            return EYE_WHITE;
        }
        if (y - 0.035).abs() < 0.005 && (x - 0.032).abs() < 0.02 {
            return HAIR; // eyebrows
        }
        if (x / 0.027).hypot((y + 0.05) / 0.009) < 1.0 {
            return LIPS;
        }
        if (x / 0.011).hypot((y + 0.015) / 0.02) < 1.0 {
            return SKIN * 0.85; // nose
        }
        SKIN
    }
}

/// Alternating bands of width `width` along coordinate `t`.
fn stripes(t: f32, width: f32, a: Vec3, b: Vec3) -> Vec3 {
    if (t / width).floor() as i32 % 2 == 0 {
        a
    } else {
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_have_their_colours() {
        let shape = BodyShape::default();
        let o = Outfit::new(&shape);
        let j = shape.rest_joints();
        assert_eq!(o.albedo(j[L_WRIST] + Vec3::X * 0.05), SKIN, "hand");
        assert_eq!(o.albedo(j[L_KNEE] + Vec3::Z * 0.05), DENIM, "knee");
        assert_eq!(o.albedo(j[L_FOOT] + Vec3::Y * 0.02), SHOE_L, "left shoe");
        assert_eq!(o.albedo(j[R_FOOT] + Vec3::Y * 0.02), SHOE_R, "right shoe");
        assert_eq!(
            o.albedo(j[HEAD] + Vec3::new(0.0, 0.12, -0.09)),
            HAIR,
            "back of the head"
        );
        let eye = j[HEAD] + Vec3::new(0.032, 0.11, 0.1);
        assert_eq!(o.albedo(eye), IRIS, "eye");
        // Stripes alternate down the shirt front.
        let front = |y: f32| o.albedo(Vec3::new(-0.08, y, 0.1));
        let colours: std::collections::HashSet<_> = (0..8)
            .map(|i| format!("{:?}", front(j[SPINE1].y + 0.03 * i as f32)))
            .collect();
        assert!(colours.len() >= 2, "{colours:?}");
        // Shading: a surface facing the light is brighter than one facing away.
        let p = j[SPINE2] + Vec3::Z * 0.1;
        assert!(o.colour(p, o.light).length() > o.colour(p, -o.light).length());
    }
}
