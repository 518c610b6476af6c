//! Large freed blocks kept for the next allocation of the same size.
//!
//! A 4096² image passes through several 64 MiB buffers (read, scaled,
//! background-subtracted, smoothed in `measure`; canvas, model, FITS bytes
//! in `generate`). glibc serves every block above 32 MiB with a fresh
//! `mmap` and returns it with `munmap` when freed, so each buffer of each
//! image is faulted in and zeroed by the kernel again: in a `measure` of 8
//! preset images, 30 % of the CPU time was the kernel clearing pages
//! (`perf`, BENCHMARKS.md "measure's page faults"). [`BlockCache`] keeps up
//! to [`SLOTS`] freed blocks of [`MIN_CACHED_BYTES`] to
//! [`MAX_CACHED_BYTES`], at most [`BUDGET_BYTES`] in all, and hands one back
//! to the next request of exactly its size and alignment (zeroed first when
//! asked for zeroed memory). Blocks of other sizes, and the oldest when the
//! budget is full, go back to the system. The bytes a program computes are
//! the same with or without it: `STEPSIM_BLOCK_CACHE=0` turns it off (the
//! plain allocator, its slow twin). Only `measure` turns it on
//! ([`crate::huge_pages::keep_large_blocks`]).

use std::sync::Mutex;

/// Blocks smaller than this are left to the system allocator (its own
/// free lists serve them without page faults).
pub const MIN_CACHED_BYTES: usize = 16 << 20;

/// Blocks larger than this are never kept: holding one would cost more
/// memory than its page faults cost time.
pub const MAX_CACHED_BYTES: usize = 256 << 20;

/// Bytes kept at most, in all.
pub const BUDGET_BYTES: usize = 512 << 20;

/// Blocks kept at most.
pub const SLOTS: usize = 16;

/// One kept block.
#[derive(Debug, Clone, Copy)]
struct Kept {
    addr: usize,
    size: usize,
    align: usize,
    /// When it was kept (a counter): the oldest goes first.
    at: u64,
}

#[derive(Debug)]
struct Shelf {
    slots: [Option<Kept>; SLOTS],
    clock: u64,
    bytes: usize,
}

/// The cache (one per process, inside the global allocator).
#[derive(Debug)]
pub struct BlockCache {
    shelf: Mutex<Shelf>,
}

impl Default for BlockCache {
    fn default() -> Self {
        Self::new()
    }
}

impl BlockCache {
    /// An empty cache.
    pub const fn new() -> Self {
        Self {
            shelf: Mutex::new(Shelf {
                slots: [None; SLOTS],
                clock: 0,
                bytes: 0,
            }),
        }
    }

    fn shelf(&self) -> std::sync::MutexGuard<'_, Shelf> {
        // Nothing panics while the lock is held; a poisoned lock still
        // holds a consistent shelf.
        self.shelf.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// True when blocks of `size` bytes are kept.
    pub fn keeps(size: usize) -> bool {
        (MIN_CACHED_BYTES..=MAX_CACHED_BYTES).contains(&size)
    }

    /// The most recently kept block of exactly `size` and `align`, taken
    /// off the shelf.
    pub fn take(&self, size: usize, align: usize) -> Option<*mut u8> {
        if !Self::keeps(size) {
            return None;
        }
        let mut s = self.shelf();
        let i = (0..SLOTS)
            .filter(|&i| s.slots[i].is_some_and(|k| k.size == size && k.align == align))
            .max_by_key(|&i| s.slots[i].map_or(0, |k| k.at))?;
        let k = s.slots[i].take()?;
        s.bytes -= k.size;
        Some(k.addr as *mut u8)
    }

