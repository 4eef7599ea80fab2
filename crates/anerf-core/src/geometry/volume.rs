//! Blend-weight volumes: `K` skinning weights plus the distance to the body surface (metres) on a regular
//! grid, looked up trilinearly. The reference stores them as `(Nx, Ny, Nz, K+1)` float32 arrays
//! (`lbs/bweights/{i}.npy` in pose space, `lbs/tbw.npy` in canonical space).

use std::sync::Arc;

use burn::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use super::Aabb;
use crate::error::GeometryError;
use crate::kernels::warp::TrilinearGrid;

/// Skinning weights below this are stored as zeros. Body models' weights that fall off smoothly leave
/// values down to subnormal floats (9 % of the synthetic subjects' volume values lie below `1.2e-38`), and
/// arithmetic on subnormals is many times slower on x86: the host lookups of weights were the slowest part
/// of a refined training step. Such a weight adds under a thousandth of the log-softmax
/// blend's `ε = 1e-9` to its bone's prior, and nothing at `f32` precision to a blend of bones.
pub const NEGLIGIBLE_WEIGHT: f32 = 1e-12;

/// A `(Nx, Ny, Nz, K+1)` grid whose node `(0,0,0)` sits at `bounds.min` and node `(Nx−1, Ny−1, Nz−1)` at
/// `bounds.max` (`grid_sample` with `align_corners=True`). Channels `0..K` are blend weights, channel `K`
/// the distance to the body (metres). Points outside the box read the nearest border value.
///
/// Reading the reference's files with the reference's bounds (SMPL box ± 0.05 m) reproduces its lookup
/// exactly, including its stretch of up to one voxel; volumes anerf builds itself place their nodes so
/// that the mapping is exact.
#[derive(Debug, Clone, PartialEq)]
pub struct BlendWeightVolume {
    pub bounds: Aabb,
    pub dims: [usize; 3],
    pub num_joints: usize,
    /// Row-major `[x][y][z][channel]`.
    pub data: Vec<f32>,
}

impl BlendWeightVolume {
    /// Checks that the data length matches the dimensions, all values are finite and the box is not empty,
    /// and stores weights smaller than [`NEGLIGIBLE_WEIGHT`] as exact zeros.
    pub fn new(
        bounds: Aabb,
        dims: [usize; 3],
        num_joints: usize,
        mut data: Vec<f32>,
    ) -> Result<Self, GeometryError> {
        let channels = num_joints + 1;
        let expected = dims.iter().product::<usize>() * channels;
        if dims.contains(&0) || data.len() != expected {
            return Err(GeometryError::VolumeSize {
                dims,
                channels,
                expected,
                got: data.len(),
            });
        }
        if !(bounds.size().cmpgt(Vec3::ZERO).all()
            && bounds.min.is_finite()
            && bounds.max.is_finite())
        {
            return Err(GeometryError::EmptyBox {
                what: "volume bounds",
                value: format!("{}..{}", bounds.min, bounds.max),
            });
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(GeometryError::NonFinite {
                what: format!("volume value {i}"),
                value: data[i].to_string(),
            });
        }
        for node in data.chunks_exact_mut(channels) {
            for w in &mut node[..num_joints] {
                if w.abs() < NEGLIGIBLE_WEIGHT {
                    *w = 0.0;
                }
            }
        }
        Ok(Self {
            bounds,
            dims,
            num_joints,
            data,
        })
    }

