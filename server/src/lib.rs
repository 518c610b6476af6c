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
//! A challenge lives in one directory (`--state DIR`): `challenge.db` (or
//! `store.url`, naming a PostgreSQL database), `uploads/<sha256>`
//! (immutable submission files) and `entries/<id>/{public,holdout}/` (the
//! harness's reports). Processes on several hosts share the directory (a
//! network file system) and the database.
#![deny(missing_docs)]

pub mod challenge;
pub mod http;
pub mod observe;
pub mod store;
pub mod worker;

pub use challenge::{Challenge, ChallengeError, Settings};

/// Runs `f` to its end on a runtime of its own (for the command line's
/// organiser commands, which call the async store).
pub fn block_on<F: std::future::Future>(f: F) -> Result<F::Output, ChallengeError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ChallengeError::Run(format!("cannot start a runtime: {e}")))?;
    Ok(rt.block_on(f))
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

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

/// Days since 1970-01-01 of a civil date (proleptic Gregorian).
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y.rem_euclid(400);
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Reads an RFC 3339 time (`2026-12-31T23:59:59Z`, `...T12:00:00+02:00`,
/// fractions of a second dropped) as Unix seconds; `None` when it is not one.
pub fn parse_rfc3339(text: &str) -> Option<i64> {
    let t = text.trim();
    let b = t.as_bytes();
    let num = |r: std::ops::Range<usize>| -> Option<i64> {
        let s = t.get(r)?;
        (!s.is_empty() && s.bytes().all(|c| c.is_ascii_digit())).then(|| s.parse().ok())?
    };
    if b.len() < 20
        || b[4] != b'-'
        || b[7] != b'-'
        || !matches!(b[10], b'T' | b't' | b' ')
        || b[13] != b':'
        || b[16] != b':'
    {
        return None;
    }
    let (year, month, day) = (num(0..4)?, num(5..7)?, num(8..10)?);
    let (hour, minute, second) = (num(11..13)?, num(14..16)?, num(17..19)?);
    let mut rest = t.get(19..)?;
    if let Some(frac) = rest.strip_prefix('.') {
        let n = frac.bytes().take_while(u8::is_ascii_digit).count();
        if n == 0 {
            return None;
        }
        rest = &frac[n..];
    }
    let offset_s = match rest {
        "Z" | "z" => 0,
        _ => {
            let sign = match rest.as_bytes().first()? {
                b'+' => 1,
                b'-' => -1,
                _ => return None,
            };
            let o = rest.get(1..)?;
            if o.len() != 5 || o.as_bytes()[2] != b':' {
                return None;
            }
            let (h, m): (i64, i64) = (o[..2].parse().ok()?, o[3..].parse().ok()?);
            if h > 23 || m > 59 {
                return None;
            }
            sign * (h * 3600 + m * 60)
        }
    };
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let month_days = [
        31,
        if leap { 29 } else { 28 },
        31,
        30,
        31,
        30,
        31,
        31,
        30,
        31,
        30,
        31,
    ];
    if !(1..=12).contains(&month)
        || day < 1
        || day > month_days[(month - 1) as usize]
        || hour > 23
        || minute > 59
        || second > 60
    {
        return None;
    }
    let days = days_from_civil(year, month, day);
    Some(days * 86_400 + hour * 3600 + minute * 60 + second.min(59) - offset_s)
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
    }
}
