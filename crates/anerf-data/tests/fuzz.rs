//! Property tests over mutated real files: the `.npy` reader, the unpickler and the image and mask reader
//! return errors on any input, never panic, and never request an allocation out of proportion to the input
//! (checked by a counting global allocator); plus the hostile inputs of issue 18 as regressions (the cut
//! images are in `images.rs`). Seeded and bounded (a second or two in the test profile), so CI runs them
//! with `cargo test`, and a failure reproduces with the failing input printed.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use anerf_data::formats::{image_structure, images, npy, pickle};
use rand::{Rng, SeedableRng};

/// Counts this thread's allocations (tests run on threads of their own): the largest single request and
/// the peak of live bytes since [`Counting::reset`].
struct Counting;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    static LIVE: Cell<usize> = const { Cell::new(0) };
    static PEAK: Cell<usize> = const { Cell::new(0) };
}

impl Counting {
    fn reset() {
        LARGEST.set(0);
        LIVE.set(0);
        PEAK.set(0);
    }

    fn grew(request: usize, added: usize) {
        LARGEST.set(LARGEST.get().max(request));
        LIVE.set(LIVE.get() + added);
        PEAK.set(PEAK.get().max(LIVE.get()));
    }

    /// Memory freed here may have been allocated before the reset.
    fn shrank(freed: usize) {
        LIVE.set(LIVE.get().saturating_sub(freed));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        Counting::grew(layout.size(), layout.size());
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        Counting::shrank(layout.size());
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // While the block moves, old and new coexist.
        Counting::grew(new_size, new_size);
        Counting::shrank(layout.size());
        // SAFETY: as in `alloc`/`dealloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Every file of the fixture folders `dirs` that `keep` selects, sorted by path.
fn corpus(dirs: &[&str], keep: impl Fn(&Path) -> bool) -> Vec<(String, Vec<u8>)> {
    let mut files = Vec::new();
    for dir in dirs {
        for entry in std::fs::read_dir(anerf_testing::fixture(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.is_file() && keep(&path) {
                files.push((path.display().to_string(), std::fs::read(&path).unwrap()));
            }
        }
    }
    files.sort();
    files
}

fn extension(path: &Path) -> &str {
    path.extension().and_then(|e| e.to_str()).unwrap_or("")
}

fn mutate(rng: &mut impl Rng, src: &[u8]) -> Vec<u8> {
    let mut b = src.to_vec();
    for _ in 0..rng.random_range(1..4) {
        if b.is_empty() {
            b.push(rng.random());
            continue;
        }
        let at = rng.random_range(0..b.len());
        match rng.random_range(0..6) {
            0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b[at] = [0u8, 0xff, 0x7f, 0x80, b'(', b'.', 0x94, b'h'][rng.random_range(0..8)],
            2 => b.truncate(at),
            3 => {
                let n = rng.random_range(1..16);
                let junk: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                b.splice(at..at, junk);
            }
            4 => {
                // A huge length field: what a hostile file would use to force a giant allocation.
                let big = [0xffu8, 0xff, 0xff, 0x7f, 0xff, 0xff, 0xff, 0x0f];
                for (i, v) in big.iter().enumerate() {
                    if at + i < b.len() {
                        b[at + i] = *v;
                    }
                }
            }
            _ => {
                let end = (at + rng.random_range(1..64)).min(b.len());
                let chunk = b[at..end].to_vec();
                let to = rng.random_range(0..b.len());
                b.splice(to..to, chunk);
            }
        }
    }
    b
}

/// Feeds `rounds` mutations of every corpus file to `read` (true when it accepts the input), failing on a
/// panic or on an allocation larger than `allowed(input)`; returns how many were accepted and rejected.
fn fuzz(
    files: &[(String, Vec<u8>)],
    rounds: usize,
    seed: u64,
    read: impl Fn(&[u8]) -> bool + std::panic::RefUnwindSafe,
    allowed: impl Fn(&[u8]) -> usize,
) -> (usize, usize) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let (mut ok, mut err) = (0usize, 0usize);
    for round in 0..rounds {
        for (name, src) in files {
            let input = mutate(&mut rng, src);
            Counting::reset();
            let result = std::panic::catch_unwind(|| read(&input));
            let largest = LARGEST.get();
            match result {
                Ok(true) => ok += 1,
                Ok(false) => err += 1,
                Err(_) => panic!("round {round}, {name}: reader panicked on {input:?}"),
            }
            let cap = allowed(&input);
            assert!(
                largest <= cap,
                "round {round}, {name}: allocation of {largest} bytes for {} input bytes: {input:?}",
                input.len()
            );
        }
    }
    println!("fuzz: {} inputs, {ok} accepted, {err} rejected", ok + err);
    assert!(
        err > ok / 10,
        "mutations should mostly break files: {ok} ok, {err} rejected"
    );
    (ok, err)
}

#[test]
fn mutated_npy_and_pickle_files_give_errors_not_panics_or_huge_allocations() {
    let files = corpus(
        &[
            "formats",
            "zju_mocap/CoreView_377",
            "zju_mocap/CoreView_377/params",
            "body_model",
        ],
        |p| {
            let name = p.file_name().unwrap().to_str().unwrap();
            extension(p) == "pkl" || (extension(p) == "npy" && name.contains(['_', 'a', '0']))
        },
    );
    assert!(files.len() > 20, "{} corpus files", files.len());
    fuzz(
        &files,
        1000,
        0x5eed_a11e,
        |input| {
            let a = npy::parse(input).is_ok();
            let b = pickle::parse(input).is_ok();
            // Also feed the pickle part of object files directly to the unpickler.
            let body = input
                .iter()
                .position(|&c| c == b'\n')
                .map_or(&input[..0], |i| &input[i + 1..]);
            let c = pickle::parse(body).is_ok();
            a || b || c
        },
        |input| 64 * input.len() + (1 << 20),
    );
}

/// Images and masks: the structure check never refuses what decodes, and a decode allocates no more than
/// the input and the pixels its (possibly damaged) header declares, within the decoder's 512 MiB limit.
#[test]
fn mutated_images_and_masks_give_errors_not_panics_or_huge_allocations() {
    let files = corpus(
        &[
            "zju_mocap/CoreView_377/Camera_B1",
            "zju_mocap/CoreView_377/mask_cihp/Camera_B1",
            "h36m/S9/Posing/images/cam0",
            "metrics/png",
        ],
        |p| matches!(extension(p), "jpg" | "png"),
    );
    assert!(files.len() >= 12, "{} corpus files", files.len());
    let declared_pixels = |input: &[u8]| {
        image::ImageReader::new(std::io::Cursor::new(input))
            .with_guessed_format()
            .ok()
            .and_then(|r| r.into_dimensions().ok())
            .map_or(0, |(w, h)| w as usize * h as usize)
    };
    let (ok, _) = fuzz(
        &files,
        300,
        0x1a6e_5eed,
        |input| {
            let whole = image_structure::check(input).is_ok();
            let decoded = images::decode_bytes(input).is_ok();
            assert!(
                whole || !decoded,
                "the structure check refused a decodable file"
            );
            decoded
        },
        |input| 64 * input.len() + (1 << 20) + (16 * declared_pixels(input)).min(512 << 20),
    );
    assert!(ok > 0, "some mutations (in pixel data) still decode");
    // Every cut of a whole file is refused: the decoders alone accept many.
    let mut rng = rand::rngs::StdRng::seed_from_u64(0xc0_7ed);
    for (name, src) in &files {
        for _ in 0..50 {
            let cut = rng.random_range(0..src.len());
            assert!(
                images::decode_bytes(&src[..cut]).is_err(),
                "{name} cut to {cut} of {} bytes decodes",
                src.len()
            );
        }
    }
}

/// The hostile pickle, scaled down: one-byte EMPTY_LIST opcodes (and MEMOIZE after each), every list
/// left on the stack. Without the cap, 2 MB of them held about 170× their size.
#[test]
fn a_pickle_of_one_byte_list_opcodes_stops_at_the_memory_cap() {
    let dir = tempfile::tempdir().unwrap();
    for (name, unit) in [("lists.pkl", &b"]"[..]), ("memoised.pkl", b"]\x94")] {
        let bytes = [&b"\x80\x02"[..], &unit.repeat(2_000_000 / unit.len()), b"."].concat();
        let cap = pickle::memory_cap(bytes.len());
        Counting::reset();
        let result = pickle::parse(&bytes);
        let peak = PEAK.get();
        assert_eq!(
            result,
            Err(pickle::PickleError::MemoryCap {
                cap,
                input: bytes.len()
            }),
            "{name}"
        );
        assert!(peak <= cap, "{name}: peak {peak} bytes, cap {cap}");
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        let msg = anerf_data::formats::read_pickle(&path)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains(name) && msg.contains(&format!("memory cap of {cap} bytes")),
            "{msg}"
        );
    }
}

/// OpenCV YAML (calibration files), `.npz` archives (zip structure and members) and EasyMocap fit JSON, read
/// as motions: mutated real files give errors, never panics, and allocate in proportion to the input (an
/// `.npz` member may inflate to at most 1024× the archive: its budget).
#[test]
fn mutated_yaml_npz_and_fit_files_give_errors_not_panics_or_huge_allocations() {
    use anerf_data::formats::opencv_yaml::FileStorage;
    use anerf_data::motion::Motion;

    let yaml = corpus(&["easymocap/capture", "easymocap/yaml"], |p| {
        extension(p) == "yml"
    });
    assert!(yaml.len() >= 2, "{} YAML corpus files", yaml.len());
    fuzz(
        &yaml,
        400,
        0x0ca1_1b,
        |input| FileStorage::parse(&String::from_utf8_lossy(input), Path::new("x.yml")).is_ok(),
        |input| 64 * input.len() + (1 << 20),
    );

    let dir = tempfile::tempdir().unwrap();
    let motions = corpus(&["motion", "easymocap/capture/output-smpl-3d/smpl"], |p| {
        matches!(extension(p), "npz" | "json") && !p.to_string_lossy().contains("expected")
    });
    assert!(motions.len() >= 4, "{} motion corpus files", motions.len());
    let as_file = |input: &[u8], ext: &str| {
        let path = dir.path().join(format!("m.{ext}"));
        std::fs::write(&path, input).unwrap();
        path
    };
    let npz: Vec<_> = motions
        .iter()
        .filter(|(n, _)| n.ends_with(".npz"))
        .cloned()
        .collect();
    let json: Vec<_> = motions
        .iter()
        .filter(|(n, _)| n.ends_with(".json"))
        .cloned()
        .collect();
    fuzz(
        &npz,
        60,
        0x00a2_c0de,
        |input| Motion::read(&as_file(input, "npz"), None).is_ok(),
        |input| 1100 * input.len() + (4 << 20),
    );
    fuzz(
        &json,
        60,
        0x00f1_7501,
        |input| Motion::read(&as_file(input, "json"), None).is_ok(),
        |input| 64 * input.len() + (1 << 20),
    );
}
