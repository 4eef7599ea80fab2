//! An occupancy grid over the canonical box: which cells of canonical space hold any density, so that
//! samples warped into empty cells skip the canonical NeRF (and the canonical blend-weight field) at
//! training and render time, as nerfacc's occupancy grid does for static scenes.
//!
//! The grid is rebuilt from the current density during training (every `update_every` steps after a warm-up)
//! and once from a trained model before rendering. A cell is occupied when the raw density at its centre or
//! at any of its eight corners exceeds `density_threshold`, and then so are its 26 neighbours: a sample is
//! skipped only when the density around it is below the threshold at every probe within about two cells.
//! Points outside the canonical box are never occupied (the model gives them zero density anyway).

use burn::prelude::*;
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::{GeometryError, InvalidValue};
use crate::geometry::Aabb;
use crate::tensor::{from_rows, to_host};

/// Settings of the occupancy grid (a part of [`crate::model::ModelConfig`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccupancyConfig {
    /// Cells along the longest side of the canonical box (the other sides get cells of the same size).
    pub resolution: usize,
    /// Raw density (1/m) above which a probe marks its cell occupied.
    pub density_threshold: f32,
    /// Training steps between two rebuilds.
    pub update_every: usize,
    /// Training steps before the first build (the density of an untrained field means nothing).
    pub warmup_steps: usize,
}

impl OccupancyConfig {
    /// Checks the values; the error names the field.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        if !(2..=512).contains(&self.resolution) {
            return Err(InvalidValue::new(
                "model.occupancy.resolution",
                self.resolution,
                "2 to 512",
            ));
        }
        if !(self.density_threshold.is_finite() && self.density_threshold >= 0.0) {
            return Err(InvalidValue::new(
                "model.occupancy.density_threshold",
                self.density_threshold,
                "a density ≥ 0 (1/m)",
            ));
        }
        if self.update_every == 0 {
            return Err(InvalidValue::new(
                "model.occupancy.update_every",
                0,
                "a positive number of steps",
            ));
        }
        Ok(())
    }

    /// Whether a training run rebuilds the grid after step `step` (counted from 1).
    pub fn rebuilds_at(&self, step: usize) -> bool {
        step >= self.warmup_steps.max(1) && step.is_multiple_of(self.update_every)
    }
}

/// Occupied cells of the canonical box (metres, canonical space). Saved with checkpoints, so that a resumed
/// run and a rendering of the run skip exactly the cells training skipped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccupancyGrid {
    min: Vec3,
    cell: f32,
    dims: [usize; 3],
    /// `[x][y][z]`, row-major; already dilated by one cell.
    #[serde(with = "hex_bits")]
    occupied: Vec<bool>,
}

/// A `Vec<bool>` as a hexadecimal string, four cells per digit (most significant bit first), and its length.
mod hex_bits {
    use serde::de::Error;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    struct Packed {
        len: usize,
        hex: String,
    }

