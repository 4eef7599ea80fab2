//! Nearest points on a triangle mesh (or among its vertices) through a bounding-volume hierarchy: the
//! spatial index behind the blend-weight volumes. Positions are metres in whatever frame the caller uses.

use anerf_core::geometry::Aabb;
use glam::Vec3;

/// The closest point found: which face (or vertex), its barycentric coordinates, and the distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closest {
    /// Index of the face (triangle mode) or vertex (vertex mode).
    pub index: usize,
    /// Barycentric weights of the face's three vertices (`[1, 0, 0]` in vertex mode).
    pub barycentric: [f32; 3],
    /// Euclidean distance (metres).
    pub distance: f32,
}

/// Leaves hold at most this many primitives.
const LEAF_SIZE: usize = 4;

#[derive(Debug, Clone)]
struct Node {
    bounds: Aabb,
    /// Leaf: `start..start + count` of `order`; inner: children at `start` and `start + 1`... encoded by
    /// `count == 0` with the right child index in `start`.
    start: usize,
    count: usize,
}

/// A BVH over triangles (or over single points, the reference's nearest-vertex variant).
#[derive(Debug, Clone)]
pub struct MeshIndex {
    vertices: Vec<Vec3>,
    faces: Vec<[u32; 3]>,
    points_only: bool,
    order: Vec<usize>,
    /// Bounds of `faces[order[slot]]` at each `slot`: a cheap test before the exact distance.
    prim_boxes: Vec<Aabb>,
    nodes: Vec<Node>,
}

impl MeshIndex {
    /// An index over the mesh's triangles (nearest surface point).
    pub fn triangles(vertices: &[Vec3], faces: &[[u32; 3]]) -> Self {
        Self::build(vertices.to_vec(), faces.to_vec(), false)
    }

    /// An index over the mesh's vertices (nearest vertex).
    pub fn vertices(vertices: &[Vec3]) -> Self {
        let faces = (0..vertices.len() as u32).map(|i| [i, i, i]).collect();
        Self::build(vertices.to_vec(), faces, true)
    }

    fn prim_bounds(&self, i: usize) -> Aabb {
        let f = self.faces[i];
        Aabb::from_points(f.map(|v| self.vertices[v as usize])).expect("three points")
    }

    fn build(vertices: Vec<Vec3>, faces: Vec<[u32; 3]>, points_only: bool) -> Self {
        let mut index = Self {
            order: (0..faces.len()).collect(),
            vertices,
            faces,
            points_only,
            prim_boxes: Vec::new(),
            nodes: Vec::new(),
        };
        if !index.faces.is_empty() {
            let centroids: Vec<Vec3> = (0..index.faces.len())
                .map(|i| {
                    let b = index.prim_bounds(i);
                    (b.min + b.max) * 0.5
                })
                .collect();
            let mut order = std::mem::take(&mut index.order);
            index.split(&mut order, 0, &centroids);
            index.prim_boxes = order.iter().map(|&i| index.prim_bounds(i)).collect();
            index.order = order;
        }
        index
    }

