//! # stepsim-server
//!
//! A blind shear challenge served over HTTP (`stepsim serve`) and run by
//! the organiser's commands (`stepsim challenge ...`; docs/server.md).
//!
//! ```text
//! store.rs      the state behind a trait; SQLite (WAL, migrations in the binary)
//! challenge.rs  a challenge's directory: init, teams and tokens, reveal
//! api.rs        the JSON API (axum): uploads, entries, leaderboard
//! worker.rs     the scoring queue: claims jobs, calls the harness, records
//! web.rs        the participants' pages (HTML, sessions, CSRF), templates/
//! ```
//!
//! All state lives in one directory (`--state DIR`): `challenge.db`,
//! `uploads/<sha256>` (immutable submission files) and
//! `entries/<id>/{public,holdout}/` (the harness's reports).
#![deny(missing_docs)]

pub mod api;
pub mod challenge;
pub mod store;
pub mod web;
pub mod worker;

pub use challenge::{Challenge, ChallengeError, Settings};

/// Seconds since the Unix epoch, now.
pub fn now_s() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0)
}

/// A Unix time as `YYYY-MM-DDTHH:MM:SSZ` (UTC).
pub fn utc_text(t_s: i64) -> String {
    let days = t_s.div_euclid(86_400);
    let secs = t_s.rem_euclid(86_400);
    // Civil date from days since 1970-01-01 (proleptic Gregorian).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
}

#[cfg(test)]
mod tests {
    use super::utc_text;

    #[test]
    fn utc_text_of_known_instants() {
        assert_eq!(utc_text(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_text(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_text(1_798_761_599), "2026-12-31T23:59:59Z");
        assert_eq!(utc_text(-1), "1969-12-31T23:59:59Z");
    }
}
