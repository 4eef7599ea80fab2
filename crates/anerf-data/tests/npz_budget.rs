//! `.npz` archives cost memory for what is read, never for what a hostile archive claims or holds besides:
//! a member whose header or zip directory asks for more than the budget is refused before it is inflated,
//! members a reader does not use are never inflated, and a cut of a long motion inflates only the frames
//! it keeps. Memory is measured by this test binary's own allocator (one test in the binary, so nothing
//! else allocates meanwhile), not by timing.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use anerf_data::formats::npz::Npz;
use anerf_data::formats::{ArrayData, NdArray};
use anerf_data::motion::{Motion, Root, Timing};
use anerf_testing::npy_f64_header;

/// The system allocator, counting the bytes live now and the most live since [`reset_peak`].
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Forgets the peak: the next [`peak_above_start`] counts from now.
fn reset_peak() -> usize {
    let live = LIVE.load(Ordering::Relaxed);
    PEAK.store(live, Ordering::Relaxed);
    live
}

fn peak_above(start: usize) -> usize {
    PEAK.load(Ordering::Relaxed).saturating_sub(start)
}

const MIB: usize = 1 << 20;

/// What follows a member's header: `n` zero bytes (streamed, so writing allocates little), or values.
enum Payload {
    Zeros(usize),
    Values(Vec<f64>),
}

/// A deflated `.npz` at `path` of members `(name, header shape, payload)`.
fn write_archive(path: &Path, members: &[(&str, Vec<usize>, Payload)]) {
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    let options = zip::write::FileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(true);
    let zeros = vec![0u8; MIB];
    for (name, shape, data) in members {
        zip.start_file(format!("{name}.npy"), options).unwrap();
        zip.write_all(&npy_f64_header(shape, false)).unwrap();
        match data {
            Payload::Zeros(n) => {
                let mut left = *n;
                while left > 0 {
                    let k = left.min(MIB);
                    zip.write_all(&zeros[..k]).unwrap();
                    left -= k;
                }
            }
            Payload::Values(v) => {
                for x in v {
                    zip.write_all(&x.to_le_bytes()).unwrap();
                }
            }
        }
    }
    zip.finish().unwrap();
}

/// A four-frame SMPL+H motion at 120 frames per second, every rotation zero, the root at (0, 0, f).
fn motion_members() -> Vec<(&'static str, Vec<usize>, Payload)> {
    let trans = (0..4).flat_map(|f| [0.0, 0.0, f as f64]).collect();
    vec![
        ("poses", vec![4, 156], Payload::Zeros(4 * 156 * 8)),
        ("trans", vec![4, 3], Payload::Values(trans)),
        ("mocap_framerate", vec![], Payload::Values(vec![120.0])),
    ]
}

#[test]
fn npz_members_cost_memory_only_when_read_and_never_past_the_budget() {
    let dir = tempfile::tempdir().unwrap();

    // 1. A header that claims 4.6 GB (8,000,000 frames × 72): refused from the header alone.
    let claims = dir.path().join("claims.npz");
    write_archive(
        &claims,
        &[("poses", vec![8_000_000, 72], Payload::Zeros(64))],
    );
    let start = reset_peak();
    let mut npz = Npz::open(&claims).unwrap();
    let err = npz.array("poses").unwrap_err().to_string();
    assert!(
        err.contains("claims.npz") && err.contains("4608000000 bytes") && err.contains("at most"),
        "{err}"
    );
    drop(npz);
    assert!(
        peak_above(start) < 2 * MIB,
        "peak {} bytes",
        peak_above(start)
    );

    // 2. A member that truly inflates to 96 MiB, against a 16 MiB budget: refused before inflating.
    let bomb = dir.path().join("bomb.npz");
    let values = 96 * MIB / 8;
    write_archive(
        &bomb,
        &[("poses", vec![values], Payload::Zeros(values * 8))],
    );
    assert!(
        std::fs::metadata(&bomb).unwrap().len() < (MIB as u64),
        "a small archive"
    );
    let start = reset_peak();
    let mut npz = Npz::open_with_budget(&bomb, 16 * MIB as u64).unwrap();
    let err = npz.array("poses").unwrap_err().to_string();
    assert!(err.contains("at most 16777216"), "{err}");
    drop(npz);
    assert!(
        peak_above(start) < 2 * MIB,
        "peak {} bytes",
        peak_above(start)
    );

    // 3. A valid motion beside eight unused 64 MiB members: read, and none of them inflated.
    let padded = dir.path().join("padded.npz");
    let mut members = motion_members();
    let extra: Vec<String> = (0..8).map(|i| format!("extra{i}")).collect();
    for name in &extra {
        members.push((name.as_str(), vec![8 * MIB], Payload::Zeros(64 * MIB)));
    }
    write_archive(&padded, &members);
    let start = reset_peak();
    let motion = Motion::read(&padded, None).unwrap();
    assert_eq!(motion.frames.len(), 4);
    drop(motion);
    assert!(
        peak_above(start) < 4 * MIB,
        "peak {} bytes",
        peak_above(start)
    );

    // The same arrays without the padding read back equal (the members themselves are intact).
    let plain = dir.path().join("plain.npz");
    write_archive(&plain, &motion_members());
    let mut npz = Npz::open(&plain).unwrap();
    let trans = (0..4).flat_map(|f| [0.0, 0.0, f as f64]).collect();
    assert_eq!(
        npz.array("trans").unwrap(),
        NdArray::new(vec![4, 3], ArrayData::F64(trans)).unwrap()
    );
    drop(npz);

    // 4. A long motion (100,000 frames: 125 MB of poses) cut to four frames near its end costs the
    // memory of those frames, not of the motion; the frames are the ones asked for.
    let long = dir.path().join("long.npz");
    let frames = 100_000;
    let trans = (0..frames).flat_map(|f| [0.0, 0.0, f as f64]).collect();
    write_archive(
        &long,
        &[
            ("poses", vec![frames, 156], Payload::Zeros(frames * 156 * 8)),
            ("trans", vec![frames, 3], Payload::Values(trans)),
            ("mocap_framerate", vec![], Payload::Values(vec![120.0])),
        ],
    );
    let timing = Timing {
        declared_fps: None,
        fps: None,
        frames: "99990:99994".parse().unwrap(),
    };
    let start = reset_peak();
    let cut = Motion::read_timed(&long, None, &timing).unwrap();
    let heights: Vec<f64> = cut
        .frames
        .iter()
        .map(|f| match f.root {
            Root::Standard { trans } => trans.z,
            Root::Placed { .. } => unreachable!("AMASS roots are standard"),
        })
        .collect();
    assert_eq!(heights, [99990.0, 99991.0, 99992.0, 99993.0]);
    drop(cut);
    assert!(
        peak_above(start) < 4 * MIB,
        "peak {} bytes",
        peak_above(start)
    );
}
