//! One module per subcommand; each has `Args` (clap) and `run`.

pub mod bench;
pub mod catalog;
pub mod challenge;
pub mod config;
pub mod generate;
pub mod leaderboard;
pub mod measure;
pub mod progress;
pub mod psf;
pub mod score;
pub mod serve;
pub mod slurm;
pub mod worker;

use anyhow::Context as _;
use std::path::PathBuf;

/// Largest `--threads` accepted (beyond it: a usage error, exit 2).
pub const MAX_THREADS: usize = 1024;

/// Worker threads allowed per available core: more only adds start-up and
/// scheduling cost (3000 threads made a 1 s job take 32 s) and memory, since
/// every thread holds one image in flight; a few per core stay allowed so
/// that thread-independence can be checked on small machines.
pub const THREADS_PER_CORE: usize = 4;

/// Parses `--threads`: 0 (one per core) to [`MAX_THREADS`] (a usage
/// error, exit 2, otherwise).
pub fn threads_arg(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if n <= MAX_THREADS => Ok(n),
        Ok(n) => Err(format!(
            "{n} is more than {MAX_THREADS} (0 means one per core)"
        )),
        Err(e) => Err(format!("not a thread count: {e}")),
    }
}

/// The thread count to use for `requested` (0: one per core) on a machine
/// with `cores` cores, and a note when it was lowered: at most
/// [`THREADS_PER_CORE`] × `cores`.
pub fn effective_threads(what: &str, requested: usize, cores: usize) -> (usize, Option<String>) {
    let cores = cores.max(1);
    let cap = THREADS_PER_CORE * cores;
    match requested {
        0 => (cores, None),
        n if n > cap => (
            cap,
            Some(format!(
                "{what} {n} is more than {THREADS_PER_CORE} per core ({cores} cores here); using {cap} (the output does not depend on it)"
            )),
        ),
        n => (n, None),
    }
}

/// Cores available to this process.
pub fn available_cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Parses `--shard`: `K/N`, or `auto` for the shard of a Slurm job-array
/// task (K = SLURM_ARRAY_TASK_ID − SLURM_ARRAY_TASK_MIN + 1, N =
/// SLURM_ARRAY_TASK_COUNT). `auto` outside an array, or with variables that
/// do not describe a contiguous array, is a usage error (exit 2): the
/// command line asks for something this environment does not give, and
/// nothing has been read or written yet.
pub fn shard_arg(s: &str) -> Result<stepsim_sim::run::generate::Shard, String> {
    shard_arg_with(s, |name| std::env::var(name).ok())
}

/// [`shard_arg`] with the environment given as a function.
pub fn shard_arg_with(
    s: &str,
    var: impl Fn(&str) -> Option<String>,
) -> Result<stepsim_sim::run::generate::Shard, String> {
    use stepsim_sim::run::generate::Shard;
    if s.trim() == "auto" {
        Shard::from_slurm(var).map_err(|e| e.to_string())
    } else {
        s.parse::<Shard>().map_err(|e| e.to_string())
    }
}

/// [`effective_threads`] of `--threads` for this machine, printing the note
/// if any.
pub fn threads(requested: usize) -> usize {
    threads_of("--threads", requested)
}

/// [`effective_threads`] of a setting named `what`, printing the note if any.
pub fn threads_of(what: &str, requested: usize) -> usize {
    let (n, note) = effective_threads(what, requested, available_cores());
    if let Some(note) = note {
        eprintln!("stepsim: note: {note}");
    }
    n
}

/// A rayon pool of `n` workers (`n` from [`threads`]).
pub fn thread_pool(n: usize) -> anyhow::Result<rayon::ThreadPool> {
    use anyhow::Context as _;
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .context("cannot start the thread pool")
}

/// Refuses a command whose memory estimate exceeds the memory available
/// (`STEPSIM_MEMORY_LIMIT_BYTES`, else /proc/meminfo), before it writes
/// anything.
pub fn check_memory(
    command: &str,
    estimate: stepsim_sim::run::memory::MemoryEstimate,
    hint: &str,
) -> anyhow::Result<()> {
    let var = stepsim_sim::io::MEMORY_LIMIT_ENV;
    if let Some(v) = std::env::var_os(var)
        && v.to_str()
            .and_then(|t| t.trim().parse::<u64>().ok())
            .is_none()
    {
        anyhow::bail!(
            "{var}={}: not a number of bytes (unset it to use the memory the system reports)",
            v.to_string_lossy()
        );
    }
    stepsim_sim::run::memory::check(command, estimate, stepsim_sim::io::available_memory(), hint)?;
    Ok(())
}

/// Environment variable that sets the free disk space (bytes) `generate`
/// may plan to fill, instead of what the file system reports (for tests).
pub const DISK_LIMIT_ENV: &str = "STEPSIM_DISK_LIMIT_BYTES";