    /// Keeps the block `ptr` of `size` and `align` for reuse, if it is of
    /// a kept size; true when kept. Blocks pushed out to stay within
    /// [`SLOTS`] and [`BUDGET_BYTES`] (the oldest first) are given to
    /// `release` (called after the lock is dropped).
    pub fn put(
        &self,
        ptr: *mut u8,
        size: usize,
        align: usize,
        mut release: impl FnMut(*mut u8, usize, usize),
    ) -> bool {
        if !Self::keeps(size) || ptr.is_null() {
            return false;
        }
        let mut out: [Option<Kept>; SLOTS] = [None; SLOTS];
        {
            let mut s = self.shelf();
            let mut n_out = 0;
            loop {
                let used = s.slots.iter().filter(|k| k.is_some()).count();
                if used < SLOTS && s.bytes + size <= BUDGET_BYTES {
                    break;
                }
                let Some(oldest) = (0..SLOTS)
                    .filter(|&i| s.slots[i].is_some())
                    .min_by_key(|&i| s.slots[i].map_or(0, |k| k.at))
                else {
                    break;
                };
                let k = s.slots[oldest].take().expect("a kept block");
                s.bytes -= k.size;
                out[n_out] = Some(k);
                n_out += 1;
            }
            s.clock += 1;
            let at = s.clock;
            let free = (0..SLOTS).find(|&i| s.slots[i].is_none());
            if let Some(i) = free {
                s.slots[i] = Some(Kept {
                    addr: ptr as usize,
                    size,
                    align,
                    at,
                });
                s.bytes += size;
            }
            if free.is_none() {
                // Unreachable (the loop above empties a slot), but never
                // lose a block: hand it back.
                drop(s);
                release(ptr, size, align);
                return false;
            }
        }
        for k in out.iter().flatten() {
            release(k.addr as *mut u8, k.size, k.align);
        }
        true
    }

    /// Bytes on the shelf now.
    #[cfg(test)]
    pub fn bytes(&self) -> usize {
        self.shelf().bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: usize = 1 << 20;

    #[test]
    fn a_freed_block_is_handed_to_the_next_request_of_its_size_only() {
        let c = BlockCache::new();
        let mut released = Vec::new();
        let a = 0x1000_0000usize as *mut u8;
        assert!(c.put(a, 64 * M, 16, |p, s, _| released.push((p as usize, s))));
        assert_eq!(c.bytes(), 64 * M);
        assert_eq!(c.take(64 * M + 1, 16), None);
        assert_eq!(c.take(64 * M, 32), None);
        assert_eq!(c.take(64 * M, 16), Some(a));
        assert_eq!(c.take(64 * M, 16), None);
        assert_eq!(c.bytes(), 0);
        // Too small or too large: not kept.
        assert!(!c.put(a, MIN_CACHED_BYTES - 1, 16, |_, _, _| {}));
        assert!(!c.put(a, MAX_CACHED_BYTES + 1, 16, |_, _, _| {}));
        assert!(released.is_empty());
    }

    #[test]
    fn the_oldest_blocks_go_back_to_stay_within_the_budget_and_the_slots() {
        let c = BlockCache::new();
        let mut released = Vec::new();
        // Eight blocks of 64 MiB fill the 512 MiB budget; a ninth pushes
        // out the first.
        for k in 1..=9usize {
            assert!(c.put((k << 28) as *mut u8, 64 * M, 16, |p, s, _| {
                released.push((p as usize >> 28, s))
            }));
        }
        assert_eq!(released, vec![(1, 64 * M)]);
        assert_eq!(c.bytes(), BUDGET_BYTES);
        // The newest of a size comes first.
        assert_eq!(c.take(64 * M, 16), Some((9usize << 28) as *mut u8));
        // Sixteen small ones: the slots, not the budget, bound them.
        let c = BlockCache::new();
        let mut n_released = 0;
        for k in 1..=(SLOTS + 3) {
            c.put((k << 28) as *mut u8, 16 * M, 16, |_, _, _| n_released += 1);
        }
        assert_eq!(n_released, 3);
        assert_eq!(c.bytes(), SLOTS * 16 * M);
        // The three oldest went back; the rest come newest first.
        let kept: Vec<usize> = std::iter::from_fn(|| c.take(16 * M, 16))
            .map(|p| p as usize >> 28)
            .collect();
        assert_eq!(kept, (4..=SLOTS + 3).rev().collect::<Vec<_>>());
    }
}
