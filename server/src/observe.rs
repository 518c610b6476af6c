//! What the organisers see of a running server: a log line per request
//! (method, path, status, milliseconds, the team's id or `-`) and per
//! upload, refusal and scoring job, through `tracing` (plain text or one
//! JSON object a line, on standard error), and the counters behind
//! `GET /metrics` in the Prometheus text format (docs/server.md,
//! "Watching a server"). The request's line is written by the handlers'
//! middleware (`http::log`); this module knows no HTTP.
//!
//! Nothing here is shown to participants: the log goes to the server's
//! standard error, and `/metrics` answers only the organisers (their
//! token or their signed-in session) unless `serve --open-metrics`.

use std::collections::BTreeMap;
use std::sync::Mutex;

/// How `stepsim serve` writes its log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LogFormat {
    /// One line of text an event: time, level, message, `key=value` fields.
    #[default]
    Plain,
    /// One JSON object an event (`timestamp`, `level`, `fields`, `target`).
    Json,
}

impl LogFormat {
    /// `plain` or `json`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "plain" => Some(Self::Plain),
            "json" => Some(Self::Json),
            _ => None,
        }
    }
}

/// Installs the process's log writer (standard error, `info` and above);
/// a second call changes nothing.
pub fn init_logging(format: LogFormat) {
    let builder = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .with_target(false)
        .with_max_level(tracing::Level::INFO);
    let _ = match format {
        LogFormat::Plain => builder.try_init(),
        LogFormat::Json => builder.json().flatten_event(true).try_init(),
    };
}

/// The server's counters since it started (one set a process).
#[derive(Debug, Default)]
pub struct Metrics {
    requests: Mutex<BTreeMap<u16, u64>>,
    uploads: Mutex<BTreeMap<u16, u64>>,
    scorings: Mutex<BTreeMap<&'static str, (u64, f64)>>,
}

use crate::store::QueueCounts;

fn bump<K: Ord>(m: &Mutex<BTreeMap<K, u64>>, k: K) {
    *m.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .entry(k)
        .or_default() += 1;
}

impl Metrics {
    /// Counts an answered request by its status.
    pub fn request(&self, status: u16) {
        bump(&self.requests, status);
    }

    /// Counts an upload by the status it was answered with (202 accepted,
    /// 200 a duplicate, 4xx/5xx refused).
    pub fn upload(&self, status: u16) {
        bump(&self.uploads, status);
    }

    /// Counts a finished scoring job: `scored` or `refused`, and its time.
    pub fn scoring(&self, outcome: &'static str, seconds: f64) {
        let mut m = self
            .scorings
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let e = m.entry(outcome).or_default();
        e.0 += 1;
        e.1 += seconds;
    }

    /// The Prometheus text format (version 0.0.4) of the counters, with the
    /// queue and the live workers as gauges.
    pub fn render(&self, queue: QueueCounts, workers: Option<usize>) -> String {
        use std::fmt::Write;
        let mut out = String::new();
        let lock = |m: &Mutex<BTreeMap<u16, u64>>| {
            m.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone()
        };
        let mut family = |name: &str, kind: &str, help: &str, rows: Vec<(String, String)>| {
            let _ = writeln!(out, "# HELP {name} {help}");
            let _ = writeln!(out, "# TYPE {name} {kind}");
            for (labels, value) in rows {
                let _ = writeln!(out, "{name}{labels} {value}");
            }
        };
        let by_status = |m: BTreeMap<u16, u64>| {
            m.into_iter()
                .map(|(s, n)| (format!("{{status=\"{s}\"}}"), n.to_string()))
                .collect::<Vec<_>>()
        };
        family(
            "stepsim_http_requests_total",
            "counter",
            "Requests answered, by HTTP status.",
            by_status(lock(&self.requests)),
        );
        family(
            "stepsim_uploads_total",
            "counter",
            "Uploads answered, by HTTP status (202 accepted, 200 duplicate, 422 refused by the format check, 429 quota or refusal cap, 403 phase, 413 too large, 408 too slow, 503 busy).",
            by_status(lock(&self.uploads)),
        );
        let scorings = self
            .scorings
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone();
        let outcomes = ["scored", "refused"];
        family(
            "stepsim_scoring_jobs_total",
            "counter",
            "Scoring jobs finished by this server's workers, by outcome.",
            outcomes
                .iter()
                .map(|o| {
                    let n = scorings.get(o).map_or(0, |e| e.0);
                    (format!("{{outcome=\"{o}\"}}"), n.to_string())
                })
                .collect(),
        );
        family(
            "stepsim_scoring_seconds_total",
            "counter",
            "Seconds spent scoring by this server's workers, by outcome.",
            outcomes
                .iter()
                .map(|o| {
                    let s = scorings.get(o).map_or(0.0, |e| e.1);
                    (format!("{{outcome=\"{o}\"}}"), format!("{s:.3}"))
                })
                .collect(),
        );
        family(
            "stepsim_entries",
            "gauge",
            "Entries in the database, by status (all servers and workers of the challenge).",
            [
                ("queued", queue.queued),
                ("scoring", queue.scoring),
                ("scored", queue.scored),
                ("refused", queue.refused),
            ]
            .iter()
            .map(|(s, n)| (format!("{{status=\"{s}\"}}"), n.to_string()))
            .collect(),
        );
        family(
            "stepsim_format_refusals",
            "gauge",
            "Uploads refused by the format check, in the database (never entries).",
            vec![(String::new(), queue.format_refusals.to_string())],
        );
        if let Some(w) = workers {
            family(
                "stepsim_workers_live",
                "gauge",
                "Scoring workers alive in this server.",
                vec![(String::new(), w.to_string())],
            );
        }
        out
    }
}

