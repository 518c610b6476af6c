//! Large allocations backed by transparent huge pages (Linux), when asked.
//!
//! A 4096² image passes through several 67 MB buffers (the canvas, the
//! convolved model, the FITS bytes), each fresh from the kernel and faulted
//! in 4 kB pages: about 16 000 page faults, each zeroing its page, per
//! buffer. [`HugePageAlloc`] is the system allocator plus one request: when
//! turned on, for every allocation of [`MIN_ADVISED_BYTES`] or more it asks
//! the kernel (`madvise`, `MADV_HUGEPAGE`) to back the 2 MB-aligned inside
//! of the block with 2 MB pages, which takes 512 times fewer faults. The
//! kernel honours it when its transparent-huge-page mode is `madvise`
//! (Debian's default) or `always`, and ignores it under `never`; nothing
//! else changes, so the bytes written are the same.
//!
//! It is **off by default** since 2026-12-05; `STEPSIM_HUGE_PAGES=1` turns
//! it on. With two images in flight and more buffers per image it once
//! saved ≈ 0.3 s of system time per image (BENCHMARKS.md, "Speed, fourth
//! pass"). Since then an image holds fewer such buffers, and on the
//! project's machines (virtual machines that hand free memory back to the
//! host in 8 MiB blocks, `page_reporting.page_reporting_order=11`) a huge
//! page comes from memory the host must map again, where 4 kB pages come
//! from memory it still maps: a user's first image took up to 1.25× the
//! CPU with the advice than without, `measure` 1.04× (BENCHMARKS.md,
//! "Huge pages off by default").
//!
//! glibc's tunable `GLIBC_TUNABLES=glibc.malloc.hugetlb=1` does the like for
//! every `malloc` of the process, C libraries included, but only if it is
//! set before the process starts; this allocator does it from inside, for
//! the Rust allocations (which hold the image buffers).
//!
//! In `measure` the allocator also keeps large freed blocks for the next
//! request of the same size ([`crate::block_cache`], [`keep_large_blocks`]),
//! so that an image's buffers are faulted in once per process rather than
//! once per image.

use crate::block_cache::BlockCache;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};

/// The huge page size the advice aligns to.
const HUGE_PAGE: usize = 2 << 20;

/// Allocations of at least one huge page are advised (only from this size on
/// can the aligned inside of a block hold a whole huge page).
pub const MIN_ADVISED_BYTES: usize = HUGE_PAGE;

/// Whether large blocks are advised (off unless `STEPSIM_HUGE_PAGES` turns
/// it on).
static ENABLED: AtomicBool = AtomicBool::new(false);

/// Large freed blocks kept for reuse, whether they are (only in the
/// commands that ask, [`keep_large_blocks`]), and whether the environment
/// allows it.
static CACHE: BlockCache = BlockCache::new();
static CACHING: AtomicBool = AtomicBool::new(false);
static CACHE_ALLOWED: AtomicBool = AtomicBool::new(true);

/// Reads `STEPSIM_HUGE_PAGES` (`1`, `on` or `true` turn the advice on) and
/// `STEPSIM_BLOCK_CACHE` (`0`, `off` or `false` turn the cache of large
/// blocks off). Called once at the start of `main`.
pub fn configure() {
    let (advise, cache) = settings(|name| std::env::var(name).ok());
    ENABLED.store(advise, Ordering::Relaxed);
    CACHE_ALLOWED.store(cache, Ordering::Relaxed);
}

/// (huge-page advice on, block cache allowed) from the environment `var`.
fn settings(var: impl Fn(&str) -> Option<String>) -> (bool, bool) {
    let is = |name: &str, values: [&str; 3]| var(name).is_some_and(|v| values.contains(&v.trim()));
    (
        is("STEPSIM_HUGE_PAGES", ["1", "on", "true"]),
        !is("STEPSIM_BLOCK_CACHE", ["0", "off", "false"]),
    )
}

