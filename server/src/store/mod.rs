//! The challenge's state behind one async trait ([`Store`]), with two
//! backends: [`SqliteStore`] (the embedded default: one SQLite file in WAL
//! mode beside the uploads) and [`PgStore`] (PostgreSQL, for several
//! `serve` and `worker` processes on several hosts). [`open`] picks one by
//! its address ([`StoreUrl`]).
//!
//! Times are Unix seconds (UTC). A submission moves
//! `queued → scoring → scored | refused`; a worker takes a job with a
//! lease ([`Store::claim_job`]) that it renews while it scores
//! ([`Store::renew_lease`]). A worker that dies (killed, its host lost)
//! stops renewing, and once the lease has run out another worker takes the
//! job again. Only the worker holding the lease can record the result
//! ([`Store::finish_job`]), in one transaction, so every accepted
//! submission is scored once.
//!
//! Every rule that several processes could break together is one
//! transaction in the database, never a process's mutex: an upload's
//! admission ([`Store::admit`]: phase, duplicate, quota, refusal cap,
//! insert), the choice of final entries ([`Store::set_final_entries`]:
//! refused once closed), and the claim of a job (one job per team at a
//! time).

mod postgres;
mod sqlite;

pub use postgres::PgStore;
pub use sqlite::{MIGRATIONS, SqliteStore};

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// What can go wrong in the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database refused an operation.
    #[error("database {path}: {message}")]
    Db {
        /// The database (a file, or a PostgreSQL address without password).
        path: String,
        /// What the database said.
        message: String,
    },
    /// The database was made by a newer stepsim.
    #[error("database {path} has schema version {found}; this stepsim knows up to {known}")]
    TooNew {
        /// The database.
        path: String,
        /// Its version.
        found: i64,
        /// The newest this binary knows.
        known: i64,
    },
}

/// A team's part in the challenge: participants are ranked; the organisers'
/// rows and the baseline (the KSB+ reference) are shown, tagged, unranked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Role {
    /// Ranked on the leaderboards.
    #[default]
    Participant,
    /// The organisers' own entries: shown, never ranked.
    Organisers,
    /// The reference pipeline: shown, tagged, never ranked.
    Baseline,
}

impl Role {
    /// Every role.
    pub const ALL: [Role; 3] = [Role::Participant, Role::Organisers, Role::Baseline];

    /// The role's name (`participant`, `organisers`, `baseline`), as stored
    /// and as the API's `role` key.
    pub fn name(self) -> &'static str {
        match self {
            Role::Participant => "participant",
            Role::Organisers => "organisers",
            Role::Baseline => "baseline",
        }
    }

    /// The role of a name, if it is one.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// One score of an entry by one scorer version (kept when the entry is
/// scored again by another).
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    /// The entry.
    pub submission_id: i64,
    /// The scorer that made it (`challenge::SCORER_VERSION`).
    pub scorer_version: String,
    /// `scored` or `refused`.
    pub status: String,
    /// When it was recorded.
    pub finished_s: i64,
    /// Why it was refused.
    pub error: Option<String>,
    /// The public feedback (JSON).
    pub public_json: Option<String>,
    /// The held-out summary (JSON).
    pub holdout_json: Option<String>,
    /// How many times this scorer version finished scoring the entry
    /// (1: exactly once).
    pub n_scorings: i64,
}

/// A team.
#[derive(Debug, Clone, PartialEq)]
pub struct Team {
    /// Row id.
    pub id: i64,
    /// Display name (any text; escaped wherever shown).
    pub name: String,
    /// True when its token no longer works.
    pub revoked: bool,
    /// Ranked, or shown unranked as the organisers' or the baseline.
    pub role: Role,
}

/// One submission.
#[derive(Debug, Clone, PartialEq)]
pub struct Submission {
    /// Row id (the `id` of the API).
    pub id: i64,
    /// Its team.
    pub team_id: i64,
    /// SHA-256 of the uploaded bytes (lower-case hex).
    pub sha256: String,
    /// Size of the upload.
    pub bytes: i64,
    /// When it was accepted.
    pub created_s: i64,
    /// `queued`, `scoring`, `scored` or `refused`.
    pub status: String,
    /// Why it was refused.
    pub error: Option<String>,
    /// The public feedback (JSON of `stepsim_harness::PublicFeedback`).
    pub public_json: Option<String>,
    /// The held-out summary (JSON), shown only after reveal.
    pub holdout_json: Option<String>,
    /// How many times a worker finished scoring it, over all scorer
    /// versions (1 once scored; each re-score adds one).
    pub n_scorings: i64,
    /// The scorer version of the score shown (the newest), once scored.
    pub scorer_version: Option<String>,
    /// True when its team chose it as a final entry.
    pub final_choice: bool,
    /// The worker that holds its lease (while `scoring`) or last held it.
    pub worker: Option<String>,
}