    /// Evaluates `node_values` (the `K + 1` channels at a position) at every node of a `dims` grid over
    /// `bounds`.
    pub fn from_fn(
        bounds: Aabb,
        dims: [usize; 3],
        num_joints: usize,
        node_values: impl Fn(Vec3) -> Vec<f32>,
    ) -> Result<Self, GeometryError> {
        let nodes = dims.iter().product::<usize>();
        let mut volume = Self {
            bounds,
            dims,
            num_joints,
            data: Vec::with_capacity(nodes * (num_joints + 1)),
        };
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    volume
                        .data
                        .extend(node_values(volume.node_position(i, j, k)));
                }
            }
        }
        Self::new(bounds, dims, num_joints, volume.data)
    }

    /// Channels per node (`K + 1`).
    pub fn channels(&self) -> usize {
        self.num_joints + 1
    }

    /// Position of node `(i, j, k)`.
    pub fn node_position(&self, i: usize, j: usize, k: usize) -> Vec3 {
        let t = |idx: usize, n: usize| {
            if n > 1 {
                idx as f32 / (n - 1) as f32
            } else {
                0.0
            }
        };
        let s = Vec3::new(t(i, self.dims[0]), t(j, self.dims[1]), t(k, self.dims[2]));
        self.bounds.min + s * self.bounds.size()
    }

    fn node(&self, i: usize, j: usize, k: usize) -> &[f32] {
        let c = self.channels();
        let start = self.node_index([i, j, k]) * c;
        &self.data[start..start + c]
    }

    /// Trilinear lookup at one point: `K + 1` values (weights, then distance).
    pub fn sample(&self, p: Vec3) -> Vec<f32> {
        let mut out = vec![0.0; self.channels()];
        self.accumulate(p, &mut out);
        out
    }

    /// Adds the trilinear lookup at `p` of the first `out.len()` channels to `out` (zero on entry).
    fn accumulate(&self, p: Vec3, out: &mut [f32]) {
        let c = self.channels();
        for (idx, w) in self.corners(p) {
            let n = self.node_index(idx);
            for (o, v) in out.iter_mut().zip(&self.data[n * c..(n + 1) * c]) {
                *o += w * v;
            }
        }
    }

    /// The distance channel alone at one point (metres): what culling reads for every sample.
    pub fn distance_at(&self, p: Vec3) -> f32 {
        let (base, frac) = self.cell(p);
        self.distance_in_cell(base, frac)
    }

    /// [`Self::distance_at`] from the point's cell and position in it ([`Self::cell`]).
    fn distance_in_cell(&self, base: [usize; 3], frac: [f32; 3]) -> f32 {
        self.cell_corners(base, frac)
            .iter()
            .map(|(idx, w)| w * self.node(idx[0], idx[1], idx[2])[self.num_joints])
            .sum()
    }

    /// The 8 surrounding nodes and their trilinear weights (border clamped).
    fn corners(&self, p: Vec3) -> [([usize; 3], f32); 8] {
        let (base, frac) = self.cell(p);
        self.cell_corners(base, frac)
    }

    /// The cell holding `p` (its lowest node; border clamped) and `p`'s position in it, in `[0, 1]` per axis.
    fn cell(&self, p: Vec3) -> ([usize; 3], [f32; 3]) {
        let mut base = [0usize; 3];
        let mut frac = [0.0f32; 3];
        for a in 0..3 {
            let n = self.dims[a];
            let u = ((p[a] - self.bounds.min[a]) / self.bounds.size()[a] * (n - 1) as f32)
                .clamp(0.0, (n - 1) as f32);
            // `u ≥ 0`, so truncation is the floor (and needs no libm call on baseline x86-64).
            let i0 = (u as usize).min(n.saturating_sub(2));
            base[a] = i0;
            frac[a] = u - i0 as f32;
        }
        (base, frac)
    }

    /// The nodes of the cell at `base` and their trilinear weights at `frac`.
    fn cell_corners(&self, base: [usize; 3], frac: [f32; 3]) -> [([usize; 3], f32); 8] {
        std::array::from_fn(|c| {
            let mut idx = [0usize; 3];
            let mut w = 1.0;
            for a in 0..3 {
                let hi = (c >> a) & 1 == 1;
                idx[a] = (base[a] + hi as usize).min(self.dims[a] - 1);
                w *= if hi { frac[a] } else { 1.0 - frac[a] };
            }
            (idx, w)
        })
    }

    /// The flat index of the node at `idx` (the order of [`Self::data`]'s rows).
    fn node_index(&self, idx: [usize; 3]) -> usize {
        (idx[0] * self.dims[1] + idx[1]) * self.dims[2] + idx[2]
    }

    /// The node spacing per axis (metres; zero along an axis of a single node).
    fn spacing(&self) -> Vec3 {
        let size = self.bounds.size();
        Vec3::from_array(std::array::from_fn(|a| {
            if self.dims[a] > 1 {
                size[a] / (self.dims[a] - 1) as f32
            } else {
                0.0
            }
        }))
    }

    /// Per cell (indexed as [`Self::cell_index`]), a Lipschitz constant of the interpolated distance channel
    /// inside it: there the distance's slope along an axis is a convex blend of the slopes of the cell's four
    /// edges along that axis, so with `s_a` the steepest of them, `|∇d| ≤ √(Σ s_a²)`. An exact distance
    /// field gives about 1 in most cells and at most `√3`. Between any two points the border-clamped
    /// distance changes by at most the largest constant of the cells the clamped segment crosses times the
    /// points' distance (the clamp is a projection, which moves no two points apart).
    fn cell_lipschitz(&self) -> Vec<f32> {
        let spacing = self.spacing();
        let distance =
            |idx: [usize; 3]| self.data[self.node_index(idx) * self.channels() + self.num_joints];
        let c = self.cell_dims();
        let mut constants = Vec::with_capacity(c.iter().product());
        for i in 0..c[0] {
            for j in 0..c[1] {
                for k in 0..c[2] {
                    let corners = self.cell_corners([i, j, k], [0.0; 3]);
                    let mut steepest = [0.0f32; 3];
                    for (idx, _) in &corners {
                        for (a, slope) in steepest.iter_mut().enumerate() {
                            // The edge from a low corner along `a`, where the cell has one along `a`.
                            let low = idx[a] == [i, j, k][a];
                            if low && idx[a] + 1 < self.dims[a] {
                                let mut next = *idx;
                                next[a] += 1;
                                *slope =
                                    slope.max((distance(next) - distance(*idx)).abs() / spacing[a]);
                            }
                        }
                    }
                    constants.push(Vec3::from_array(steepest).length());
                }
            }
        }
        constants
    }

    /// Cells per axis (one even for an axis of a single node).
    fn cell_dims(&self) -> [usize; 3] {
        self.dims.map(|n| n.saturating_sub(1).max(1))
    }

    /// The blocks of [`BoneBlocks`]: a block's nodes are those of its cells, so neighbouring blocks share
    /// their boundary nodes. `lipschitz` holds [`Self::cell_lipschitz`]'s constants.
    fn bone_blocks(&self, lipschitz: &[f32]) -> BoneBlocks {
        let cells = self.cell_dims();
        let dims = cells.map(|c| c.div_ceil(BLOCK_CELLS));
        let nodes = |b: usize, a: usize| {
            let lo = (b * BLOCK_CELLS).min(self.dims[a] - 1);
            lo..=(lo + BLOCK_CELLS).min(self.dims[a] - 1)
        };
        let mut blocks = Vec::with_capacity(dims.iter().product());
        let mut steepest = Vec::with_capacity(dims.iter().product());
        for bi in 0..dims[0] {
            for bj in 0..dims[1] {
                for bk in 0..dims[2] {
                    let (ri, rj, rk) = (nodes(bi, 0), nodes(bj, 1), nodes(bk, 2));
                    let mut weighted = vec![false; self.num_joints];
                    for i in ri.clone() {
                        for j in rj.clone() {
                            for k in rk.clone() {
                                let node = self.node(i, j, k);
                                for (w, has) in node[..self.num_joints].iter().zip(&mut weighted) {
                                    *has |= *w != 0.0;
                                }
                            }
                        }
                    }
                    let bones = (0..self.num_joints as u16)
                        .filter(|&k| weighted[k as usize])
                        .collect();
                    let bounds = Aabb {
                        min: self.node_position(*ri.start(), *rj.start(), *rk.start()),
                        max: self.node_position(*ri.end(), *rj.end(), *rk.end()),
                    };
                    blocks.push((bones, bounds));
                    steepest.push(self.steepest_near_block([bi, bj, bk], lipschitz));
                }
            }
        }
        // Along an axis of one node a point never leaves its cell.
        let spacing = self.spacing();
        let margin = (0..3)
            .filter(|&a| self.dims[a] > 1)
            .map(|a| BLOCK_CELLS as f32 * spacing[a])
            .fold(f32::INFINITY, f32::min);
        BoneBlocks {
            dims,
            blocks,
            steepest,
            margin,
        }
    }

    /// The largest of `lipschitz` (per cell) over the cells of block `b` and of the blocks around it: every
    /// point less than a block's width ([`BoneBlocks::margin`]) from a point of the block lies in one of them.
    fn steepest_near_block(&self, b: [usize; 3], lipschitz: &[f32]) -> f32 {
        let cells = self.cell_dims();
        let range = |a: usize| {
            let lo = (b[a] * BLOCK_CELLS).saturating_sub(BLOCK_CELLS);
            lo..((b[a] + 2) * BLOCK_CELLS).min(cells[a])
        };
        let mut steepest = 0.0f32;
        for i in range(0) {
            for j in range(1) {
                for k in range(2) {
                    steepest = steepest.max(lipschitz[self.cell_index([i, j, k])]);
                }
            }
        }
        steepest
    }

    /// The flat index of the cell at `base`.
    fn cell_index(&self, base: [usize; 3]) -> usize {
        let c = self.cell_dims();
        (base[0] * c[1] + base[1]) * c[2] + base[2]
    }

    /// The least and greatest distance at the corners of every cell (indexed as [`Self::cell_index`]).
    fn cell_distance_ranges(&self) -> Vec<[f32; 2]> {
        let c = self.cell_dims();
        let mut ranges = Vec::with_capacity(c.iter().product());
        for i in 0..c[0] {
            for j in 0..c[1] {
                for k in 0..c[2] {
                    let corners = self.cell_corners([i, j, k], [0.0; 3]);
                    ranges.push(corners.iter().fold(
                        [f32::INFINITY, f32::NEG_INFINITY],
                        |[lo, hi], (idx, _)| {
                            let d = self.node(idx[0], idx[1], idx[2])[self.num_joints];
                            [lo.min(d), hi.max(d)]
                        },
                    ));
                }
            }
        }
        ranges
    }

    /// Uploads the volume for tensor lookups.
    pub fn to_tensor(&self, device: &Device) -> VolumeTensor {
        let nodes = self.dims.iter().product::<usize>();
        let lipschitz = self.cell_lipschitz();
        let distance: Vec<f32> = self
            .data
            .chunks_exact(self.channels())
            .map(|node| node[self.num_joints])
            .collect();
        VolumeTensor {
            table: crate::tensor::from_rows(&self.data, nodes, self.channels(), device),
            distance: crate::tensor::from_rows(&distance, nodes, 1, device),
            host: Arc::new(HostVolume {
                cell_distances: self.cell_distance_ranges(),
                lipschitz: lipschitz.iter().copied().fold(0.0, f32::max),
                blocks: self.bone_blocks(&lipschitz),
                weight_sum: self
                    .data
                    .chunks_exact(self.channels())
                    .map(|node| node[..self.num_joints].iter().sum::<f32>())
                    .fold(0.0, f32::max),
                volume: self.clone(),
            }),
        }
    }
}

