//! A global allocator that keeps freed large blocks for reuse.
//!
//! Burn allocates every intermediate tensor anew, and a training step frees and re-allocates the same sizes
//! over and over. The system allocator hands blocks above a threshold (glibc: at most 32 MiB; a
//! `[65536, 256]` activation is 64 MiB) to the kernel on free and gets fresh pages on the next allocation,
//! which the kernel zeroes on first touch: about a million page faults, 15–20 % of a training step of the
//! paper preset. [`BlockCache`] rounds large requests up to one of eight size classes per power of two
//! (at most 12.5 % slack), keeps freed blocks per class, and serves the next request of that class from
//! them. Small requests go straight to the system allocator.
//!
//! Install it in a binary:
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOCATOR: alloc::BlockCache = alloc::BlockCache::new();
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// Requests smaller than this go to the system allocator (which reuses them well).
const MIN_BLOCK: usize = 1 << 18;
/// Largest alignment the cache serves; every cached block has it.
const BLOCK_ALIGN: usize = 64;
/// log2 of the largest cached block (1 TiB); larger requests go to the system allocator.
const MAX_LOG2: u32 = 40;
const SUBCLASSES: usize = 8;
const CLASSES: usize = (MAX_LOG2 as usize - MIN_BLOCK.trailing_zeros() as usize + 1) * SUBCLASSES;
/// Freed blocks kept per class.
const PER_CLASS: usize = 64;
/// Most bytes the cache keeps; a freed block that would exceed it is returned to the system.
pub const DEFAULT_CAPACITY: usize = 8 << 30;

/// The size class of a large request: its index and the block size (the request rounded up).
fn class_of(size: usize) -> Option<(usize, usize)> {
    if !(MIN_BLOCK..=(1usize << MAX_LOG2)).contains(&size) {
        return None;
    }
    let step = 1usize << (size.ilog2() - 3);
    let rounded = size.div_ceil(step) * step;
    let octave = rounded.ilog2();
    if octave > MAX_LOG2 {
        return None;
    }
    let sub = (rounded >> (octave - 3)) - SUBCLASSES;
    let index = (octave - MIN_BLOCK.trailing_zeros()) as usize * SUBCLASSES + sub;
    Some((index, rounded))
}

struct Classes {
    /// Addresses of free blocks, `PER_CLASS` slots per class.
    free: [[usize; PER_CLASS]; CLASSES],
    len: [u8; CLASSES],
    bytes: usize,
}

/// The caching allocator (see the module documentation). `capacity` bounds the bytes it keeps.
pub struct BlockCache {
    classes: Mutex<Classes>,
    capacity: usize,
    /// When false, new requests go straight to the system allocator (blocks already handed out are still
    /// recognised by their layout and returned to the cache or the system correctly).
    enabled: AtomicBool,
}

impl BlockCache {
    /// A cache keeping at most [`DEFAULT_CAPACITY`] bytes.
    pub const fn new() -> Self {
        Self::with_capacity(DEFAULT_CAPACITY)
    }

    /// A cache keeping at most `capacity` bytes of freed blocks.
    pub const fn with_capacity(capacity: usize) -> Self {
        Self {
            classes: Mutex::new(Classes {
                free: [[0; PER_CLASS]; CLASSES],
                len: [0; CLASSES],
                bytes: 0,
            }),
            capacity,
            enabled: AtomicBool::new(true),
        }
    }

    /// Stops keeping freed blocks (to measure what the cache buys); kept blocks stay in use.
    pub fn disable(&self) {
        self.enabled.store(false, Ordering::Relaxed);
    }

