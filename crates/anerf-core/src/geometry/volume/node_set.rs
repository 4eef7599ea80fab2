//! A set of a volume's nodes (flat indices, [`super::BlendWeightVolume`]'s row order) as a bitmap with each
//! word's rank, so that a member's position among the members, in index order, is one lookup and a count of
//! bits: tables that hold values for only some nodes index their rows by it.

use rayon::prelude::*;

/// Nodes `0..len` as one bit each, with the number of members before each 64-node word.
#[derive(Debug, Clone)]
pub(crate) struct NodeSet {
    bits: Vec<u64>,
    rank: Vec<u32>,
    len: usize,
}

impl NodeSet {
    /// The nodes that `members` yields (each as many times as it likes), of `len` nodes. The yielded indices
    /// must be below `len`.
    pub(crate) fn collect<I>(len: usize, members: I) -> Self
    where
        I: ParallelIterator<Item = usize>,
    {
        let words = len.div_ceil(64);
        let bits = members
            .fold(
                || vec![0u64; words],
                |mut bits, n| {
                    assert!(n < len, "node {n} of {len}");
                    bits[n / 64] |= 1 << (n % 64);
                    bits
                },
            )
            .reduce(
                || vec![0u64; words],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(a, b)| *a |= b);
                    a
                },
            );
        let rank = bits
            .iter()
            .scan(0u32, |before, w| {
                let here = *before;
                *before += w.count_ones();
                Some(here)
            })
            .collect();
        Self { bits, rank, len }
    }

    /// How many nodes the set is of (members or not).
    pub(crate) fn nodes(&self) -> usize {
        self.len
    }

    /// The number of members.
    pub(crate) fn count(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// The members in increasing order.
    pub(crate) fn members(&self) -> Vec<usize> {
        let mut out = Vec::with_capacity(self.count());
        for (i, &word) in self.bits.iter().enumerate() {
            let mut w = word;
            while w != 0 {
                out.push(i * 64 + w.trailing_zeros() as usize);
                w &= w - 1;
            }
        }
        out
    }

    /// The position of member `n` among the members in increasing order; `None` when `n` is not one.
    pub(crate) fn position(&self, n: usize) -> Option<usize> {
        let word = *self.bits.get(n / 64)?;
        let bit = 1u64 << (n % 64);
        (word & bit != 0)
            .then(|| self.rank[n / 64] as usize + (word & (bit - 1)).count_ones() as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Against a sorted, deduplicated list: the members, their count, and every node's position (its index
    /// in the list, or none), for sets from empty to full over lengths that do and do not fill a word.
    #[test]
    fn positions_are_the_members_sorted_order() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for len in [1, 63, 64, 65, 200, 1000] {
            for draws in [0, 1, 10, len / 2, 4 * len] {
                let drawn: Vec<usize> = (0..draws).map(|_| rng.random_range(0..len)).collect();
                let set = NodeSet::collect(len, drawn.par_iter().copied());
                let mut expected = drawn.clone();
                expected.sort_unstable();
                expected.dedup();
                assert_eq!(set.members(), expected, "{len} nodes, {draws} draws");
                assert_eq!(set.count(), expected.len());
                assert_eq!(set.nodes(), len);
                for n in 0..len + 70 {
                    assert_eq!(
                        set.position(n),
                        expected.binary_search(&n).ok(),
                        "node {n} of {len}"
                    );
                }
            }
        }
    }
}