    pub fn serialize<S: Serializer>(bits: &[bool], s: S) -> Result<S::Ok, S::Error> {
        let hex = bits
            .chunks(4)
            .map(|c| {
                let v = c
                    .iter()
                    .enumerate()
                    .fold(0u32, |v, (i, &b)| v | (b as u32) << (3 - i));
                char::from_digit(v, 16).expect("a nibble")
            })
            .collect();
        Packed {
            len: bits.len(),
            hex,
        }
        .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<bool>, D::Error> {
        let p = Packed::deserialize(d)?;
        if p.hex.len() != p.len.div_ceil(4) {
            return Err(D::Error::custom(format!(
                "occupancy: {} hex digits for {} cells (expected {})",
                p.hex.len(),
                p.len,
                p.len.div_ceil(4)
            )));
        }
        let mut bits = Vec::with_capacity(p.len);
        for c in p.hex.chars() {
            let v = c
                .to_digit(16)
                .ok_or_else(|| D::Error::custom(format!("occupancy: '{c}' is not a hex digit")))?;
            bits.extend((0..4).map(|i| v >> (3 - i) & 1 == 1));
        }
        bits.truncate(p.len);
        Ok(bits)
    }
}

/// Probes per density evaluation.
const CHUNK: usize = 65_536;

impl OccupancyGrid {
    /// Builds the grid over `bounds` by probing `density` (raw density `[N, 1]` at canonical points `[N, 3]`
    /// on `device`) at every cell centre and cell corner.
    pub fn build(
        config: &OccupancyConfig,
        bounds: Aabb,
        device: &Device,
        mut density: impl FnMut(Tensor<2>) -> Tensor<2>,
    ) -> Self {
        let size = bounds.size();
        let cell = size.max_element() / config.resolution as f32;
        let dims = [0, 1, 2].map(|a| ((size[a] / cell).ceil() as usize).max(1));
        let index = |i: usize, j: usize, k: usize, d: [usize; 3]| (i * d[1] + j) * d[2] + k;
        let corners = dims.map(|d| d + 1);
        let mut probes = Vec::with_capacity(3 * (cells(dims) + cells(corners)));
        for (d, offset) in [(dims, 0.5), (corners, 0.0)] {
            for i in 0..d[0] {
                for j in 0..d[1] {
                    for k in 0..d[2] {
                        let p =
                            bounds.min + cell * (Vec3::new(i as f32, j as f32, k as f32) + offset);
                        probes.extend(p.to_array());
                    }
                }
            }
        }
        let n = probes.len() / 3;
        let mut values = Vec::with_capacity(n);
        for start in (0..n).step_by(CHUNK) {
            let m = CHUNK.min(n - start);
            let points = from_rows(&probes[3 * start..3 * (start + m)], m, 3, device);
            values.extend(to_host(density(points).detach()));
        }
        let (centre, corner) = values.split_at(cells(dims));
        let above = |v: f32| v > config.density_threshold;
        let mut raw = vec![false; cells(dims)];
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    let c = index(i, j, k, dims);
                    raw[c] = above(centre[c])
                        || (0..8).any(|b| {
                            above(
                                corner[index(
                                    i + (b & 1),
                                    j + ((b >> 1) & 1),
                                    k + ((b >> 2) & 1),
                                    corners,
                                )],
                            )
                        });
                }
            }
        }
        let mut occupied = vec![false; cells(dims)];
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    if !raw[index(i, j, k, dims)] {
                        continue;
                    }
                    for di in i.saturating_sub(1)..(i + 2).min(dims[0]) {
                        for dj in j.saturating_sub(1)..(j + 2).min(dims[1]) {
                            for dk in k.saturating_sub(1)..(k + 2).min(dims[2]) {
                                occupied[index(di, dj, dk, dims)] = true;
                            }
                        }
                    }
                }
            }
        }
        Self {
            min: bounds.min,
            cell,
            dims,
            occupied,
        }
    }

    /// Checks a grid read from a file: the cell count matches the dimensions, the geometry is finite.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if cells(self.dims) != self.occupied.len() {
            return Err(GeometryError::GridCells {
                cells: self.occupied.len(),
                dims: self.dims,
            });
        }
        if !(self.min.is_finite() && self.cell.is_finite() && self.cell > 0.0) {
            return Err(GeometryError::EmptyBox {
                what: "occupancy grid (origin, cell size)",
                value: format!("({}, {})", self.min, self.cell),
            });
        }
        Ok(())
    }

    /// Cells per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Fraction of the cells that are occupied.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied.iter().filter(|&&o| o).count() as f64 / self.occupied.len() as f64
    }

    /// Whether the cell holding canonical point `p` is occupied (false outside the grid).
    pub fn contains(&self, p: Vec3) -> bool {
        let u = (p - self.min) / self.cell;
        if u.cmplt(Vec3::ZERO).any() {
            return false;
        }
        let [i, j, k] = [u.x, u.y, u.z].map(|v| v as usize);
        if i >= self.dims[0] || j >= self.dims[1] || k >= self.dims[2] {
            return false;
        }
        self.occupied[(i * self.dims[1] + j) * self.dims[2] + k]
    }

    /// Indices of the rows of `points` (`[N, 3]` row-major, canonical space) that lie in occupied cells.
    pub fn occupied_rows(&self, points: &[f32]) -> Vec<i64> {
        points
            .chunks_exact(3)
            .enumerate()
            .filter(|(_, p)| self.contains(Vec3::from_slice(p)))
            .map(|(i, _)| i as i64)
            .collect()
    }
}