/// Text a client chose (a path, a refusal quoting an uploaded id) as one
/// safe field of a log line: at most `max` characters (then `…`), every
/// control character (C0, DEL, C1), every white space other than the
/// plain space, and the line and paragraph separators written as
/// `\u{..}`, so that no client can end a line, forge a field (`\u{a0}`
/// looks like a space) or reach the organiser's terminal.
pub fn log_text(text: &str, max: usize) -> String {
    let mut out = String::new();
    for (k, c) in text.chars().enumerate() {
        if k == max {
            out.push('…');
            break;
        }
        if c.is_control() || (c.is_whitespace() && c != ' ') {
            out.push_str(&format!("\\u{{{:x}}}", u32::from(c)));
        } else {
            out.push(c);
        }
    }
    out
}

/// The first line of a message, made safe and at most 300 characters (a
/// refusal's reason in a log line).
pub(crate) fn first_line(message: &str) -> String {
    log_text(message.lines().next().unwrap_or_default(), 300)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn client_text_in_a_log_line_cannot_end_the_line_or_forge_a_field() {
        assert_eq!(log_text("/api/submissions", 200), "/api/submissions");
        assert_eq!(
            log_text("a\rb\nc\x1b[2Jd", 200),
            "a\\u{d}b\\u{a}c\\u{1b}[2Jd"
        );
        // Look-alike spaces, NEL, C1 and the line separator are escaped.
        assert_eq!(
            log_text("/x\u{a0}status=202\u{85}\u{9b}\u{2028}", 200),
            "/x\\u{a0}status=202\\u{85}\\u{9b}\\u{2028}"
        );
        assert_eq!(log_text("γ ok", 200), "γ ok");
        let long = "x".repeat(60_000);
        assert_eq!(log_text(&long, 200).chars().count(), 201);
        assert_eq!(first_line("one\rtwo\nthree"), "one\\u{d}two");
    }

    #[test]
    fn metrics_render_in_the_prometheus_text_format() {
        let m = Metrics::default();
        m.request(200);
        m.request(200);
        m.request(404);
        m.upload(202);
        m.upload(422);
        m.scoring("scored", 1.5);
        m.scoring("scored", 0.25);
        let text = m.render(
            QueueCounts {
                queued: 3,
                scoring: 1,
                scored: 2,
                refused: 0,
                format_refusals: 4,
            },
            Some(2),
        );
        for line in [
            "stepsim_http_requests_total{status=\"200\"} 2",
            "stepsim_http_requests_total{status=\"404\"} 1",
            "stepsim_uploads_total{status=\"202\"} 1",
            "stepsim_uploads_total{status=\"422\"} 1",
            "stepsim_scoring_jobs_total{outcome=\"scored\"} 2",
            "stepsim_scoring_jobs_total{outcome=\"refused\"} 0",
            "stepsim_scoring_seconds_total{outcome=\"scored\"} 1.750",
            "stepsim_entries{status=\"queued\"} 3",
            "stepsim_entries{status=\"scoring\"} 1",
            "stepsim_format_refusals 4",
            "stepsim_workers_live 2",
            "# TYPE stepsim_entries gauge",
        ] {
            assert!(text.lines().any(|l| l == line), "{line:?} not in\n{text}");
        }
        // Every sample line is `name{labels} value` with a number.
        for l in text.lines().filter(|l| !l.starts_with('#')) {
            let v = l.rsplit(' ').next().unwrap();
            assert!(v.parse::<f64>().is_ok(), "{l}");
        }
    }
}
