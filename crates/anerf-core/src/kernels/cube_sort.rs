//! Device-wide scans and sorts of `u32` arrays for the CubeCL kernels (the `wgpu` and `cuda` features), so
//! that work lists (the splat rasteriser's tiles) are built where their data lives, with no read-back.
//!
//! [`exclusive_scan`] is Hillis–Steele's: `⌈log₂ n⌉` launches, each adding the value `2^k` places back,
//! between two buffers. [`sort_pairs`] is a least-significant-digit radix sort, 4 bits a pass: each unit
//! owns a chunk of [`CHUNK`] consecutive entries, counts its digits, and after a scan of the counts (digit
//! by digit, chunk by chunk) writes its entries in their input order to the slots that scan gives them, so
//! every pass, and the sort, is stable. Both are simple before they are fast: no shared memory and no
//! subgroup operations, which keeps them on every adapter wgpu finds (software Vulkan and OpenGL included).
//!
//! Arrays are contiguous `[n]` tensors of `DType::U32`.

use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl;
use burn_cubecl::ops::into_data_sync;
use burn_cubecl::ops::numeric::empty_device_contiguous_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::cube::Units;

/// Bits of the key one radix pass orders by.
const RADIX_BITS: u32 = 4;
/// Digits of a pass.
const BINS: usize = 1 << RADIX_BITS;
/// A key's digit, once shifted.
const DIGIT_MASK: u32 = (1 << RADIX_BITS) - 1;
/// Entries one unit counts and places per pass.
const CHUNK: usize = 256;

/// `out[i] = input[i − 1]` (`out[0] = 0`) for `i ≤ n`: the scan's first buffer, one longer than the input.
#[cube(launch_unchecked)]
fn shift_in(input: &Tensor<u32>, out: &mut Tensor<u32>, n: u32) {
    let i = ABSOLUTE_POS;
    if i > n as usize {
        terminate!();
    }
    if i == 0 {
        out[i] = 0u32;
    } else {
        out[i] = input[i - 1];
    }
}

/// One Hillis–Steele step over `len` values: `out[i] = input[i] + input[i − offset]` where `i ≥ offset`.
#[cube(launch_unchecked)]
fn scan_step(input: &Tensor<u32>, out: &mut Tensor<u32>, len: u32, offset: u32) {
    let i = ABSOLUTE_POS;
    if i >= len as usize {
        terminate!();
    }
    let mut v = input[i];
    if i >= offset as usize {
        v += input[i - offset as usize];
    }
    out[i] = v;
}

/// `[n + 1]`: the exclusive prefix sums of `values` (`[n]`), then their total. Sums wrap at 2³²; the
/// callers keep them below.
pub(crate) fn exclusive_scan(values: &CubeTensor) -> CubeTensor {
    let n = values.meta.shape().dims::<1>()[0];
    let len = n + 1;
    let mut a = empty_u32(values, len);
    let units = Units::on(values, len).expect("a scan has at least its total");
    // SAFETY: every unit < n + 1 writes its own slot of `a` ([n + 1]) and reads `values[i − 1]`, i − 1 < n.
    unsafe {
        shift_in::launch_unchecked(
            &units.client,
            units.count.clone(),
            units.dim,
            values.clone().into_tensor_arg(),
            a.clone().into_tensor_arg(),
            n as u32,
        )
    }
    let mut b = empty_u32(values, len);
    let mut offset = 1;
    while offset < len {
        // SAFETY: units < len read `a[i]` and `a[i − offset]` and write `b[i]`, all of length `len`.
        unsafe {
            scan_step::launch_unchecked(
                &units.client,
                units.count.clone(),
                units.dim,
                a.clone().into_tensor_arg(),
                b.clone().into_tensor_arg(),
                len as u32,
                offset as u32,
            )
        }
        std::mem::swap(&mut a, &mut b);
        offset *= 2;
    }
    a
}

/// The entries `begin..end` of chunk `c` of `n`.
#[derive(CubeType)]
struct Chunk {
    begin: usize,
    end: usize,
}

#[cube]
fn chunk(c: usize, n: u32) -> Chunk {
    let begin = c * CHUNK;
    Chunk {
        begin,
        end: min(begin + CHUNK, n as usize),
    }
}

/// A key's digit in the pass at `shift`.
#[cube]
fn digit(key: u32, shift: u32, mask: u32) -> usize {
    ((key >> shift) & mask) as usize
}