/// `[L | t] · (p, 1)` for a `3×4` row-major map.
fn transform_point(m: &[f32; 12], p: Vec3) -> Vec3 {
    Vec3::new(
        m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
        m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
        m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11],
    )
}

/// `‖L‖_F` of a `3×4` row-major map `[L | t]`: how far it moves two points apart per metre between them.
fn linear_norm(m: &[f32; 12]) -> f32 {
    [0, 1, 2, 4, 5, 6, 8, 9, 10]
        .iter()
        .map(|&i| m[i] * m[i])
        .sum::<f32>()
        .sqrt()
}

/// A [`BlendWeightVolume`] on a device: a `[nodes, K+1]` table read with one gather for all 8 corners, and
/// its distance channel `[nodes, 1]` alone (a 25th of the gather); a host copy serves the renderer's culling and
/// prior weights, which need no gradient (it doubles the volume's memory, 8 MiB per frame of the demo).
#[derive(Debug, Clone)]
pub struct VolumeTensor {
    table: Tensor<2>,
    distance: Tensor<2>,
    /// The volume on the host (shared by clones), for the renderer's lookups at constant points.
    host: Arc<HostVolume>,
}

/// A volume on the host with the least and greatest corner distance of each cell: trilinear interpolation
/// is a convex combination of a cell's corners, so every point of a cell lies at least as far from the body as
/// its nearest corner and at most as far as its farthest, and culling interpolates only in cells that straddle
/// the threshold.
#[derive(Debug)]
struct HostVolume {
    volume: BlendWeightVolume,
    cell_distances: Vec<[f32; 2]>,
    /// The largest of [`BlendWeightVolume::cell_lipschitz`]: how far a displacement can move the distance.
    lipschitz: f32,
    /// The largest sum of a node's weights (1 up to rounding and the zeroed negligible weights).
    weight_sum: f32,
    blocks: BoneBlocks,
}