impl Submission {
    /// True when it has a score to show (`scored`, or queued again for a
    /// re-score and still showing its previous one).
    pub fn has_score(&self) -> bool {
        self.public_json.is_some()
    }
}

/// An upload the format check refused: never an entry, but counted
/// against its team's cap on refused uploads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FormatFailure {
    /// The team.
    pub team_id: i64,
    /// When (Unix seconds).
    pub created_s: i64,
    /// The harness's message, as the team was shown it.
    pub error: String,
}

/// How many entries are in each state, and how many uploads the format
/// check refused (what the organisers' page and `/metrics` show).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct QueueCounts {
    /// Entries waiting for a worker.
    pub queued: u64,
    /// Entries being scored.
    pub scoring: u64,
    /// Entries scored.
    pub scored: u64,
    /// Entries the scorer refused.
    pub refused: u64,
    /// Uploads refused by the format check (never entries).
    pub format_refusals: u64,
}

/// What an upload's admission sees, read in the transaction that then
/// inserts it (or not): every setting, and the team's recent uploads.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Ledger {
    /// Every setting (`deadline`, `frozen`, `closed`, ...).
    pub meta: HashMap<String, String>,
    /// Creation times of the team's accepted entries since the window's
    /// start, oldest first.
    pub accepted: Vec<i64>,
    /// Times of the team's refused uploads since the window's start,
    /// oldest first.
    pub refused: Vec<i64>,
}

/// The rule of an upload's admission ([`Store::admit`]): true to insert.
pub type Rule = std::sync::Arc<dyn Fn(&Ledger) -> bool + Send + Sync>;

/// The answer of [`Store::admit`].
#[derive(Debug, Clone, PartialEq)]
pub enum Admission {
    /// Inserted as a new queued entry with this id.
    Inserted(i64),
    /// The team has an entry with the same bytes: (its id, its status).
    /// Nothing was inserted.
    Duplicate(i64, String),
    /// The caller's rule refused it on this ledger. Nothing was inserted.
    Declined(Ledger),
}

/// Who takes a job, and for how long without renewal.
#[derive(Debug, Clone, PartialEq)]
pub struct Lease {
    /// The worker's name (host, process, thread: `worker_name`).
    pub worker: String,
    /// How long a lease lasts without renewal, in seconds.
    pub seconds: i64,
}

/// A worker's name, unique among the live workers of every host: the host
/// name, the process id, a number within the process and 32 random bits.
pub fn worker_name(n: usize) -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "host".into());
    let mut b = [0u8; 4];
    let _ = getrandom::fill(&mut b);
    format!(
        "{host}:{}:{n}:{}",
        std::process::id(),
        stepsim_contract::digest::hex(&b)
    )
}