/// Free bytes on the file system that holds `path` (or its nearest existing
/// ancestor), and where the number comes from: `STEPSIM_DISK_LIMIT_BYTES`
/// if set, else `statvfs` (blocks available to unprivileged users). `None`
/// when unknown.
pub fn free_disk(path: &std::path::Path) -> anyhow::Result<Option<(u64, String)>> {
    if let Some(v) = std::env::var_os(DISK_LIMIT_ENV) {
        let b = v
            .to_str()
            .and_then(|t| t.trim().parse::<u64>().ok())
            .with_context(|| {
                format!(
                    "{DISK_LIMIT_ENV}={}: not a number of bytes (unset it to use the free space the file system reports)",
                    v.to_string_lossy()
                )
            })?;
        return Ok(Some((b, format!("{DISK_LIMIT_ENV}={b}"))));
    }
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let Some(existing) = abs.ancestors().find(|p| p.exists()) else {
        return Ok(None);
    };
    let Ok(c) = std::ffi::CString::new(existing.as_os_str().as_encoded_bytes()) else {
        return Ok(None);
    };
    let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `c` is a valid NUL-terminated path and `st` a writable
    // statvfs; the struct is read only when the call succeeds.
    let rc = unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) };
    if rc != 0 {
        return Ok(None);
    }
    // SAFETY: statvfs returned 0, so it filled `st`.
    let st = unsafe { st.assume_init() };
    // The field types differ between platforms (u64 on 64-bit Linux).
    #[allow(clippy::useless_conversion)]
    let free = u64::from(st.f_bavail).saturating_mul(u64::from(st.f_frsize));
    Ok(Some((free, format!("statvfs of {}", existing.display()))))
}

/// Bytes of the regular files under `dir` (0 when it does not exist); the
/// files of a run being resumed count against what it still has to write.
pub fn bytes_under(dir: &std::path::Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut total = 0u64;
    for e in entries.flatten() {
        let Ok(t) = e.file_type() else { continue };
        if t.is_dir() {
            total = total.saturating_add(bytes_under(&e.path()));
        } else if t.is_file() {
            total = total.saturating_add(e.metadata().map(|m| m.len()).unwrap_or(0));
        }
    }
    total
}

/// Refuses a `generate` whose files would not fit on the file system of
/// `out` (before anything is written, with the PSF files counted at their
/// least), and returns the space measured, against which `generate`
/// checks again once the PSFs are solved.
pub fn check_disk(
    plan: &stepsim_sim::Plan,
    out: &std::path::Path,
) -> anyhow::Result<stepsim_sim::run::disk::DiskSpace> {
    let space = stepsim_sim::run::disk::DiskSpace {
        present_bytes: bytes_under(out),
        free: free_disk(out)?,
    };
    stepsim_sim::run::disk::check(
        &out.display().to_string(),
        stepsim_sim::run::disk::generate_estimate(plan, None),
        space.present_bytes,
        space.free.clone(),
    )?;
    Ok(space)
}

/// Refuses a path that is not valid UTF-8 where FITS files are read or
/// written below it (cfitsio's file names are text), before any work.
pub fn fits_path(flag: &str, path: &std::path::Path) -> anyhow::Result<()> {
    if path.to_str().is_none() {
        anyhow::bail!(
            "{flag} {}: the path is not valid UTF-8, which FITS file names must be",
            path.display()
        );
    }
    Ok(())
}

/// Arguments shared by every command that reads a config.
#[derive(Debug, clap::Args)]
pub struct ConfigArgs {
    /// The JSON config file (see docs/config.md).
    #[arg(long, value_name = "FILE")]
    pub config: PathBuf,
    /// Override one config value: `--set image.n_images=4` (repeatable; the
    /// value is read as JSON when it parses, as a string otherwise).
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    pub overrides: Vec<String>,
}

impl ConfigArgs {
    /// Loads and validates the config with its overrides.
    pub fn plan(&self) -> anyhow::Result<stepsim_sim::Plan> {
        Ok(stepsim_sim::Plan::load(&self.config, &self.overrides)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_auto_reads_the_slurm_array_and_k_n_stays() {
        let slurm = |name: &str| {
            [
                ("SLURM_ARRAY_TASK_ID", "5"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("SLURM_ARRAY_TASK_MIN", "2"),
            ]
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| v.to_string())
        };
        let s = shard_arg_with("auto", slurm).unwrap();
        assert_eq!((s.k, s.n), (4, 4));
        let s = shard_arg_with("2/3", slurm).unwrap();
        assert_eq!((s.k, s.n), (2, 3));
        let e = shard_arg_with("auto", |_| None).unwrap_err();
        assert!(e.contains("SLURM_ARRAY_TASK_ID is not set"), "{e}");
        assert!(shard_arg_with("4/3", slurm).is_err());
    }

    #[test]
    fn thread_counts_are_capped_per_core_with_a_note() {
        assert_eq!(effective_threads("--threads", 0, 2), (2, None));
        assert_eq!(effective_threads("--threads", 3, 2), (3, None));
        assert_eq!(effective_threads("--threads", 8, 2), (8, None));
        let (n, note) = effective_threads("--threads", 3000, 2);
        assert_eq!(n, 8);
        let note = note.unwrap();
        assert!(
            note.contains("--threads 3000") && note.contains("using 8"),
            "{note}"
        );
        assert_eq!(effective_threads("--threads", 5, 1).0, 4);
        // No core count (0) is taken as one core.
        assert_eq!(effective_threads("--threads", 0, 0), (1, None));
    }
}