/// Cells per axis of a block of [`BoneBlocks`].
const BLOCK_CELLS: usize = 4;

/// The volume's cells in blocks of [`BLOCK_CELLS`]³, each with the bones that have weight at one of its
/// nodes and its box: a field blended from per-bone maps has only those bones' maps in the block.
#[derive(Debug)]
struct BoneBlocks {
    /// Blocks per axis.
    dims: [usize; 3],
    /// Per block (row-major), its bones and its box (metres).
    blocks: Vec<(Vec<u16>, Aabb)>,
    /// Per block, the distance's Lipschitz constant over the block and the blocks around it
    /// ([`BlendWeightVolume::steepest_near_block`]): it bounds how far a displacement shorter than `margin`
    /// moves the distance of a point of the block (about 1 near the body against the whole volume's `√3`).
    steepest: Vec<f32>,
    /// A block's width along its narrowest axis (metres).
    margin: f32,
}

impl BoneBlocks {
    /// The block holding the cell at `base`.
    fn of_cell(&self, base: [usize; 3]) -> usize {
        let b = base.map(|c| c / BLOCK_CELLS);
        (b[0] * self.dims[1] + b[1]) * self.dims[2] + b[2]
    }
}

/// A bound on the field `δ(p) = Σ_k w_k(p) M_k p̃` of some per-bone maps, block by block of the volume
/// ([`VolumeTensor::field_bound`]): `|δ(p)| ≤ a + s · e` for `p` whose cell lies in a block of bound
/// `[a, s]`, with `e` the distance from `p` to the volume's box. It settles most samples far from the body
/// before any node is blended.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldBound {
    blocks: Vec<[f32; 2]>,
}

impl HostVolume {
    /// Exactly `volume.distance_at(p) < threshold`, interpolating only where the cell's corners straddle the
    /// threshold. The margin covers the rounding of the interpolation weights (which sum to 1 within a few ulp).
    fn is_near(&self, p: Vec3, threshold: f32) -> bool {
        let (base, frac) = self.volume.cell(p);
        let margin = 1e-5 * threshold.abs() + 1e-7;
        self.settled_by_cell(base, threshold, margin)
            .unwrap_or_else(|| self.volume.distance_in_cell(base, frac) < threshold)
    }

    /// `distance < threshold` for every point of the cell at `base`, and for every point whose distance
    /// differs from one of the cell's by at most `slack`, where the cell's corner distances all lie beyond
    /// the threshold by more than `slack` on the same side; `None` where they do not.
    fn settled_by_cell(&self, base: [usize; 3], threshold: f32, slack: f32) -> Option<bool> {
        settled_within(
            self.cell_distances[self.volume.cell_index(base)],
            threshold,
            slack,
        )
    }
}

/// `Some(d < threshold)` for every distance `d` within `slack` of the range `[lo, hi]` where the range lies
/// beyond the threshold by more than `slack` on one side; `None` where it does not.
fn settled_within([lo, hi]: [f32; 2], threshold: f32, slack: f32) -> Option<bool> {
    if lo >= threshold + slack {
        Some(false)
    } else if hi < threshold - slack {
        Some(true)
    } else {
        None
    }
}

/// Blend weights and distance read from a volume at a batch of points.
#[derive(Debug, Clone)]
pub struct VolumeSample {
    /// `[N, K]` prior blend weights `w^s` (interpolated, so rows sum to 1 only up to interpolation).
    pub weights: Tensor<2>,
    /// `[N, 1]` distance to the body, metres.
    pub distance: Tensor<2>,
}

impl VolumeTensor {
    /// Number of joints `K`.
    pub fn num_joints(&self) -> usize {
        self.host.volume.num_joints
    }

    /// The device holding the volume.
    pub fn device(&self) -> Device {
        self.table.device()
    }

    /// Trilinear lookup at points `[N, 3]` (the volume's frame, metres), border clamped; differentiable in
    /// the points.
    pub fn sample(&self, points: Tensor<2>) -> VolumeSample {
        let values = self.interpolate(&self.table, points);
        VolumeSample {
            weights: values.clone().narrow(1, 0, self.host.volume.num_joints),
            distance: values.narrow(1, self.host.volume.num_joints, 1),
        }
    }