/// The challenge's storage. Every method is one transaction; every method
/// takes `&self`, so one store serves every handler and worker of a
/// process at once (each backend keeps its own connections).
#[async_trait::async_trait]
pub trait Store: Send + Sync + std::fmt::Debug {
    /// Where the store is (a file, or a PostgreSQL address without its
    /// password): for messages.
    fn describe(&self) -> String;
    /// A setting (`run`, `quota`, `revealed`, ...).
    async fn meta(&self, key: &str) -> Result<Option<String>, StoreError>;
    /// Every setting.
    async fn all_meta(&self) -> Result<HashMap<String, String>, StoreError>;
    /// Sets a setting.
    async fn set_meta(&self, key: &str, value: &str) -> Result<(), StoreError>;
    /// Adds a team with the SHA-256 of its token.
    async fn add_team(&self, name: &str, token_sha256: &str, now_s: i64)
    -> Result<i64, StoreError>;
    /// A team by name.
    async fn team_by_name(&self, name: &str) -> Result<Option<Team>, StoreError>;
    /// The team whose (unrevoked) token has this SHA-256.
    async fn team_by_token(&self, token_sha256: &str) -> Result<Option<Team>, StoreError>;
    /// Replaces a team's token hash (and un-revokes it).
    async fn set_token(&self, team_id: i64, token_sha256: &str) -> Result<(), StoreError>;
    /// Revokes a team's token.
    async fn revoke(&self, team_id: i64) -> Result<(), StoreError>;
    /// Every team, by id.
    async fn teams(&self) -> Result<Vec<Team>, StoreError>;
    /// Admits an upload in one transaction that holds the team: reads the
    /// `Ledger` (settings, the team's uploads since `since_s`), answers
    /// `Admission::Duplicate` when the team has an entry with these
    /// bytes, `Admission::Declined` when `accept` says no, and otherwise
    /// inserts a queued entry. Two admissions of one team never both pass
    /// a quota, on any number of hosts.
    async fn admit(
        &self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
        since_s: i64,
        accept: Rule,
    ) -> Result<Admission, StoreError>;
    /// Queues an upload with no checks (tests, and imports by the
    /// organisers); returns its id.
    async fn insert_submission(
        &self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
    ) -> Result<i64, StoreError>;
    /// One submission.
    async fn submission(&self, id: i64) -> Result<Option<Submission>, StoreError>;
    /// A team's submissions, newest first.
    async fn submissions_of(&self, team_id: i64) -> Result<Vec<Submission>, StoreError>;
    /// Every submission, by id.
    async fn all_submissions(&self) -> Result<Vec<Submission>, StoreError>;
    /// Creation times of a team's accepted submissions since `since_s`.
    async fn accepted_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError>;
    /// Records a refused upload (format check).
    async fn add_format_failure(
        &self,
        team_id: i64,
        error: &str,
        now_s: i64,
    ) -> Result<(), StoreError>;
    /// Times of a team's refused uploads since `since_s`.
    async fn format_failures_since(
        &self,
        team_id: i64,
        since_s: i64,
    ) -> Result<Vec<i64>, StoreError>;
    /// The newest `limit` refused uploads, of one team or (`None`) of all,
    /// newest first.
    async fn format_failures(
        &self,
        team_id: Option<i64>,
        limit: usize,
    ) -> Result<Vec<FormatFailure>, StoreError>;
    /// Entries by state and the count of refused uploads.
    async fn queue_counts(&self) -> Result<QueueCounts, StoreError>;
    /// How many uploads of each team the format check refused, all time
    /// (team id, count), by team id.
    async fn format_failure_counts(&self) -> Result<Vec<(i64, u64)>, StoreError>;
    /// Takes the oldest job that is queued, or whose lease ran out before
    /// `now_s`, of a team with no other job under a live lease, and leases
    /// it to `lease.worker` until `now_s + lease.seconds`. Concurrent
    /// claims (any number of processes) never take one job twice.
    async fn claim_job(&self, lease: &Lease, now_s: i64) -> Result<Option<Submission>, StoreError>;
    /// Extends the lease of job `id` held by `lease.worker` to
    /// `now_s + lease.seconds`; false when the worker no longer holds it
    /// (it ran out and another worker took the job).
    async fn renew_lease(&self, id: i64, lease: &Lease, now_s: i64) -> Result<bool, StoreError>;
    /// Ends job `id` held by `worker`: `scored` with its feedback, or
    /// `refused` with a message. Returns false, recording nothing, when
    /// `worker` no longer holds the job.
    async fn finish_job(
        &self,
        id: i64,
        worker: &str,
        result: Result<(String, Option<String>), String>,
        scorer_version: &str,
        now_s: i64,
    ) -> Result<bool, StoreError>;
    /// Puts every job left `scoring` back in the queue, leases or not;
    /// returns how many. No command calls it (leases do this job); the
    /// tests use it to make a crash's state.
    async fn requeue_interrupted(&self) -> Result<usize, StoreError>;
    /// Sets a team's role.
    async fn set_role(&self, team_id: i64, role: Role) -> Result<(), StoreError>;
    /// Makes `ids` the team's final entries (and no other), unless the
    /// challenge is closed (setting `closed`), in one transaction; returns
    /// false, changing nothing, when closed. The caller checks the ids
    /// (`challenge::choose_final_entries`). Ids of other teams are
    /// left alone.
    async fn set_final_entries(&self, team_id: i64, ids: &[i64]) -> Result<bool, StoreError>;
    /// The entries a team chose as final, by id (empty: none chosen).
    async fn final_entries(&self, team_id: i64) -> Result<Vec<i64>, StoreError>;
    /// Queues again every scored entry that has no score by
    /// `scorer_version`; returns how many. Their previous scores stay shown
    /// until the new ones are recorded, and stay in [`Store::scores_of`].
    async fn rescore(&self, scorer_version: &str) -> Result<usize, StoreError>;
    /// Every score of an entry, the most recently recorded first.
    async fn scores_of(&self, submission_id: i64) -> Result<Vec<Score>, StoreError>;
}

/// Where a challenge's store is: a SQLite file, or a PostgreSQL database
/// (`postgres://user@host:port/db` or `postgresql://…`, libpq's URL form).
#[derive(Clone, PartialEq, Eq)]
pub enum StoreUrl {
    /// A SQLite file (`sqlite:PATH`, or the state directory's
    /// `challenge.db`).
    Sqlite(PathBuf),
    /// A PostgreSQL connection URL.
    Postgres(String),
}

impl std::fmt::Debug for StoreUrl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.shown())
    }
}

