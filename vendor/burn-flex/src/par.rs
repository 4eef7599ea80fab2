//! anerf patch: element-wise loops over large buffers split into chunks for rayon's threads.
//!
//! Upstream runs unary, scalar and non-SIMD binary element-wise ops on the calling thread, and its SIMD
//! add/sub/mul/div only fan out at 4 Mi elements (lowered here too). A training step of a small MLP is
//! dominated by such ops on `[65536, 64]` tensors, so one of two cores idled through them. Every helper here
//! runs the same per-element closure as the sequential loop it replaces, over disjoint chunks, so results
//! are identical.

use alloc::vec::Vec;

/// Elements per task: large enough that dispatch costs nothing measurable, small enough to balance.
#[cfg(feature = "rayon")]
const CHUNK: usize = 1 << 14;

/// Buffers shorter than this stay on the calling thread.
#[cfg(feature = "rayon")]
const MIN_PARALLEL: usize = 1 << 16;

/// Whether a loop over `len` elements is split across threads.
#[cfg(feature = "rayon")]
#[inline]
fn parallel(len: usize) -> bool {
    len >= MIN_PARALLEL
}

/// `x = op(x)` for every element of `dst`.
#[inline]
pub(crate) fn map_inplace<E, Op>(dst: &mut [E], op: Op)
where
    E: Copy + Send,
    Op: Fn(E) -> E + Sync,
{
    let run = |c: &mut [E]| c.iter_mut().for_each(|x| *x = op(*x));
    #[cfg(feature = "rayon")]
    if parallel(dst.len()) {
        use rayon::prelude::*;
        dst.par_chunks_mut(CHUNK).for_each(run);
        return;
    }
    run(dst)
}

/// `d = op(d, s)` for every pair of elements of `dst` and `src` (same length).
#[inline]
pub(crate) fn zip_inplace<D, S, Op>(dst: &mut [D], src: &[S], op: Op)
where
    D: Copy + Send,
    S: Copy + Sync,
    Op: Fn(D, S) -> D + Sync,
{
    debug_assert_eq!(dst.len(), src.len());
    let run = |(d, s): (&mut [D], &[S])| {
        d.iter_mut().zip(s).for_each(|(d, &s)| *d = op(*d, s));
    };
    #[cfg(feature = "rayon")]
    if parallel(dst.len()) {
        use rayon::prelude::*;
        dst.par_chunks_mut(CHUNK)
            .zip(src.par_chunks(CHUNK))
            .for_each(run);
        return;
    }
    run((dst, src))
}

/// `op(x)` of every element of `src`, collected.
#[inline]
pub(crate) fn map<S, E, Op>(src: &[S], op: Op) -> Vec<E>
where
    S: Copy + Sync,
    E: Send,
    Op: Fn(S) -> E + Sync + Send,
{
    #[cfg(feature = "rayon")]
    if parallel(src.len()) {
        use rayon::prelude::*;
        let mut out = Vec::with_capacity(src.len());
        src.par_iter().map(|&x| op(x)).collect_into_vec(&mut out);
        return out;
    }
    src.iter().map(|&x| op(x)).collect()
}

/// `op(l, r)` of every pair of elements of `lhs` and `rhs` (same length), collected.
#[inline]
pub(crate) fn zip_map<L, R, E, Op>(lhs: &[L], rhs: &[R], op: Op) -> Vec<E>
where
    L: Copy + Sync,
    R: Copy + Sync,
    E: Send,
    Op: Fn(L, R) -> E + Sync + Send,
{
    debug_assert_eq!(lhs.len(), rhs.len());
    #[cfg(feature = "rayon")]
    if parallel(lhs.len()) {
        use rayon::prelude::*;
        let mut out = Vec::with_capacity(lhs.len());
        lhs.par_iter()
            .zip(rhs)
            .map(|(&l, &r)| op(l, r))
            .collect_into_vec(&mut out);
        return out;
    }
    lhs.iter().zip(rhs).map(|(&l, &r)| op(l, r)).collect()
}

/// Rows of a dense buffer, `row_len` elements each, dealt to threads in blocks: `f(first_row, rows)`.
#[inline]
pub(crate) fn for_row_blocks<E, F>(dst: &mut [E], row_len: usize, f: F)
where
    E: Send,
    F: Fn(usize, &mut [E]) + Sync,
{
    #[cfg(feature = "rayon")]
    if row_len > 0 && parallel(dst.len()) {
        use rayon::prelude::*;
        let rows_per_task = CHUNK.div_ceil(row_len);
        dst.par_chunks_mut(rows_per_task * row_len)
            .enumerate()
            .for_each(|(i, block)| f(i * rows_per_task, block));
        return;
    }
    f(0, dst)
}