    /// The distance to the body at one point of the volume's frame (metres), read on the host: the renderer
    /// culls every sample with it before anything reaches the device.
    pub fn distance_at(&self, p: Vec3) -> f32 {
        self.host.volume.distance_at(p)
    }

    /// Whether a point of the volume's frame lies nearer to the body than `threshold` metres: the same answer as
    /// `distance_at(p) < threshold`, mostly without interpolating (`HostVolume`).
    pub fn is_near(&self, p: Vec3, threshold: f32) -> bool {
        self.host.is_near(p, threshold)
    }

    /// A bound on the field of `maps` (one `[L | t]` a bone, row-major) blended by this volume's weights,
    /// block by block ([`BoneBlocks`]): for `p` in a block's box, `|δ(p)| ≤ Σ_c λ_c Σ_k w_k(c) |M_k p̃| ≤
    /// S · max_k |M_k p̃|` over the block's bones (`S` the largest sum of a node's weights), and `|M_k p̃|` is
    /// convex in `p`, so at most its largest value at the box's corners; outside the volume's box a point
    /// reads its clamped point's cell, and `|M_k p̃|` grows by at most `‖L_k‖_F` a metre from there.
    pub fn field_bound(&self, maps: &[[f32; 12]]) -> FieldBound {
        let host = &*self.host;
        assert_eq!(maps.len(), host.volume.num_joints, "one map a bone");
        let slopes: Vec<f32> = maps.iter().map(linear_norm).collect();
        let sum = host.weight_sum;
        let blocks = host
            .blocks
            .blocks
            .par_iter()
            .map(|(bones, bounds)| {
                let (mut at, mut slope) = (0.0f32, 0.0f32);
                for &k in bones {
                    let m = &maps[k as usize];
                    for x in bounds.corners() {
                        at = at.max(transform_point(m, x).length());
                    }
                    slope = slope.max(slopes[k as usize]);
                }
                [sum * at, sum * slope]
            })
            .collect();
        FieldBound { blocks }
    }

    /// `Some(self.is_near(p + δ(p), threshold))` for every field `δ` under `bound` where the distances at
    /// the corners of `p`'s cell, or else the distance at `p`, settle it, `None` where they do not
    /// ([`Self::is_near_displaced`] answers those). A displacement shorter than a block's width is measured
    /// with the Lipschitz constant around `p`'s block, a longer one with the whole volume's. The slack's
    /// margin covers rounding as there.
    pub fn settled_under(&self, p: Vec3, threshold: f32, bound: &FieldBound) -> Option<bool> {
        let host = &*self.host;
        let v = &host.volume;
        let (base, frac) = v.cell(p);
        let block = host.blocks.of_cell(base);
        let [at, slope] = bound.blocks[block];
        let outside = (p - p.clamp(v.bounds.min, v.bounds.max)).length();
        let reach = at + slope * outside;
        let lipschitz = if reach < host.blocks.margin {
            host.blocks.steepest[block]
        } else {
            host.lipschitz
        };
        let slack = lipschitz * reach * (1.0 + 1e-4) + 1e-5;
        host.settled_by_cell(base, threshold, slack).or_else(|| {
            let d = v.distance_in_cell(base, frac);
            settled_within([d, d], threshold, slack)
        })
    }

    /// The field `δ(p) = Σ_k w_k(p) M_k p̃` of per-bone maps `maps` (one `[L | t]` a bone, row-major, acting on
    /// points of the volume's frame, metres) blended by the volume's interpolated weights at `p`.
    pub fn displacement(&self, maps: &[[f32; 12]], p: Vec3) -> Vec3 {
        let v = &self.host.volume;
        assert_eq!(maps.len(), v.num_joints, "one map a bone");
        let mut scratch = [0.0f32; 64];
        let mut heap = Vec::new();
        let weights = if v.num_joints <= scratch.len() {
            &mut scratch[..v.num_joints]
        } else {
            heap.resize(v.num_joints, 0.0);
            &mut heap[..]
        };
        v.accumulate(p, weights);
        weights
            .iter()
            .zip(maps)
            .filter(|(w, _)| **w != 0.0)
            .map(|(w, m)| *w * transform_point(m, p))
            .sum()
    }

    /// Exactly `self.is_near(p + self.displacement(maps, p), threshold)`.
    pub fn is_near_displaced(&self, p: Vec3, threshold: f32, maps: &[[f32; 12]]) -> bool {
        self.is_near(p + self.displacement(maps, p), threshold)
    }

    /// Prior weights `[N, K]` at host points (the volume's frame, metres) that need no gradient, such as the
    /// renderer's samples: interpolated on the host (as [`BlendWeightVolume::sample`]) and uploaded, instead
    /// of the few dozen tensor operations of [`Self::sample`].
    pub fn weights_at(&self, points: &[Vec3]) -> Tensor<2> {
        let k = self.host.volume.num_joints;
        let mut weights = vec![0.0; points.len() * k];
        // Blocks of points per rayon task: one task per point costs more than its lookup.
        const BLOCK: usize = 256;
        weights
            .par_chunks_mut(BLOCK * k.max(1))
            .zip(points.par_chunks(BLOCK))
            .for_each(|(out, points)| {
                for (out, &p) in out.chunks_exact_mut(k.max(1)).zip(points) {
                    self.host.volume.accumulate(p, &mut out[..k]);
                }
            });
        let n = points.len();
        Tensor::from_data(TensorData::new(weights, [n, k]), &self.table.device())
    }