/// From now on, keeps large freed blocks for reuse ([`crate::block_cache`])
/// unless `STEPSIM_BLOCK_CACHE` turns it off. Only `measure` asks: its
/// memory estimate leaves room for the kept blocks (measured peaks 571–759
/// MiB against its 1 GiB estimate at 4096², two threads), while
/// `generate`'s PSF builds would keep up to the whole budget beside what
/// its estimate counts (the mini preset peaked at 549 MiB with it, 311
/// MiB without, against an estimate of 354 MiB).
pub fn keep_large_blocks() {
    CACHING.store(CACHE_ALLOWED.load(Ordering::Relaxed), Ordering::Relaxed);
}

/// A kept block of exactly this layout, if caching.
fn reuse(layout: Layout) -> Option<*mut u8> {
    if !CACHING.load(Ordering::Relaxed) {
        return None;
    }
    CACHE.take(layout.size(), layout.align())
}

/// The 2 MB-aligned part `[start, end)` of the block at `addr` of `size`
/// bytes, if the block is advised and holds a whole huge page.
pub fn advised_range(addr: usize, size: usize) -> Option<(usize, usize)> {
    if size < MIN_ADVISED_BYTES {
        return None;
    }
    let start = addr.checked_add(HUGE_PAGE - 1)? & !(HUGE_PAGE - 1);
    let end = addr.checked_add(size)? & !(HUGE_PAGE - 1);
    (start < end).then_some((start, end))
}

fn advise(ptr: *mut u8, size: usize) {
    if ptr.is_null() || !ENABLED.load(Ordering::Relaxed) {
        return;
    }
    #[cfg(target_os = "linux")]
    if let Some((start, end)) = advised_range(ptr as usize, size) {
        // SAFETY: [start, end) lies inside the block just allocated for the
        // caller; MADV_HUGEPAGE changes only how its pages are backed, not
        // their contents. A refusal (EINVAL under THP `never`) is ignored.
        unsafe {
            libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
        }
    }
}

/// The system allocator, with large blocks advised to use huge pages.
pub struct HugePageAlloc;