/// Each chunk's count of each digit (`digit`): `counts[d · chunks + c]`.
#[cube(launch_unchecked)]
fn digit_counts(
    keys: &Tensor<u32>,
    counts: &mut Tensor<u32>,
    n: u32,
    chunks: u32,
    shift: u32,
    mask: u32,
) {
    let c = ABSOLUTE_POS;
    if c >= chunks as usize {
        terminate!();
    }
    let mut hist = Array::<u32>::new(BINS);
    for d in 0..BINS {
        hist[d] = 0u32;
    }
    let entries = chunk(c, n);
    for i in entries.begin..entries.end {
        hist[digit(keys[i], shift, mask)] += 1u32;
    }
    for d in 0..BINS {
        counts[d * chunks as usize + c] = hist[d];
    }
}

/// Writes each chunk's entries, in their order, to the slots the scanned counts give their digits.
#[cube(launch_unchecked)]
fn scatter(
    keys: &Tensor<u32>,
    values: &Tensor<u32>,
    offsets: &Tensor<u32>,
    keys_out: &mut Tensor<u32>,
    values_out: &mut Tensor<u32>,
    n: u32,
    chunks: u32,
    shift: u32,
    mask: u32,
) {
    let c = ABSOLUTE_POS;
    if c >= chunks as usize {
        terminate!();
    }
    let mut next = Array::<u32>::new(BINS);
    for d in 0..BINS {
        next[d] = offsets[d * chunks as usize + c];
    }
    let entries = chunk(c, n);
    for i in entries.begin..entries.end {
        let key = keys[i];
        let d = digit(key, shift, mask);
        let at = next[d] as usize;
        keys_out[at] = key;
        values_out[at] = values[i];
        next[d] += 1u32;
    }
}

/// `keys` and `values` (`[n]` each) reordered so that the keys' low `bits` bits ascend, equal ones keeping
/// their input order (higher bits are ignored: pass 32 for whole keys). The inputs are left as they were.
pub(crate) fn sort_pairs(
    keys: &CubeTensor,
    values: &CubeTensor,
    bits: u32,
) -> (CubeTensor, CubeTensor) {
    let n = keys.meta.shape().dims::<1>()[0];
    assert_eq!(values.meta.shape().dims::<1>()[0], n, "one value per key");
    assert!(
        n < u32::MAX as usize,
        "sort_pairs sorts fewer than 2³² entries"
    );
    let (mut keys, mut values) = (keys.clone(), values.clone());
    let chunks = n.div_ceil(CHUNK);
    let Some(units) = Units::on(&keys, chunks) else {
        return (keys, values);
    };
    let bits = bits.min(32);
    let mut shift = 0;
    while shift < bits {
        // This pass's digit, cut at the last bit sorted by.
        let mask = DIGIT_MASK & (u32::MAX >> (32 - bits) >> shift);
        let counts = empty_u32(&keys, BINS * chunks);
        // SAFETY: units < chunks read keys of their chunk (< n) and write `counts[d · chunks + c]`.
        unsafe {
            digit_counts::launch_unchecked(
                &units.client,
                units.count.clone(),
                units.dim,
                keys.clone().into_tensor_arg(),
                counts.clone().into_tensor_arg(),
                n as u32,
                chunks as u32,
                shift,
                mask,
            )
        }
        let offsets = exclusive_scan(&counts);
        let (keys_out, values_out) = (empty_u32(&keys, n), empty_u32(&keys, n));
        // SAFETY: the scanned counts give each entry a distinct slot < n; reads stay in the unit's chunk.
        unsafe {
            scatter::launch_unchecked(
                &units.client,
                units.count.clone(),
                units.dim,
                keys.into_tensor_arg(),
                values.into_tensor_arg(),
                offsets.into_tensor_arg(),
                keys_out.clone().into_tensor_arg(),
                values_out.clone().into_tensor_arg(),
                n as u32,
                chunks as u32,
                shift,
                mask,
            )
        }
        (keys, values) = (keys_out, values_out);
        shift += RADIX_BITS;
    }
    (keys, values)
}

/// `values[index]` (`[n]`) read back: one value, without reading the array.
pub(crate) fn read_one(values: &CubeTensor, index: usize) -> u32 {
    let out = empty_u32(values, 1);
    let units = Units::on(values, 1).expect("one unit");
    assert!(
        index < values.meta.shape().dims::<1>()[0],
        "read_one in range"
    );
    // SAFETY: one unit reads `values[index]` (in range, asserted) and writes `out[0]`.
    unsafe {
        copy_one::launch_unchecked(
            &units.client,
            units.count,
            units.dim,
            values.clone().into_tensor_arg(),
            out.clone().into_tensor_arg(),
            index as u32,
        )
    }
    download_u32(out)[0]
}