    /// The distance to the body alone, `[N, 1]` metres: what culling needs, for every sample.
    pub fn sample_distance(&self, points: Tensor<2>) -> Tensor<2> {
        self.interpolate(&self.distance, points)
    }

    /// Trilinear interpolation of the rows of `table` (`[nodes, C]`) at points `[N, 3]` → `[N, C]`
    /// ([`crate::kernels::warp::trilinear`]).
    fn interpolate(&self, table: &Tensor<2>, points: Tensor<2>) -> Tensor<2> {
        crate::kernels::warp::trilinear(points, table.clone(), self.grid())
    }

    /// The volume's node layout, as the kernels take it.
    pub(crate) fn grid(&self) -> TrilinearGrid {
        let (bounds, dims) = (self.host.volume.bounds, self.host.volume.dims);
        let size = bounds.size();
        TrilinearGrid {
            min: bounds.min.to_array(),
            scale: std::array::from_fn(|a| (dims[a] - 1) as f32 / size[a]),
            dims,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::skinning::points_tensor;
    use crate::tensor::to_host;
    use anerf_device::cpu_device;

    /// A volume whose every channel is an affine function of the node position, so trilinear interpolation
    /// reproduces it exactly inside the box.
    fn affine_volume() -> BlendWeightVolume {
        let bounds = Aabb {
            min: Vec3::new(-0.5, -1.0, -0.2),
            max: Vec3::new(0.5, 0.8, 0.3),
        };
        BlendWeightVolume::from_fn(bounds, [5, 7, 3], 2, |p| affine(p).to_vec()).unwrap()
    }

    fn affine(p: Vec3) -> [f32; 3] {
        [
            0.3 + 0.2 * p.x - 0.1 * p.y,
            0.7 - 0.2 * p.x + 0.1 * p.y,
            1.0 + p.x + 2.0 * p.y - 3.0 * p.z,
        ]
    }

    #[test]
    fn trilinear_lookup_reproduces_affine_fields_and_clamps_outside() {
        let v = affine_volume();
        let pts = [
            Vec3::new(0.1, 0.2, 0.05),
            Vec3::new(-0.49, 0.79, -0.19),
            Vec3::new(0.33, -0.6, 0.12),
        ];
        for p in pts {
            let got = v.sample(p);
            for (g, e) in got.iter().zip(affine(p)) {
                assert!((g - e).abs() < 1e-5, "{p}: {got:?}");
            }
        }
        // Outside: the border value, i.e. the value at the clamped point.
        let outside = Vec3::new(2.0, -3.0, 0.1);
        let clamped = outside.clamp(v.bounds.min, v.bounds.max);
        assert_eq!(v.sample(outside), v.sample(clamped));
        let tensor = v.to_tensor(&cpu_device());
        let all: Vec<Vec3> = pts.iter().copied().chain([outside]).collect();
        let s = tensor.sample(points_tensor(&all, &cpu_device()));
        let (w, d) = (to_host(s.weights), to_host(s.distance));
        let alone = to_host(tensor.sample_distance(points_tensor(&all, &cpu_device())));
        assert_eq!(alone, d);
        for (i, p) in all.iter().enumerate() {
            let e = v.sample(*p);
            assert!(
                (w[2 * i] - e[0]).abs() < 1e-5
                    && (w[2 * i + 1] - e[1]).abs() < 1e-5
                    && (d[i] - e[2]).abs() < 1e-5
            );
            // The host copy of the distance channel that culling reads.
            assert!((tensor.distance_at(*p) - d[i]).abs() < 1e-5);
        }
        // The renderer's lookup at constant points: host corners, one gather.
        let host = to_host(tensor.weights_at(&all));
        for (h, t) in host.iter().zip(&w) {
            assert!((h - t).abs() < 1e-6, "{host:?} vs {w:?}");
        }
    }

    /// A non-affine field of three weights and a distance over a box.
    fn wavy_volume() -> BlendWeightVolume {
        let bounds = Aabb {
            min: Vec3::new(-0.4, -0.9, -0.25),
            max: Vec3::new(0.6, 0.7, 0.35),
        };
        BlendWeightVolume::from_fn(bounds, [6, 9, 4], 3, |p| {
            vec![
                (3.0 * p.x).sin().abs(),
                p.y * p.y + 0.1,
                (p.x * p.z * 7.0).cos().abs(),
                p.length() - 0.3,
            ]
        })
        .unwrap()
    }

    /// Points inside, on and beyond the border of [`wavy_volume`]'s box.
    pub(crate) const LOOKUP_POINTS: usize = 700;

    /// The lookup of [`wavy_volume`] at [`LOOKUP_POINTS`] random points on `device` (with autodiff), by the
    /// fused kernel or the tensor reference: the values `[N, 4]` and the points' gradient `[N, 3]` of a random
    /// linear functional of every channel.
    pub(crate) fn wavy_lookup(device: &Device, fused: bool) -> (Vec<f32>, Vec<f32>) {
        let device = device.clone().autodiff();
        let tensor = wavy_volume().to_tensor(&device);
        let n = LOOKUP_POINTS;
        let mut rng = crate::geometry::lbs::tests::TestRng(17);
        let points: Vec<Vec3> = (0..n).map(|_| rng.vec3(1.0)).collect();
        let coeff: Vec<f32> = (0..n * 4).map(|_| rng.range(-1.0, 1.0)).collect();
        let p = points_tensor(&points, &device).require_grad();
        let out = if fused {
            assert!(crate::kernels::available(&device));
            tensor.interpolate(&tensor.table, p.clone())
        } else {
            crate::kernels::warp::reference::trilinear(
                p.clone(),
                tensor.table.clone(),
                &tensor.grid(),
            )
        };
        let c = crate::tensor::from_rows(&coeff, n, 4, &device);
        let grads = (out.clone() * c).sum().backward();
        (to_host(out), to_host(p.grad(&grads).unwrap()))
    }

    /// The fused kernel against the tensor reference on a non-affine field, at points inside, on and beyond
    /// the border: values and the points' gradient of a random linear functional of every channel.
    #[test]
    fn fused_lookup_matches_the_tensor_reference() {
        let (value, grad) = wavy_lookup(&cpu_device(), true);
        let (expected_value, expected_grad) = wavy_lookup(&cpu_device(), false);
        anerf_testing::assert_close(
            "trilinear value",
            &value,
            &expected_value,
            anerf_testing::Tolerance::Relative(1e-5),
        );
        anerf_testing::assert_close(
            "trilinear gradient",
            &grad,
            &expected_grad,
            anerf_testing::Tolerance::Relative(1e-4),
        );
        assert!(grad.contains(&0.0) && grad.iter().any(|g| *g != 0.0));
    }

    #[test]
    fn lookup_gradient_follows_the_field() {
        let v = affine_volume();
        let device = cpu_device().autodiff();
        let p = points_tensor(&[Vec3::new(0.1, 0.2, 0.05)], &device).require_grad();
        let grads = v
            .to_tensor(&device)
            .sample(p.clone())
            .distance
            .sum()
            .backward();
        let g = to_host(p.grad(&grads).unwrap());
        for (a, b) in g.iter().zip([1.0, 2.0, -3.0]) {
            assert!((a - b).abs() < 1e-4, "{g:?}");
        }
    }

    /// The culling test against interpolating everywhere: a volume of random distances (so cells straddle,
    /// lie below and above the thresholds), points inside and outside the box, thresholds at node values.
    #[test]
    fn is_near_agrees_with_the_interpolated_distance_everywhere() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let bounds = Aabb {
            min: Vec3::new(-0.4, -0.9, -0.3),
            max: Vec3::new(0.6, 0.9, 0.2),
        };
        let dims = [6, 9, 1];
        let data: Vec<f32> = (0..dims.iter().product::<usize>())
            .flat_map(|_| [0.5, rng.random_range(0.0..0.2f32)])
            .collect();
        let v = BlendWeightVolume::new(bounds, dims, 1, data).unwrap();
        let host = v.to_tensor(&cpu_device());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let node_distance = v.data[2 * 17 + 1];
        let (mut near, mut far) = (0, 0);
        for threshold in [0.05, 0.1, 0.15, node_distance, 0.0, 1.0] {
            for _ in 0..4000 {
                let p = Vec3::new(
                    rng.random_range(-0.6..0.8),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.4..0.3),
                );
                let expected = v.distance_at(p) < threshold;
                assert_eq!(host.is_near(p, threshold), expected, "{p} at {threshold}");
                if expected {
                    near += 1;
                } else {
                    far += 1;
                }
            }
        }
        assert!(near > 1000 && far > 1000, "{near} near, {far} far");
    }