    /// Bytes currently kept for reuse.
    #[cfg(test)]
    pub fn cached_bytes(&self) -> usize {
        self.lock().bytes
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Classes> {
        // A panic while holding the lock cannot leave the free lists inconsistent (each update is a
        // single push or pop), so a poisoned lock is still usable.
        self.classes.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn cached(layout: Layout) -> Option<(usize, usize)> {
        if layout.align() > BLOCK_ALIGN {
            return None;
        }
        class_of(layout.size())
    }

    fn take(&self, class: usize, block: usize) -> Option<*mut u8> {
        if !self.enabled.load(Ordering::Relaxed) {
            return None;
        }
        let mut c = self.lock();
        let n = c.len[class] as usize;
        if n == 0 {
            return None;
        }
        c.len[class] -= 1;
        c.bytes -= block;
        Some(c.free[class][n - 1] as *mut u8)
    }

    /// Keeps `ptr` for reuse, or returns false when the class or the cache is full.
    fn keep(&self, ptr: *mut u8, class: usize, block: usize) -> bool {
        if !self.enabled.load(Ordering::Relaxed) {
            return false;
        }
        let mut c = self.lock();
        let n = c.len[class] as usize;
        if n == PER_CLASS || c.bytes + block > self.capacity {
            return false;
        }
        c.free[class][n] = ptr as usize;
        c.len[class] += 1;
        c.bytes += block;
        true
    }

    fn block_layout(block: usize) -> Layout {
        Layout::from_size_align(block, BLOCK_ALIGN).expect("class sizes are valid layouts")
    }
}

impl Default for BlockCache {
    fn default() -> Self {
        Self::new()
    }
}

// SAFETY: every block handed out is either the system allocator's answer to the same layout, or a block
// of at least the requested size with `BLOCK_ALIGN ≥ align`, allocated from the system with the class
// layout and given back to the system with that same layout; a cached block is owned by the cache alone.
unsafe impl GlobalAlloc for BlockCache {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        match Self::cached(layout) {
            None => unsafe { System.alloc(layout) },
            Some((class, block)) => match self.take(class, block) {
                Some(ptr) => ptr,
                None => unsafe { System.alloc(Self::block_layout(block)) },
            },
        }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        match Self::cached(layout) {
            None => unsafe { System.alloc_zeroed(layout) },
            Some((class, block)) => match self.take(class, block) {
                Some(ptr) => {
                    unsafe { ptr.write_bytes(0, layout.size()) };
                    ptr
                }
                None => unsafe { System.alloc_zeroed(Self::block_layout(block)) },
            },
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        match Self::cached(layout) {
            None => unsafe { System.dealloc(ptr, layout) },
            Some((class, block)) => {
                if !self.keep(ptr, class, block) {
                    unsafe { System.dealloc(ptr, Self::block_layout(block)) }
                }
            }
        }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
        match (Self::cached(layout), Self::cached(new_layout)) {
            (None, None) => unsafe { System.realloc(ptr, layout, new_size) },
            (Some((a, _)), Some((b, _))) if a == b => ptr,
            _ => {
                let new = unsafe { self.alloc(new_layout) };
                if !new.is_null() {
                    unsafe {
                        std::ptr::copy_nonoverlapping(ptr, new, layout.size().min(new_size));
                        self.dealloc(ptr, layout);
                    }
                }
                new
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classes_round_up_by_at_most_an_eighth_and_are_distinct() {
        assert_eq!(class_of(MIN_BLOCK - 1), None);
        assert_eq!(class_of(MIN_BLOCK), Some((0, MIN_BLOCK)));
        let mut last = class_of(MIN_BLOCK).unwrap();
        for size in (MIN_BLOCK..64 * MIN_BLOCK).step_by(4099) {
            let (class, block) = class_of(size).unwrap();
            assert!(
                block >= size && block - size <= size / 8,
                "{size} → {block}"
            );
            // Classes grow with the size, and one class always means one block size.
            assert!(class >= last.0);
            if class == last.0 {
                assert_eq!(block, last.1);
            }
            last = (class, block);
        }
        // 64 MiB (a [65536, 256] f32 activation) is a class boundary: no slack.
        assert_eq!(class_of(64 << 20).unwrap().1, 64 << 20);
    }

    #[test]
    fn freed_blocks_are_reused_zeroed_on_request_and_bounded() {
        let cache = BlockCache::with_capacity(3 << 20);
        // 1 MiB + 1000 and 1 MiB + 2000 bytes share the 1.125 MiB class.
        let layout = Layout::from_size_align((1 << 20) + 1000, 8).unwrap();
        let block = (1 << 20) + (1 << 17);
        unsafe {
            let a = cache.alloc(layout);
            assert!(!a.is_null() && (a as usize).is_multiple_of(BLOCK_ALIGN));
            a.write_bytes(7, layout.size());
            cache.dealloc(a, layout);
            assert_eq!(cache.cached_bytes(), block);
            let bigger = Layout::from_size_align((1 << 20) + 2000, 8).unwrap();
            let b = cache.alloc_zeroed(bigger);
            assert_eq!(a, b);
            assert!(std::slice::from_raw_parts(b, bigger.size())
                .iter()
                .all(|&v| v == 0));
            assert_eq!(cache.cached_bytes(), 0);
            // Growing within the class keeps the block; growing past it moves the contents.
            let c = cache.realloc(b, bigger, (1 << 20) + 3000);
            assert_eq!(c, b);
            c.write_bytes(3, 16);
            let grown = Layout::from_size_align(4 << 20, 8).unwrap();
            let d = cache.realloc(c, layout, grown.size());
            assert_eq!(std::slice::from_raw_parts(d, 16), &[3u8; 16]);
            assert_eq!(cache.cached_bytes(), block);
            // Beyond the capacity, freed blocks go back to the system.
            cache.dealloc(d, grown);
            assert_eq!(cache.cached_bytes(), block);
            let e = cache.alloc(layout);
            assert_eq!(e, a);
            cache.dealloc(e, layout);
        }
    }
}