    /// Builds the subtree over `order[offset..offset + items.len()]`; returns its node index.
    fn split(&mut self, items: &mut [usize], offset: usize, centroids: &[Vec3]) -> usize {
        let bounds = items
            .iter()
            .map(|&i| self.prim_bounds(i))
            .reduce(|a, b| Aabb {
                min: a.min.min(b.min),
                max: a.max.max(b.max),
            })
            .expect("non-empty node");
        let id = self.nodes.len();
        self.nodes.push(Node {
            bounds,
            start: offset,
            count: items.len(),
        });
        if items.len() <= LEAF_SIZE {
            return id;
        }
        let extent = bounds.size();
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |&a, &b| {
            centroids[a][axis].total_cmp(&centroids[b][axis])
        });
        let (left, right) = items.split_at_mut(mid);
        self.split(left, offset, centroids);
        let r = self.split(right, offset + mid, centroids);
        self.nodes[id].count = 0;
        self.nodes[id].start = r;
        id
    }

    /// The nearest primitive to `p`; `None` for an empty mesh.
    pub fn closest(&self, p: Vec3) -> Option<Closest> {
        self.closest_within(p, f32::INFINITY)
    }

    /// The nearest primitive to `p` if it lies within `bound` metres, else `None`. With a bound at or above
    /// the true distance the answer is [`closest`](Self::closest)'s; the bound only prunes the search, so a
    /// caller that knows a nearby primitive (the previous grid node's) searches far fewer boxes. The bound
    /// carries a slack of 1e-5 of itself plus a micrometre (rounding of the closest point at coordinates of
    /// a metre or so), so one taken from [`distance_to`](Self::distance_to) of the nearest primitive finds it.
    pub fn closest_within(&self, p: Vec3, bound: f32) -> Option<Closest> {
        let slack = bound * (1.0 + 1e-5) + 1e-6;
        let limit = slack * slack;
        let mut best: Option<(f32, usize, [f32; 3])> = None;
        // Each entry keeps its box's squared distance, measured when its parent was opened. Median splits
        // halve every node, so the depth (and the stack) stays under 64.
        let mut stack = [(0usize, 0.0f32); 64];
        let mut top = 0;
        if let Some(root) = self.nodes.first() {
            stack[0] = (0, box_distance2(&root.bounds, p));
            top = 1;
        }
        while top > 0 {
            top -= 1;
            let (n, d2) = stack[top];
            if d2 > best.map_or(limit, |(b, _, _)| b) {
                continue;
            }
            let node = &self.nodes[n];
            if node.count > 0 {
                for slot in node.start..node.start + node.count {
                    let reach = best.map_or(limit, |(b, _, _)| b);
                    if box_distance2(&self.prim_boxes[slot], p) > reach {
                        continue;
                    }
                    let i = self.order[slot];
                    let (d2, bary) = self.prim_distance2(i, p);
                    if d2 <= limit && best.is_none_or(|(b, _, _)| d2 < b) {
                        best = Some((d2, i, bary));
                    }
                }
            } else {
                let (l, r) = (n + 1, node.start);
                let (dl, dr) = (
                    box_distance2(&self.nodes[l].bounds, p),
                    box_distance2(&self.nodes[r].bounds, p),
                );
                // Visit the nearer child first (pushed last); a child beyond reach is never pushed.
                let reach = best.map_or(limit, |(b, _, _)| b);
                let (near, far) = if dl < dr {
                    ((l, dl), (r, dr))
                } else {
                    ((r, dr), (l, dl))
                };
                if far.1 <= reach {
                    stack[top] = far;
                    top += 1;
                }
                if near.1 <= reach {
                    stack[top] = near;
                    top += 1;
                }
            }
        }
        best.map(|(d2, index, barycentric)| Closest {
            index,
            barycentric,
            distance: d2.sqrt(),
        })
    }

    /// Distance from `p` to primitive `i` (metres): an upper bound on [`closest`](Self::closest)'s.
    pub fn distance_to(&self, i: usize, p: Vec3) -> f32 {
        self.prim_distance2(i, p).0.sqrt()
    }

    fn prim_distance2(&self, i: usize, p: Vec3) -> (f32, [f32; 3]) {
        let f = self.faces[i];
        if self.points_only {
            return (
                self.vertices[f[0] as usize].distance_squared(p),
                [1.0, 0.0, 0.0],
            );
        }
        let [a, b, c] = f.map(|v| self.vertices[v as usize]);
        let bary = closest_on_triangle(p, a, b, c);
        let q = a * bary[0] + b * bary[1] + c * bary[2];
        (q.distance_squared(p), bary)
    }
}

fn box_distance2(b: &Aabb, p: Vec3) -> f32 {
    let d = (b.min - p).max(p - b.max).max(Vec3::ZERO);
    d.length_squared()
}

/// Barycentric coordinates of the point of triangle `abc` closest to `p` (Ericson, *Real-Time Collision
/// Detection*, §5.1.5): Voronoi regions of the vertices, then the edges, then the face.
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f32; 3] {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = va + vb + vc;
    if denom.abs() < f32::MIN_POSITIVE {
        // Degenerate (zero-area) triangle: fall back to its nearest vertex.
        let d = [a, b, c].map(|v| v.distance_squared(p));
        let i = (0..3).min_by(|&i, &j| d[i].total_cmp(&d[j])).unwrap_or(0);
        let mut out = [0.0; 3];
        out[i] = 1.0;
        return out;
    }
    let (v, w) = (vb / denom, vc / denom);
    [1.0 - v - w, v, w]
}
