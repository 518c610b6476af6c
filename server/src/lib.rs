//! # stepsim-server
//!
//! A blind shear challenge served over HTTP (`stepsim serve`) and run by
//! the organiser's commands (`stepsim challenge ...`; docs/server.md).
//!
//! Three layers, each using only those below it (`tests/module_graph.rs`
//! checks it):
//!
//! ```text
//! http/         the handlers: AppState, ApiError, the router, `serve`
//!   api/        the JSON API by job: entries and finals, uploads, the
//!               leaderboard, the challenge's state, the public data files
//!   pages/      the pages (HTML, sessions, CSRF; templates/), one a page
//!   auth.rs     bearer tokens and the rate limit
//!   log.rs      the log line of each request
//!   net.rs      the connection layer (hyper): timeouts, caps per address
//!   limits.rs   the limits on connections, bodies, uploads, format checks
//! worker.rs     the scoring queue: claims jobs, calls the harness, records;
//!               store errors are waited out, never end a worker
//! observe.rs    what the organisers see: a log line per upload, refusal
//!               and scoring job; the counters of /metrics
//! challenge/    the challenge, no HTTP: its directory (init, teams and
//!               tokens, reveal, export), phase, admission rules, final
//!               entries, typed figures, the leaderboard, the public data
//! store/        the state behind an async trait: SQLite (WAL, migrations in
//!               the binary; the default) and PostgreSQL (several hosts)
//! ```
//!
//! `worker` and `observe` sit beside the handlers: they use the challenge
//! and the store, never `http`, and know no HTTP.
//!
//! The modules are private: what the binary and the tests call is
//! re-exported here, each item under one name.
//!
//! A challenge lives in one directory (`--state DIR`): `challenge.db` (or
//! `store.url`, naming a PostgreSQL database), `uploads/<sha256>`
//! (immutable submission files) and `entries/<id>/{public,holdout}/` (the
//! harness's reports). Processes on several hosts share the directory (a
//! network file system) and the database.
#![deny(missing_docs)]

mod challenge;
mod http;
mod observe;
mod store;
mod worker;

// The challenge and its rules.
pub use challenge::leaderboard::{q_c_interval, rows as leaderboard_rows};
pub use challenge::{
    Challenge, ChallengeError, DEFAULT_QUOTA, Export, ORGANISER_PASSWORD_KEY, Phase,
    SCORER_VERSION, Settings, verify_organiser_password,
};

// The store.
pub use store::{Lease, MIGRATIONS, Role, STORE_FILE, SqliteStore, Store, StoreUrl};

// The scoring queue and what the organisers see.
pub use observe::{LogFormat, init_logging};
pub use worker::{
    DEFAULT_LEASE_S, DEFAULT_TIMEOUT, WorkerOptions, WorkerPool, run_worker, score_entry,
};

// HTTP: the handlers, the connection layer and its limits, the pages.
pub use http::auth::bearer_token;
pub use http::limits::{
    DEFAULT_BODY_GRACE, DEFAULT_BODY_MIN_BYTES_PER_S, DEFAULT_BODY_STALL_TIMEOUT,
    DEFAULT_CHECK_BUDGET, DEFAULT_HEADER_TIMEOUT, DEFAULT_IDLE_TIMEOUT, DEFAULT_MAX_CONNECTIONS,
    DEFAULT_MAX_CONNECTIONS_PER_ADDR, DEFAULT_UPLOADS_AT_ONCE, DEFAULT_UPLOADS_PER_TEAM, Limits,
    default_checks_at_once,
};
pub use http::net::serve_with_limits;
pub use http::pages::{PAGE_CSP, SESSION_COOKIE, escape as escape_html};
pub use http::{AppState, router, serve_blocking};

/// Runs `f` to its end on a runtime of its own (for the command line's
/// organiser commands, which call the async store).
pub fn block_on<F: std::future::Future>(f: F) -> Result<F::Output, ChallengeError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ChallengeError::Run(format!("cannot start a runtime: {e}")))?;
    Ok(rt.block_on(f))
}

/// Seconds since the Unix epoch, now.
pub fn now_s() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0)
}

/// A Unix time as `YYYY-MM-DDTHH:MM:SSZ` (UTC, RFC 3339 by the `time`
/// crate); a time outside the years 0000–9999, which RFC 3339 cannot
/// write, as `@` and its seconds since 1970 (`@1000000000000`).
pub fn utc_text(t_s: i64) -> String {
    time::OffsetDateTime::from_unix_timestamp(t_s)
        .ok()
        .and_then(|t| {
            t.format(&time::format_description::well_known::Rfc3339)
                .ok()
        })
        .unwrap_or_else(|| format!("@{t_s}"))
}

/// Reads an RFC 3339 time (`2026-12-31T23:59:59Z`, `...T12:00:00+02:00`;
/// the `time` crate's reader, surrounding white space ignored, fractions of
/// a second dropped) as Unix seconds; `None` when it is not one.
pub fn parse_rfc3339(text: &str) -> Option<i64> {
    time::OffsetDateTime::parse(text.trim(), &time::format_description::well_known::Rfc3339)
        .ok()
        .map(|t| t.unix_timestamp())
}

#[cfg(test)]
mod tests {
    use super::{parse_rfc3339, utc_text};

    #[test]
    fn rfc3339_times_read_back_as_written() {
        for t in [0, 951_782_400, 1_798_761_599, -1, 1_700_000_000] {
            assert_eq!(parse_rfc3339(&utc_text(t)), Some(t));
        }
        assert_eq!(
            parse_rfc3339("2026-12-31T23:59:59.25+01:00"),
            Some(1_798_761_599 - 3600)
        );
        assert_eq!(
            parse_rfc3339("2000-02-29t00:00:00-00:30"),
            Some(951_784_200)
        );
        for bad in [
            "",
            "2026-12-31",
            "2026-12-31T23:59:59",
            "2026-02-30T00:00:00Z",
            "2026-13-01T00:00:00Z",
            "2026-12-31T24:00:00Z",
            "2026-12-31T23:59:59+1:00",
            "2026-12-31T23:59:59.Z",
            "２026-12-31T23:59:59Z",
            "tomorrow",
        ] {
            assert_eq!(parse_rfc3339(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn utc_text_of_known_instants() {
        assert_eq!(utc_text(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_text(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_text(1_798_761_599), "2026-12-31T23:59:59Z");
        assert_eq!(utc_text(-1), "1969-12-31T23:59:59Z");
        assert_eq!(utc_text(i64::MAX), "@9223372036854775807");
        assert_eq!(
            parse_rfc3339(" 2026-12-31 23:59:59Z\n"),
            Some(1_798_761_599)
        );
    }
}