#[cube(launch_unchecked)]
fn copy_one(values: &Tensor<u32>, out: &mut Tensor<u32>, index: u32) {
    if ABSOLUTE_POS == 0 {
        out[0] = values[index as usize];
    }
}

/// A new contiguous `u32` array of `len` (at least one, so that an empty list still binds a buffer) on the
/// device of `like`.
pub(crate) fn empty_u32(like: &CubeTensor, len: usize) -> CubeTensor {
    empty_device_contiguous_dtype(
        like.client.clone(),
        like.device.clone(),
        Shape::new([len.max(1)]),
        DType::U32,
    )
}

/// `values` as a `u32` array on the device of `like` (an empty one still holds a slot to bind).
pub(crate) fn upload_u32(like: &CubeTensor, values: &[u32]) -> CubeTensor {
    let bytes: Vec<u8> = values
        .iter()
        .chain(values.is_empty().then_some(&0))
        .flat_map(|v| v.to_ne_bytes())
        .collect();
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        Shape::new([values.len()]),
        like.client.create_from_slice(&bytes),
        DType::U32,
    )
}

/// A `u32` array read back to the host.
pub(crate) fn download_u32(t: CubeTensor) -> Vec<u32> {
    into_data_sync(t).try_into_vec::<u32>().expect("u32 values")
}

#[cfg(test)]
pub(crate) mod tests {
    use burn::prelude::Tensor as BurnTensor;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::kernels::cube::testing::cube_tensor;
    use anerf_device::testing::gpu_devices_for_test;

    /// A CubeCL tensor on each GPU that passes the probe for `test`, to place arrays beside.
    fn devices(test: &str) -> Vec<CubeTensor> {
        gpu_devices_for_test(&format!("kernels::cube_sort::tests::{test}"))
            .into_iter()
            .map(|(choice, gpu)| {
                eprintln!("on {choice}");
                cube_tensor(BurnTensor::zeros([1, 1], &gpu))
            })
            .collect()
    }

    #[test]
    fn the_scan_matches_running_sums() {
        for like in devices("the_scan_matches_running_sums") {
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            for n in [0, 1, 2, 3, 255, 256, 1000, 4097] {
                let values: Vec<u32> = (0..n).map(|_| rng.random_range(0..1000)).collect();
                let mut expected = vec![0u32];
                for v in &values {
                    expected.push(expected.last().unwrap() + v);
                }
                let input = upload_u32(&like, &values);
                let got = download_u32(exclusive_scan(&input));
                assert_eq!(got, expected, "n = {n}");
            }
        }
    }

    /// Against the standard library's stable sort by the low `bits` bits: keys drawn from a few values so
    /// that ties are common (their values must keep the input order), sizes around the chunk size.
    #[test]
    fn the_radix_sort_is_a_stable_sort_of_the_low_bits() {
        for like in devices("the_radix_sort_is_a_stable_sort_of_the_low_bits") {
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            for (n, bits, distinct) in [
                (1, 32, 1u32),
                (255, 32, 7),
                (256, 10, 1024),
                (257, 8, 40),
                (3000, 32, u32::MAX),
                (5000, 12, 300),
            ] {
                let keys: Vec<u32> = (0..n)
                    .map(|_| {
                        // Higher bits set at random: the sort must ignore them.
                        let low = rng.random_range(0..distinct.min(1 << bits.min(31)).max(1));
                        let high = if bits < 32 {
                            rng.random::<u32>() << bits
                        } else {
                            0
                        };
                        if distinct == u32::MAX {
                            rng.random()
                        } else {
                            low | high
                        }
                    })
                    .collect();
                let values: Vec<u32> = (0..n as u32).collect();
                let mask = if bits >= 32 {
                    u32::MAX
                } else {
                    (1 << bits) - 1
                };
                let mut expected: Vec<(u32, u32)> =
                    keys.iter().copied().zip(values.iter().copied()).collect();
                expected.sort_by_key(|&(k, _)| k & mask);
                let (k, v) =
                    sort_pairs(&upload_u32(&like, &keys), &upload_u32(&like, &values), bits);
                let got: Vec<(u32, u32)> =
                    download_u32(k).into_iter().zip(download_u32(v)).collect();
                assert_eq!(got, expected, "n = {n}, {bits} bits");
            }
        }
    }
}
