//! Which latent code each point of a batch is conditioned on: one code for the whole batch (a render of one
//! frame), or one code per group of consecutive points (a render of several frames at once, each frame's
//! points one group), so that one MLP call serves every frame of a training step.

use burn::prelude::*;

/// Rows of a code table (an `Embedding`'s weight, `[codes, C]`) for a batch of points.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CodeRows {
    /// Every point uses this row.
    One(usize),
    /// Consecutive groups of points, `(row, points)` each, in the batch's order.
    Groups(Vec<(usize, usize)>),
}

impl CodeRows {
    /// The codes of `table` for these points. A single group is [`CodeRows::One`]: the same operations,
    /// and so the same values, as a batch of one frame.
    pub fn codes(&self, table: Tensor<2>) -> Codes {
        match self {
            Self::One(row) => Codes {
                rows: table.narrow(0, *row, 1),
                of_point: None,
            },
            Self::Groups(groups) if groups.len() == 1 => Self::One(groups[0].0).codes(table),
            Self::Groups(groups) => {
                let device = table.device();
                let rows: Vec<i64> = groups.iter().map(|&(row, _)| row as i64).collect();
                let of_point: Vec<i64> = groups
                    .iter()
                    .enumerate()
                    .flat_map(|(g, &(_, n))| std::iter::repeat_n(g as i64, n))
                    .collect();
                let rows =
                    Tensor::<1, Int>::from_data(TensorData::new(rows, [groups.len()]), &device);
                let n = of_point.len();
                Codes {
                    rows: table.select(0, rows),
                    of_point: Some(Tensor::from_data(TensorData::new(of_point, [n]), &device)),
                }
            }
        }
    }
}

/// Latent codes for a batch of points: `[G, C]` rows and, for more than one row, the row of each point.
#[derive(Debug, Clone)]
pub struct Codes {
    rows: Tensor<2>,
    of_point: Option<Tensor<1, Int>>,
}

impl Codes {
    /// A per-row map of the codes (`[G, C] → [G, D]`, e.g. a layer's part that meets the code) carried to
    /// the points: `[1, D]`, broadcast over the batch, for one code; `[N, D]` for groups. Mapping the `G`
    /// codes before spreading them costs `G` rows instead of `N`.
    pub fn project(&self, map: impl FnOnce(Tensor<2>) -> Tensor<2>) -> Tensor<2> {
        let projected = map(self.rows.clone());
        match &self.of_point {
            None => projected,
            Some(of_point) => projected.select(0, of_point.clone()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::{from_rows, to_host};
    use anerf_device::cpu_device;

    /// Grouped codes give each point its group's row of the mapped table, as one code per group would.
    #[test]
    fn grouped_codes_give_each_point_its_groups_row() {
        let device = cpu_device();
        let table: Vec<f32> = (0..12).map(|i| i as f32 * 0.5 - 1.0).collect();
        let t = from_rows(&table, 4, 3, &device);
        let map = |c: Tensor<2>| c * 2.0 + 1.0;
        let groups = [(2, 3), (0, 1), (3, 2)];
        let got = to_host(
            CodeRows::Groups(groups.to_vec())
                .codes(t.clone())
                .project(map),
        );
        let expected: Vec<f32> = groups
            .iter()
            .flat_map(|&(row, n)| {
                std::iter::repeat_n(to_host(map(t.clone().narrow(0, row, 1))), n).flatten()
            })
            .collect();
        assert_eq!(got, expected);
        let one = to_host(CodeRows::Groups(vec![(1, 5)]).codes(t.clone()).project(map));
        assert_eq!(
            one,
            to_host(map(t.narrow(0, 1, 1))),
            "one group broadcasts its row"
        );
    }
}