    /// The displaced culling test: a capsule's distance field with three bones' weights (zero over parts of
    /// the box), per-bone affine maps moving points by up to about 10 cm, points inside and outside the box.
    /// The displacement is the device's per-point blend (the weights looked up as tensors, then the maps
    /// blended by them) and, where every bone has the same map, that map itself (the weights sum to 1). The
    /// field's bound block by block ([`VolumeTensor::field_bound`]) holds at every point, and the points it
    /// settles (thousands, not all of the far ones) get the displaced point's answer.
    #[test]
    fn is_near_displaced_agrees_with_displacing_every_point() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let bounds = Aabb {
            min: Vec3::new(-0.3, -0.8, -0.25),
            max: Vec3::new(0.35, 0.8, 0.3),
        };
        let v = BlendWeightVolume::from_fn(bounds, [14, 33, 12], 3, |p| {
            let axis = Vec3::new(0.0, p.y.clamp(-0.5, 0.5), 0.0);
            let (lower, upper) = ((-p.y).max(0.0), p.y.max(0.0));
            vec![
                lower,
                upper,
                1.0 - lower - upper,
                ((p - axis).length() - 0.1).abs(),
            ]
        })
        .unwrap();
        let host = v.to_tensor(&cpu_device());
        let maps: Vec<[f32; 12]> = (0..3)
            .map(|_| {
                std::array::from_fn(|i| {
                    rng.random_range(-0.08..0.08f32) * if i % 4 == 3 { 0.6 } else { 1.0 }
                })
            })
            .collect();
        let points: Vec<Vec3> = (0..20_000)
            .map(|_| {
                Vec3::new(
                    rng.random_range(-0.35..0.4),
                    rng.random_range(-0.9..0.9),
                    rng.random_range(-0.3..0.35),
                )
            })
            .collect();
        // The device's blend: weights `[N, K]` as tensors, the maps blended per point.
        let device = cpu_device();
        let rows: Vec<f32> = maps.iter().flatten().copied().collect();
        let per_point = to_host(
            crate::geometry::BoneMatrices::from_rows(crate::tensor::from_rows(
                &rows, 3, 12, &device,
            ))
            .forward(
                points_tensor(&points, &device),
                host.sample(points_tensor(&points, &device)).weights,
            ),
        );
        let same = [maps[0]; 3];
        let bound = host.field_bound(&maps);
        let (mut near, mut far, mut settled_by_bound) = (0, 0, 0);
        for (i, &p) in points.iter().enumerate() {
            let delta = host.displacement(&maps, p);
            let q = p + Vec3::from_slice(&per_point[3 * i..3 * i + 3]);
            assert!(
                (p + delta - q).length() < 1e-6,
                "{p}: {} against {q}",
                p + delta
            );
            assert!((host.displacement(&same, p) - transform_point(&maps[0], p)).length() < 1e-6);
            let expected = host.is_near(q, 0.05);
            assert_eq!(host.is_near_displaced(p, 0.05, &maps), expected, "{p}");
            // The field's bound holds at every point, and where it settles a point it is right.
            let outside = (p - p.clamp(bounds.min, bounds.max)).length();
            let [at, slope] = bound.blocks[host.host.blocks.of_cell(v.cell(p).0)];
            assert!(
                (q - p).length() <= (at + slope * outside) * (1.0 + 1e-5),
                "{p}: |δ| {} over the block's bound {at} + {slope} · {outside} m outside",
                (q - p).length()
            );
            if let Some(settled) = host.settled_under(p, 0.05, &bound) {
                assert_eq!(settled, expected, "{p}: settled by the bound");
                settled_by_bound += 1;
            }
            if expected {
                near += 1;
            } else {
                far += 1;
            }
        }
        assert!(near > 1000 && far > 1000, "{near} near, {far} far");
        assert!(
            settled_by_bound > 1000 && settled_by_bound < far,
            "the bound settled {settled_by_bound} of {far} far points"
        );
    }

    /// The Lipschitz constants culling settles with: for pairs of points a random step apart, the
    /// interpolated distance changes by at most the constant around the first point's block times the step
    /// where the step is shorter than a block's width, and by the whole volume's constant for any step; on a
    /// field whose slope differs from region to region, the constant near a block is below the volume's.
    #[test]
    fn the_distance_moves_by_at_most_its_lipschitz_constant() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let bounds = Aabb {
            min: Vec3::new(-0.5, -0.9, -0.3),
            max: Vec3::new(0.5, 0.9, 0.3),
        };
        // Steep along x on one side, shallow elsewhere, and a wavy term: no single slope.
        let v = BlendWeightVolume::from_fn(bounds, [21, 37, 13], 1, |p| {
            vec![
                1.0,
                3.0 * p.x.max(0.0) + 0.4 * (5.0 * p.y).sin() + 0.3 * p.z * p.z,
            ]
        })
        .unwrap();
        let host = v.to_tensor(&cpu_device());
        let blocks = &host.host.blocks;
        let (mut local_used, mut tight) = (0, 0);
        for _ in 0..20_000 {
            let p = Vec3::new(
                rng.random_range(-0.6..0.6),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.4..0.4),
            );
            let step = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ) * rng.random_range(0.0..0.3f32);
            let change = (v.distance_at(p + step) - v.distance_at(p)).abs();
            let length = step.length();
            assert!(
                change <= host.host.lipschitz * length * (1.0 + 1e-4) + 1e-6,
                "{p} + {step}"
            );
            if length < blocks.margin {
                let block = blocks.of_cell(v.cell(p).0);
                let local = blocks.steepest[block];
                assert!(
                    change <= local * length * (1.0 + 1e-4) + 1e-6,
                    "{p} + {step}: {change} over {local}"
                );
                local_used += 1;
                tight += usize::from(local < 0.9 * host.host.lipschitz);
            }
        }
        assert!(
            local_used > 1000 && tight > 1000,
            "{local_used} local, {tight} tighter"
        );
    }

    /// Weights below [`NEGLIGIBLE_WEIGHT`] (subnormal ones among them) are stored as zeros, larger ones and
    /// the distance channel, however small, as given.
    #[test]
    fn negligible_weights_are_stored_as_zeros() {
        let bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let node = [1e-40, -1e-13, 1e-12, 0.5, 1e-40];
        let v = BlendWeightVolume::new(bounds, [2, 2, 2], 4, node.repeat(8)).unwrap();
        for stored in v.data.chunks_exact(5) {
            assert_eq!(stored, [0.0, 0.0, 1e-12, 0.5, 1e-40]);
        }
    }

    #[test]
    fn malformed_volumes_are_rejected() {
        let b = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        assert_eq!(
            BlendWeightVolume::new(b, [2, 2, 2], 1, vec![0.0; 15]).unwrap_err(),
            GeometryError::VolumeSize {
                dims: [2, 2, 2],
                channels: 2,
                expected: 16,
                got: 15
            }
        );
        assert!(matches!(
            BlendWeightVolume::new(b, [2, 2, 2], 1, vec![f32::NAN; 16]).unwrap_err(),
            GeometryError::NonFinite { .. }
        ));
        let flat = Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(1.0, 0.0, 1.0),
        };
        assert!(matches!(
            BlendWeightVolume::new(flat, [2, 2, 2], 1, vec![0.0; 16]).unwrap_err(),
            GeometryError::EmptyBox { .. }
        ));
    }
}
