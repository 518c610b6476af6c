//! The server's limits on connections, request bodies, uploads and format
//! checks (docs/server.md, "Threat model"): one value each, with a default
//! chosen for one challenge on a small machine, set per `stepsim serve`
//! (its flags) rather than per challenge.

use std::time::Duration;

/// Limits of one running server.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// From the first byte of a request to the end of its headers.
    pub header_timeout: Duration,
    /// A connection with no request in flight and no byte read or written
    /// for this long is closed (also a kept-alive one between requests).
    pub idle_timeout: Duration,
    /// A request body that sends nothing for this long is cut off (408).
    pub body_stall_timeout: Duration,
    /// After [`Limits::body_grace`], a body must have arrived at this many
    /// bytes per second on average (counted from its start), or it is cut
    /// off (408).
    pub body_min_bytes_per_s: u64,
    /// See [`Limits::body_min_bytes_per_s`].
    pub body_grace: Duration,
    /// Connections open at once, from all clients.
    pub max_connections: usize,
    /// Connections open at once from one client address.
    pub max_connections_per_addr: usize,
    /// Uploads of one team being received or checked at once.
    pub uploads_per_team: usize,
    /// Uploads being received or checked at once, all teams together.
    pub uploads_at_once: usize,
    /// Format checks (the harness reading an upload) running at once.
    pub checks_at_once: usize,
    /// The wall-clock budget of one format check, its wait for a turn
    /// included; past it the upload is refused (503, not counted as the
    /// participant's refusal).
    pub check_budget: Duration,
}

/// Default [`Limits::header_timeout`].
pub const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// Default [`Limits::idle_timeout`].
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// Default [`Limits::body_stall_timeout`].
pub const DEFAULT_BODY_STALL_TIMEOUT: Duration = Duration::from_secs(30);
/// Default [`Limits::body_min_bytes_per_s`] (16 KiB/s: a 256 MiB upload
/// may take up to 4.5 hours).
pub const DEFAULT_BODY_MIN_BYTES_PER_S: u64 = 16 * 1024;
/// Default [`Limits::body_grace`].
pub const DEFAULT_BODY_GRACE: Duration = Duration::from_secs(30);
/// Default [`Limits::max_connections`].
pub const DEFAULT_MAX_CONNECTIONS: usize = 512;
/// Default [`Limits::max_connections_per_addr`].
pub const DEFAULT_MAX_CONNECTIONS_PER_ADDR: usize = 32;
/// Default [`Limits::uploads_per_team`].
pub const DEFAULT_UPLOADS_PER_TEAM: usize = 1;
/// Default [`Limits::uploads_at_once`].
pub const DEFAULT_UPLOADS_AT_ONCE: usize = 4;
/// Default [`Limits::check_budget`].
pub const DEFAULT_CHECK_BUDGET: Duration = Duration::from_secs(300);

impl Default for Limits {
    fn default() -> Self {
        Self {
            header_timeout: DEFAULT_HEADER_TIMEOUT,
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            body_stall_timeout: DEFAULT_BODY_STALL_TIMEOUT,
            body_min_bytes_per_s: DEFAULT_BODY_MIN_BYTES_PER_S,
            body_grace: DEFAULT_BODY_GRACE,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_connections_per_addr: DEFAULT_MAX_CONNECTIONS_PER_ADDR,
            uploads_per_team: DEFAULT_UPLOADS_PER_TEAM,
            uploads_at_once: DEFAULT_UPLOADS_AT_ONCE,
            checks_at_once: default_checks_at_once(),
            check_budget: DEFAULT_CHECK_BUDGET,
        }
    }
}

/// Default [`Limits::checks_at_once`]: one per core.
pub fn default_checks_at_once() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

impl Limits {
    /// How long the next piece of a body may take when `received` bytes
    /// came in `elapsed` since it began: the stall timeout, or less when
    /// the average rate would fall below the minimum sooner. `None` when
    /// the body is already too slow.
    pub fn body_wait(&self, received: u64, elapsed: Duration) -> Option<Duration> {
        // The body is too slow at t when received < rate × (t − grace).
        let rate = self.body_min_bytes_per_s.max(1) as f64;
        let limit_t = self.body_grace.as_secs_f64() + (received as f64 + 1.0) / rate;
        let left = limit_t - elapsed.as_secs_f64();
        (left > 0.0).then(|| self.body_stall_timeout.min(Duration::from_secs_f64(left)))
    }
}

#[cfg(test)]
mod tests {
    use super::Limits;
    use std::time::Duration;

    #[test]
    fn body_wait_is_the_stall_timeout_or_the_time_left_at_the_minimum_rate() {
        let l = Limits {
            body_stall_timeout: Duration::from_secs(30),
            body_min_bytes_per_s: 1000,
            body_grace: Duration::from_secs(10),
            ..Limits::default()
        };
        // Nothing yet: the grace and the time for one byte (10.001 s),
        // shorter than the stall timeout.
        let w = l.body_wait(0, Duration::ZERO).unwrap();
        assert!((w.as_secs_f64() - 10.001).abs() < 1e-9, "{w:?}");
        // Early on with some bytes, the stall timeout.
        assert_eq!(
            l.body_wait(100_000, Duration::from_secs(1)),
            Some(Duration::from_secs(30))
        );
        // 1000 bytes by 10.5 s: too slow from 11.001 s on.
        let w = l.body_wait(1000, Duration::from_millis(10_500)).unwrap();
        assert!((w.as_secs_f64() - 0.501).abs() < 1e-9, "{w:?}");
        // 5000 bytes at 20 s: 15 s needed at least, too slow already.
        assert_eq!(l.body_wait(5000, Duration::from_secs(20)), None);
        // A fast body waits the stall timeout.
        assert_eq!(
            l.body_wait(10_000_000, Duration::from_secs(20)),
            Some(Duration::from_secs(30))
        );
    }
}
