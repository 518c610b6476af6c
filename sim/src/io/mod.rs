//! File input and output. Nothing in the numerical core touches files: all
//! reading and writing of FITS, CSV, JSON and SkyMaker lists lives here.
//!
//! Every writer goes through [`stepsim_contract::io::write_atomically`]: the
//! file is written under a temporary name in the same directory and renamed
//! into place only when complete, so a killed run never leaves a truncated file under a final name.
//! The error type, the atomic writes, FITS open/create by plain name and the
//! truth tables are the run's on-disk contract and live in
//! [`stepsim_contract::io`]; the PNG writer is [`stepsim_figure::png`].

pub mod image_fits;
pub mod psf_fits;
pub mod psf_store;
pub mod skymaker;
pub mod truth_header;

/// Environment variable that sets the memory (bytes) a command may plan to
/// use, instead of what the system reports (for tests, and for organisers
/// who share a machine).
pub const MEMORY_LIMIT_ENV: &str = "STEPSIM_MEMORY_LIMIT_BYTES";

/// The memory this process may use, and where the number comes from:
/// `STEPSIM_MEMORY_LIMIT_BYTES` if set, else `MemAvailable` of
/// `/proc/meminfo`, lowered to what the cgroup (`memory.max` −
/// `memory.current`) leaves when that is less. `None` when unknown.
pub fn available_memory() -> Option<(u64, String)> {
    if let Ok(v) = std::env::var(MEMORY_LIMIT_ENV) {
        return v
            .trim()
            .parse::<u64>()
            .ok()
            .map(|b| (b, format!("{MEMORY_LIMIT_ENV}={b}")));
    }
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kib: u64 = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemAvailable:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    let mut best = (kib * 1024, "MemAvailable in /proc/meminfo".to_string());
    let read = |p: &str| -> Option<u64> { std::fs::read_to_string(p).ok()?.trim().parse().ok() };
    if let (Some(max), Some(cur)) = (
        read("/sys/fs/cgroup/memory.max"),
        read("/sys/fs/cgroup/memory.current"),
    ) {
        let left = max.saturating_sub(cur);
        if left < best.0 {
            best = (left, "the cgroup's memory.max".into());
        }
    }
    Some(best)
}