impl StoreUrl {
    /// Reads `--store`'s value: `postgres://…`, `postgresql://…`,
    /// `sqlite:PATH`; anything else is refused with the forms it takes.
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        if t.starts_with("postgres://") || t.starts_with("postgresql://") {
            Ok(Self::Postgres(t.to_string()))
        } else if let Some(p) = t.strip_prefix("sqlite:") {
            if p.is_empty() {
                return Err("--store sqlite: needs a file (sqlite:PATH)".into());
            }
            Ok(Self::Sqlite(PathBuf::from(p)))
        } else {
            // The value is not repeated: it may hold a password.
            Err(
                "--store: not a store address; give postgres://USER@HOST:PORT/DATABASE or \
                 sqlite:PATH"
                    .into(),
            )
        }
    }

    /// The address as messages show it: a PostgreSQL password replaced by
    /// `***`.
    pub fn shown(&self) -> String {
        match self {
            Self::Sqlite(p) => format!("sqlite:{}", p.display()),
            Self::Postgres(u) => hide_password(u),
        }
    }
}

/// A PostgreSQL URL with its password (if any: `user:PASSWORD@`, or a
/// `password=` parameter) replaced by `***`.
pub fn hide_password(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    let (rest, query) = match rest.split_once('?') {
        Some((r, q)) => (r, Some(q)),
        None => (rest, None),
    };
    let rest = match rest.rsplit_once('@') {
        Some((auth, host)) => match auth.split_once(':') {
            Some((user, _)) => format!("{user}:***@{host}"),
            None => format!("{auth}@{host}"),
        },
        None => rest.to_string(),
    };
    let query = query.map(|q| {
        q.split('&')
            .map(|kv| match kv.split_once('=') {
                Some((k, _)) if k.eq_ignore_ascii_case("password") => format!("{k}=***"),
                _ => kv.to_string(),
            })
            .collect::<Vec<_>>()
            .join("&")
    });
    match query {
        Some(q) => format!("{scheme}://{rest}?{q}"),
        None => format!("{scheme}://{rest}"),
    }
}

/// Opens (creating the schema when `create`) the store at `url`.
pub async fn open(url: &StoreUrl, create: bool) -> Result<std::sync::Arc<dyn Store>, StoreError> {
    Ok(match url {
        StoreUrl::Sqlite(p) => std::sync::Arc::new(SqliteStore::open(p, create).await?),
        StoreUrl::Postgres(u) => std::sync::Arc::new(PgStore::open(u, create).await?),
    })
}

/// Name of the SQLite database in a state directory.
pub const DB_FILE: &str = "challenge.db";

/// The file in a state directory that names its store when it is not the
/// directory's own SQLite file (`challenge init --store URL` writes it,
/// readable by its owner only: the URL may hold a password).
pub const STORE_FILE: &str = "store.url";

/// The store a state directory names: `--store` when given, else its
/// [`STORE_FILE`], else its `challenge.db`.
pub fn url_of_state(dir: &Path, given: Option<&StoreUrl>) -> Result<StoreUrl, String> {
    if let Some(u) = given {
        return Ok(u.clone());
    }
    let file = dir.join(STORE_FILE);
    match std::fs::read_to_string(&file) {
        Ok(text) => StoreUrl::parse(text.lines().next().unwrap_or(""))
            .map_err(|e| format!("{}: {e}", file.display())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Ok(StoreUrl::Sqlite(dir.join(DB_FILE)))
        }
        Err(e) => Err(format!("{}: {e}", file.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn store_urls_are_read_and_shown_without_passwords() {
        assert_eq!(
            StoreUrl::parse("postgres://u:secret@db:5432/c").unwrap(),
            StoreUrl::Postgres("postgres://u:secret@db:5432/c".into())
        );
        assert_eq!(
            StoreUrl::parse("postgres://u:secret@db:5432/c")
                .unwrap()
                .shown(),
            "postgres://u:***@db:5432/c"
        );
        assert_eq!(
            StoreUrl::parse("postgresql://u@h/c").unwrap().shown(),
            "postgresql://u@h/c"
        );
        assert_eq!(
            hide_password("postgres://u@h/c?sslmode=disable&password=pw2&x=1"),
            "postgres://u@h/c?sslmode=disable&password=***&x=1"
        );
        assert_eq!(
            hide_password("postgres://u:p@ss@h/c?PASSWORD=z"),
            "postgres://u:***@h/c?PASSWORD=***"
        );
        assert_eq!(
            StoreUrl::parse("sqlite:/x/c.db").unwrap(),
            StoreUrl::Sqlite("/x/c.db".into())
        );
        for bad in [
            "",
            "sqlite:",
            "mysql://h/d",
            "/x/c.db",
            "postgres:/u:secret@h",
        ] {
            let e = StoreUrl::parse(bad).unwrap_err();
            assert!(e.contains("--store") && !e.contains("secret"), "{bad}: {e}");
        }
    }
}
