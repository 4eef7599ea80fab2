//! Axis-aligned boxes and ray/box intersection (near/far bounds of volume rendering).

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::camera::Ray;

/// An axis-aligned box `[min, max]` (metres, in whichever frame the caller states).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

/// Where a ray enters and leaves a box (`0 ≤ near < far`, metres along the unit direction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    pub near: f32,
    pub far: f32,
}

impl Aabb {
    /// The tight box around `points`; `None` when empty.
    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Option<Self> {
        let mut it = points.into_iter();
        let first = it.next()?;
        Some(it.fold(
            Self {
                min: first,
                max: first,
            },
            |b, p| Self {
                min: b.min.min(p),
                max: b.max.max(p),
            },
        ))
    }

    /// The box grown by `pad` on every side (the reference pads SMPL boxes by 0.05 m).
    pub fn padded(&self, pad: f32) -> Self {
        Self {
            min: self.min - Vec3::splat(pad),
            max: self.max + Vec3::splat(pad),
        }
    }

    /// True when `p` lies inside or on the boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Edge lengths.
    pub fn size(&self) -> Vec3 {
        self.max - self.min
    }

    /// The 8 corners.
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }

    /// Slab intersection. Direction components with `|d| < 1e-5` are treated as ±1e-5 (the reference's
    /// guard against division by zero); a ray starting inside the box gets `near = 0`. `None` on a miss.
    pub fn intersect(&self, ray: &Ray) -> Option<RayHit> {
        let guard = |d: f32| {
            if d.abs() < 1e-5 {
                if d < 0.0 {
                    -1e-5
                } else {
                    1e-5
                }
            } else {
                d
            }
        };
        let d = Vec3::new(
            guard(ray.direction.x),
            guard(ray.direction.y),
            guard(ray.direction.z),
        );
        let t0 = (self.min - ray.origin) / d;
        let t1 = (self.max - ray.origin) / d;
        let near = t0.min(t1).max_element().max(0.0);
        let far = t0.max(t1).min_element();
        (near < far).then_some(RayHit { near, far })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::lbs::tests::TestRng;

    /// Brute force: march the ray in 1 mm steps and record where it is inside the box.
    fn brute_force(b: &Aabb, ray: &Ray) -> Option<(f32, f32)> {
        let step = 1e-3;
        let inside: Vec<f32> = (0..8000)
            .map(|i| i as f32 * step)
            .filter(|&t| b.contains(ray.at(t)))
            .collect();
        Some((*inside.first()?, *inside.last()?))
    }

    #[test]
    fn near_far_agree_with_brute_force_marching() {
        let b = Aabb {
            min: Vec3::new(-0.4, -0.9, -0.2),
            max: Vec3::new(0.5, 0.8, 0.3),
        };
        let mut rng = TestRng(21);
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..400 {
            let origin = rng.vec3(3.0);
            let target = rng.vec3(1.0);
            let ray = Ray {
                origin,
                direction: (target - origin).normalize(),
            };
            match (b.intersect(&ray), brute_force(&b, &ray)) {
                (Some(h), Some((n, f))) => {
                    hits += 1;
                    assert!(
                        (h.near - n).abs() < 2e-3 && (h.far - f).abs() < 2e-3,
                        "{h:?} vs {n} {f}"
                    );
                }
                (None, None) => misses += 1,
                // Grazing rays can touch the box between two brute-force steps.
                (Some(h), None) => assert!(h.far - h.near < 2e-3, "{h:?}"),
                (None, Some((n, f))) => panic!("missed a hit {n}..{f}"),
            }
        }
        assert!(hits > 50 && misses > 50, "hits {hits} misses {misses}");
    }

    #[test]
    fn axis_parallel_rays_are_handled() {
        let b = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let hit = b
            .intersect(&Ray {
                origin: Vec3::new(0.5, 0.5, -1.0),
                direction: Vec3::Z,
            })
            .unwrap();
        assert!((hit.near - 1.0).abs() < 1e-5 && (hit.far - 2.0).abs() < 1e-5);
        assert!(b
            .intersect(&Ray {
                origin: Vec3::new(2.0, 0.5, -1.0),
                direction: Vec3::Z
            })
            .is_none());
        let inside = b
            .intersect(&Ray {
                origin: Vec3::splat(0.5),
                direction: Vec3::X,
            })
            .unwrap();
        assert_eq!(inside.near, 0.0);
    }

    #[test]
    fn boxes_from_points_and_padding() {
        let b = Aabb::from_points([Vec3::new(1.0, -1.0, 0.0), Vec3::new(-1.0, 2.0, 0.5)])
            .unwrap()
            .padded(0.05);
        assert_eq!(b.min, Vec3::new(-1.05, -1.05, -0.05));
        assert_eq!(b.max, Vec3::new(1.05, 2.05, 0.55));
        assert!(Aabb::from_points(std::iter::empty()).is_none());
        assert_eq!(b.corners().iter().filter(|c| b.contains(**c)).count(), 8);
    }
}