fn cells(dims: [usize; 3]) -> usize {
    dims.iter().product()
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_device::cpu_device;

    fn config() -> OccupancyConfig {
        OccupancyConfig {
            resolution: 20,
            density_threshold: 0.5,
            update_every: 4,
            warmup_steps: 10,
        }
    }

    /// A ball of density 10 (radius 0.3 m) in a 2 × 1 × 1 m box: occupied cells cover the ball and stay
    /// within two cells (0.2 m) of it.
    #[test]
    fn a_ball_is_covered_with_a_margin_of_at_most_two_cells() {
        let device = cpu_device();
        let bounds = Aabb {
            min: Vec3::new(-1.0, -0.5, -0.5),
            max: Vec3::new(1.0, 0.5, 0.5),
        };
        let centre = Vec3::new(0.4, 0.0, 0.1);
        let grid = OccupancyGrid::build(&config(), bounds, &device, |p: Tensor<2>| {
            let c = Tensor::<2>::from_floats([centre.to_array()], &p.device());
            let r = (p - c).powi_scalar(2).sum_dim(1).sqrt();
            r.lower_elem(0.3).float() * 10.0
        });
        assert_eq!(grid.dims(), [20, 10, 10]);
        let mut state = 12345u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1 << 24) as f32
        };
        for _ in 0..20_000 {
            let p = bounds.min + bounds.size() * Vec3::new(next(), next(), next());
            let d = (p - centre).length();
            if d < 0.3 {
                assert!(grid.contains(p), "{p} inside the ball is not occupied");
            }
            if d > 0.3 + 2.0 * 0.1 * 3f32.sqrt() {
                assert!(!grid.contains(p), "{p} ({d} m from the centre) is occupied");
            }
        }
        assert!(!grid.contains(Vec3::new(2.0, 0.0, 0.0)));
        let f = grid.occupied_fraction();
        assert!(f > 0.05 && f < 0.5, "{f}");
        let rows = grid.occupied_rows(&[0.4, 0.0, 0.1, -0.9, 0.4, 0.4]);
        assert_eq!(rows, vec![0]);
    }

    /// The grid survives JSON (as checkpoints store it) bit for bit; a truncated or mismatched one is refused.
    #[test]
    fn json_round_trip_and_corrupt_grids() {
        let bounds = Aabb {
            min: Vec3::new(-1.0, -0.5, -0.5),
            max: Vec3::new(1.0, 0.5, 0.5),
        };
        let grid = OccupancyGrid::build(&config(), bounds, &cpu_device(), |p: Tensor<2>| {
            let x = p.narrow(1, 0, 1);
            x.clone().greater_elem(0.3).float() * (x.lower_elem(0.5).float()) * 10.0
        });
        let f = grid.occupied_fraction();
        assert!(f > 0.0 && f < 1.0, "{f}");
        let text = serde_json::to_string(&grid).unwrap();
        let back: OccupancyGrid = serde_json::from_str(&text).unwrap();
        assert_eq!(back, grid);
        assert!(back.validate().is_ok());
        let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
        value["dims"][0] = 7.into();
        let wrong: OccupancyGrid = serde_json::from_value(value.clone()).unwrap();
        assert!(matches!(
            wrong.validate().unwrap_err(),
            GeometryError::GridCells {
                dims: [7, _, _],
                ..
            }
        ));
        let hex = value["occupied"]["hex"].as_str().unwrap().to_string();
        value["occupied"]["hex"] = hex[1..].into();
        let err = serde_json::from_value::<OccupancyGrid>(value)
            .unwrap_err()
            .to_string();
        assert!(err.contains("hex digits"), "{err}");
    }

    #[test]
    fn rebuild_schedule_and_validation() {
        let c = config();
        let steps: Vec<usize> = (1..=24).filter(|&s| c.rebuilds_at(s)).collect();
        assert_eq!(steps, vec![12, 16, 20, 24]);
        assert!(c.validate().is_ok());
        let bad = OccupancyConfig {
            update_every: 0,
            ..c
        };
        assert_eq!(
            bad.validate().unwrap_err().key,
            "model.occupancy.update_every"
        );
    }
}