// SAFETY: every call is forwarded to `System` with the caller's arguments;
// the advice touches no memory.
// A kept block came from System with exactly the layout it is reused for,
// was advised then, and is handed to one caller at a time.
unsafe impl GlobalAlloc for HugePageAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if let Some(p) = reuse(layout) {
            return p;
        }
        // SAFETY: the caller's contract is System's.
        let p = unsafe { System.alloc(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if let Some(p) = reuse(layout) {
            // SAFETY: the kept block holds layout.size() writable bytes.
            unsafe { std::ptr::write_bytes(p, 0, layout.size()) };
            return p;
        }
        // SAFETY: as for `alloc`.
        let p = unsafe { System.alloc_zeroed(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        let release = |p: *mut u8, size: usize, align: usize| {
            // SAFETY: a kept block came from System with this size and
            // alignment (a valid layout then).
            unsafe { System.dealloc(p, Layout::from_size_align_unchecked(size, align)) }
        };
        if CACHING.load(Ordering::Relaxed) && CACHE.put(ptr, layout.size(), layout.align(), release)
        {
            return;
        }
        // SAFETY: `ptr` came from System with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as for `dealloc`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        advise(p, new_size);
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_advice_is_off_and_the_cache_allowed_unless_the_environment_says() {
        fn env(pairs: &[(&str, &str)]) -> (bool, bool) {
            settings(|name| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == name)
                    .map(|(_, v)| v.to_string())
            })
        }
        assert_eq!(env(&[]), (false, true));
        for on in ["1", "on", " true "] {
            assert_eq!(env(&[("STEPSIM_HUGE_PAGES", on)]), (true, true));
        }
        for other in ["0", "off", "yes", ""] {
            assert_eq!(env(&[("STEPSIM_HUGE_PAGES", other)]), (false, true));
        }
        for off in ["0", "off", "false"] {
            assert_eq!(env(&[("STEPSIM_BLOCK_CACHE", off)]), (false, false));
        }
        assert_eq!(env(&[("STEPSIM_BLOCK_CACHE", "1")]), (false, true));
    }

    #[test]
    fn only_the_aligned_inside_of_large_blocks_is_advised() {
        const M: usize = 1 << 20;
        assert_eq!(advised_range(0x1000, MIN_ADVISED_BYTES - 1), None);
        // 4 MB from just past a boundary: one whole 2 MB page inside.
        let a = 2 * HUGE_PAGE + 16;
        assert_eq!(
            advised_range(a, 4 * M),
            Some((3 * HUGE_PAGE, 4 * HUGE_PAGE))
        );
        // Aligned: both pages.
        assert_eq!(
            advised_range(2 * HUGE_PAGE, 4 * M),
            Some((2 * HUGE_PAGE, 4 * HUGE_PAGE))
        );
        // 67 MB of a 4096² float image from an unaligned start: 31 pages.
        let (s, e) = advised_range(a, 4096 * 4096 * 4).unwrap();
        assert_eq!((e - s) / HUGE_PAGE, 31);
        assert!(s >= a && e <= a + 4096 * 4096 * 4);
        // No overflow at the top of the address space.
        assert_eq!(advised_range(usize::MAX - M, 8 * M), None);
    }

    /// kB of `AnonHugePages` in the mapping of /proc/self/smaps holding
    /// `addr`.
    fn huge_kb_at(addr: usize) -> Option<u64> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
        let mut inside = false;
        for line in smaps.lines() {
            let first = line.split_whitespace().next().unwrap_or("");
            if let Some((lo, hi)) = first.split_once('-')
                && let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
            {
                inside = (lo..hi).contains(&addr);
                continue;
            }
            if inside && let Some(rest) = line.strip_prefix("AnonHugePages:") {
                return rest.trim().trim_end_matches("kB").trim().parse().ok();
            }
        }
        None
    }

    #[test]
    fn a_large_buffer_is_backed_by_huge_pages_where_the_kernel_allows() {
        let mode = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled")
            .unwrap_or_default();
        if !(mode.contains("[madvise]") || mode.contains("[always]")) {
            eprintln!("skipped: transparent huge pages are off here ({mode:?})");
            return;
        }
        // This test binary allocates through HugePageAlloc (main.rs), with
        // the advice on as STEPSIM_HUGE_PAGES=1 turns it.
        ENABLED.store(true, Ordering::Relaxed);
        let mut v = vec![0u8; 64 << 20];
        for b in v.iter_mut().step_by(4096) {
            *b = 1;
        }
        let kb = huge_kb_at(v.as_ptr() as usize + (32 << 20)).expect("the buffer is mapped");
        eprintln!(
            "64 MB buffer: {kb} kB in huge pages (THP mode {})",
            mode.trim()
        );
        assert!(kb >= 2048, "{kb} kB");
        assert_eq!(v.iter().map(|&b| usize::from(b)).sum::<usize>(), 16384);
        if mode.contains("[madvise]") {
            // Without the advice the kernel uses 4 kB pages in this mode.
            // (Nor from a kept block, advised when it was made.)
            ENABLED.store(false, Ordering::Relaxed);
            let caching = CACHING.swap(false, Ordering::Relaxed);
            let mut w = vec![0u8; 64 << 20];
            CACHING.store(caching, Ordering::Relaxed);
            ENABLED.store(true, Ordering::Relaxed);
            for b in w.iter_mut().step_by(4096) {
                *b = 1;
            }
            let kb = huge_kb_at(w.as_ptr() as usize + (32 << 20)).expect("mapped");
            eprintln!("64 MB buffer, not advised: {kb} kB in huge pages");
            assert_eq!(kb, 0);
        }
    }
}
