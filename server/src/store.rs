//! The challenge's state behind one trait ([`Store`]), so that PostgreSQL
//! can be a second backend; [`SqliteStore`] is the default: one SQLite file
//! in WAL mode whose schema migrations ship in the binary ([`MIGRATIONS`]).
//!
//! Times are Unix seconds (UTC). A submission moves
//! `queued → scoring → scored | refused` exactly once; a server that stops
//! while scoring puts its `scoring` rows back to `queued` when it starts
//! ([`Store::requeue_interrupted`]), and a job's result is written in one
//! transaction, so every accepted submission is scored once.

use rusqlite::{Connection, OptionalExtension, params};
use std::path::Path;

/// What can go wrong in the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database refused an operation.
    #[error("database {path}: {message}")]
    Db {
        /// The database file.
        path: String,
        /// What SQLite said.
        message: String,
    },
    /// The database was made by a newer stepsim.
    #[error("database {path} has schema version {found}; this stepsim knows up to {known}")]
    TooNew {
        /// The database file.
        path: String,
        /// Its version.
        found: i64,
        /// The newest this binary knows.
        known: i64,
    },
}

/// Schema migrations, applied in order; `PRAGMA user_version` counts those
/// applied. Never edit one that has shipped: add another.
pub const MIGRATIONS: &[&str] = &[
    r#"
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE teams (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    token_sha256 TEXT NOT NULL UNIQUE,
    revoked INTEGER NOT NULL DEFAULT 0,
    created_s INTEGER NOT NULL
);
CREATE TABLE submissions (
    id INTEGER PRIMARY KEY,
    team_id INTEGER NOT NULL REFERENCES teams(id),
    sha256 TEXT NOT NULL,
    bytes INTEGER NOT NULL,
    created_s INTEGER NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('queued', 'scoring', 'scored', 'refused')),
    started_s INTEGER,
    finished_s INTEGER,
    error TEXT,
    public_json TEXT,
    holdout_json TEXT,
    scorer_version TEXT,
    n_scorings INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX submissions_team ON submissions(team_id, created_s);
CREATE INDEX submissions_status ON submissions(status, id);
CREATE TABLE format_failures (
    id INTEGER PRIMARY KEY,
    team_id INTEGER NOT NULL REFERENCES teams(id),
    created_s INTEGER NOT NULL,
    error TEXT NOT NULL
);
CREATE INDEX format_failures_team ON format_failures(team_id, created_s);
"#,
    r#"
ALTER TABLE teams ADD COLUMN role TEXT NOT NULL DEFAULT 'participant'
    CHECK (role IN ('participant', 'organisers', 'baseline'));
ALTER TABLE submissions ADD COLUMN final INTEGER NOT NULL DEFAULT 0;
CREATE TABLE scores (
    submission_id INTEGER NOT NULL REFERENCES submissions(id),
    scorer_version TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('scored', 'refused')),
    finished_s INTEGER NOT NULL,
    error TEXT,
    public_json TEXT,
    holdout_json TEXT,
    n_scorings INTEGER NOT NULL DEFAULT 1,
    PRIMARY KEY (submission_id, scorer_version)
);
INSERT INTO scores (submission_id, scorer_version, status, finished_s, error, public_json,
                    holdout_json, n_scorings)
    SELECT id, COALESCE(scorer_version, 'unknown'), status, COALESCE(finished_s, 0), error,
           public_json, holdout_json, n_scorings
    FROM submissions WHERE status IN ('scored', 'refused');
"#,
];

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
    /// The scorer that made it ([`crate::worker::SCORER_VERSION`]).
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
    /// The public feedback (JSON of `stepsim_harness::part::PublicFeedback`).
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

/// The challenge's storage. Every method is one transaction.
pub trait Store: Send {
    /// A setting (`run`, `quota`, `revealed`, ...).
    fn meta(&self, key: &str) -> Result<Option<String>, StoreError>;
    /// Sets a setting.
    fn set_meta(&mut self, key: &str, value: &str) -> Result<(), StoreError>;
    /// Adds a team with the SHA-256 of its token.
    fn add_team(&mut self, name: &str, token_sha256: &str, now_s: i64) -> Result<i64, StoreError>;
    /// A team by name.
    fn team_by_name(&self, name: &str) -> Result<Option<Team>, StoreError>;
    /// The team whose (unrevoked) token has this SHA-256.
    fn team_by_token(&self, token_sha256: &str) -> Result<Option<Team>, StoreError>;
    /// Replaces a team's token hash (and un-revokes it).
    fn set_token(&mut self, team_id: i64, token_sha256: &str) -> Result<(), StoreError>;
    /// Revokes a team's token.
    fn revoke(&mut self, team_id: i64) -> Result<(), StoreError>;
    /// Every team, by id.
    fn teams(&self) -> Result<Vec<Team>, StoreError>;
    /// Queues an accepted upload; returns its id.
    fn insert_submission(
        &mut self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
    ) -> Result<i64, StoreError>;
    /// A team's entry with the same bytes, if any.
    fn find_duplicate(&self, team_id: i64, sha256: &str) -> Result<Option<i64>, StoreError>;
    /// One submission.
    fn submission(&self, id: i64) -> Result<Option<Submission>, StoreError>;
    /// A team's submissions, newest first.
    fn submissions_of(&self, team_id: i64) -> Result<Vec<Submission>, StoreError>;
    /// Every submission, by id.
    fn all_submissions(&self) -> Result<Vec<Submission>, StoreError>;
    /// Creation times of a team's accepted submissions since `since_s`.
    fn accepted_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError>;
    /// Records a refused upload (format check); returns nothing.
    fn add_format_failure(
        &mut self,
        team_id: i64,
        error: &str,
        now_s: i64,
    ) -> Result<(), StoreError>;
    /// Times of a team's refused uploads since `since_s`.
    fn format_failures_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError>;
    /// The newest `limit` refused uploads, of one team or (`None`) of all,
    /// newest first.
    fn format_failures(
        &self,
        team_id: Option<i64>,
        limit: usize,
    ) -> Result<Vec<FormatFailure>, StoreError>;
    /// Entries by state and the count of refused uploads.
    fn queue_counts(&self) -> Result<QueueCounts, StoreError>;
    /// How many uploads of each team the format check refused, all time
    /// (team id, count), by team id.
    fn format_failure_counts(&self) -> Result<Vec<(i64, u64)>, StoreError>;
    /// Takes the oldest queued job of a team that has none scoring.
    fn claim_job(&mut self, now_s: i64) -> Result<Option<Submission>, StoreError>;
    /// Ends a job: `scored` with its feedback, or `refused` with a message.
    fn finish_job(
        &mut self,
        id: i64,
        result: Result<(String, Option<String>), String>,
        scorer_version: &str,
        now_s: i64,
    ) -> Result<(), StoreError>;
    /// Puts jobs left `scoring` by a stopped server back in the queue.
    fn requeue_interrupted(&mut self) -> Result<usize, StoreError>;
    /// Sets a team's role.
    fn set_role(&mut self, team_id: i64, role: Role) -> Result<(), StoreError>;
    /// Makes `ids` the team's final entries (and no other); the caller
    /// checks them ([`crate::challenge::choose_final_entries`]). Ids of
    /// other teams are left alone.
    fn set_final_entries(&mut self, team_id: i64, ids: &[i64]) -> Result<(), StoreError>;
    /// The entries a team chose as final, by id (empty: none chosen).
    fn final_entries(&self, team_id: i64) -> Result<Vec<i64>, StoreError>;
    /// Queues again every scored entry that has no score by
    /// `scorer_version`; returns how many. Their previous scores stay shown
    /// until the new ones are recorded, and stay in [`Store::scores_of`].
    fn rescore(&mut self, scorer_version: &str) -> Result<usize, StoreError>;
    /// Every score of an entry, the most recently recorded first.
    fn scores_of(&self, submission_id: i64) -> Result<Vec<Score>, StoreError>;
}

/// [`Store`] on one SQLite file.
pub struct SqliteStore {
    conn: Connection,
    path: String,
}

impl std::fmt::Debug for SqliteStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SqliteStore({})", self.path)
    }
}

const SUBMISSION_COLUMNS: &str = "id, team_id, sha256, bytes, created_s, status, error, \
                                  public_json, holdout_json, n_scorings, scorer_version, final";

fn row_submission(r: &rusqlite::Row<'_>) -> rusqlite::Result<Submission> {
    Ok(Submission {
        id: r.get(0)?,
        team_id: r.get(1)?,
        sha256: r.get(2)?,
        bytes: r.get(3)?,
        created_s: r.get(4)?,
        status: r.get(5)?,
        error: r.get(6)?,
        public_json: r.get(7)?,
        holdout_json: r.get(8)?,
        n_scorings: r.get(9)?,
        scorer_version: r.get(10)?,
        final_choice: r.get::<_, i64>(11)? != 0,
    })
}

const SCORE_COLUMNS: &str = "submission_id, scorer_version, status, finished_s, error, \
                             public_json, holdout_json, n_scorings";

fn row_score(r: &rusqlite::Row<'_>) -> rusqlite::Result<Score> {
    Ok(Score {
        submission_id: r.get(0)?,
        scorer_version: r.get(1)?,
        status: r.get(2)?,
        finished_s: r.get(3)?,
        error: r.get(4)?,
        public_json: r.get(5)?,
        holdout_json: r.get(6)?,
        n_scorings: r.get(7)?,
    })
}

fn row_team(r: &rusqlite::Row<'_>) -> rusqlite::Result<Team> {
    Ok(Team {
        id: r.get(0)?,
        name: r.get(1)?,
        revoked: r.get::<_, i64>(2)? != 0,
        role: Role::from_name(&r.get::<_, String>(3)?).unwrap_or_default(),
    })
}

impl SqliteStore {
    /// Opens (creating when `create`) the database and applies the
    /// migrations it lacks.
    pub fn open(path: &Path, create: bool) -> Result<Self, StoreError> {
        use rusqlite::OpenFlags;
        let name = path.display().to_string();
        let db = |e: rusqlite::Error| StoreError::Db {
            path: name.clone(),
            message: e.to_string(),
        };
        let mut flags = OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        if create {
            flags |= OpenFlags::SQLITE_OPEN_CREATE;
        }
        let conn = Connection::open_with_flags(path, flags).map_err(db)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))
            .map_err(db)?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(db)?;
        conn.pragma_update(None, "synchronous", "FULL")
            .map_err(db)?;
        conn.pragma_update(None, "foreign_keys", "ON").map_err(db)?;
        let mut store = Self { conn, path: name };
        store.migrate()?;
        Ok(store)
    }

    fn err(&self, e: rusqlite::Error) -> StoreError {
        StoreError::Db {
            path: self.path.clone(),
            message: e.to_string(),
        }
    }

    fn migrate(&mut self) -> Result<(), StoreError> {
        let version: i64 = self
            .conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(|e| self.err(e))?;
        let known = MIGRATIONS.len() as i64;
        if version > known {
            return Err(StoreError::TooNew {
                path: self.path.clone(),
                found: version,
                known,
            });
        }
        let path = self.path.clone();
        let db = |e: rusqlite::Error| StoreError::Db {
            path: path.clone(),
            message: e.to_string(),
        };
        for (i, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
            let tx = self.conn.transaction().map_err(db)?;
            tx.execute_batch(sql).map_err(db)?;
            tx.pragma_update(None, "user_version", (i + 1) as i64)
                .map_err(db)?;
            tx.commit().map_err(db)?;
        }
        Ok(())
    }

    fn times(&self, sql: &str, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        let mut st = self.conn.prepare_cached(sql).map_err(|e| self.err(e))?;
        let rows = st
            .query_map(params![team_id, since_s], |r| r.get(0))
            .and_then(|it| it.collect::<rusqlite::Result<Vec<i64>>>());
        rows.map_err(|e| self.err(e))
    }

    fn submissions_where(
        &self,
        clause: &str,
        args: &[&dyn rusqlite::ToSql],
    ) -> Result<Vec<Submission>, StoreError> {
        let sql = format!("SELECT {SUBMISSION_COLUMNS} FROM submissions {clause}");
        let mut st = self.conn.prepare_cached(&sql).map_err(|e| self.err(e))?;
        let rows = st
            .query_map(args, row_submission)
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>());
        rows.map_err(|e| self.err(e))
    }
}

impl Store for SqliteStore {
    fn meta(&self, key: &str) -> Result<Option<String>, StoreError> {
        self.conn
            .query_row("SELECT value FROM meta WHERE key = ?1", [key], |r| r.get(0))
            .optional()
            .map_err(|e| self.err(e))
    }

    fn set_meta(&mut self, key: &str, value: &str) -> Result<(), StoreError> {
        self.conn
            .execute(
                "INSERT INTO meta (key, value) VALUES (?1, ?2) \
                 ON CONFLICT(key) DO UPDATE SET value = excluded.value",
                [key, value],
            )
            .map(drop)
            .map_err(|e| self.err(e))
    }

    fn add_team(&mut self, name: &str, token_sha256: &str, now_s: i64) -> Result<i64, StoreError> {
        self.conn
            .execute(
                "INSERT INTO teams (name, token_sha256, created_s) VALUES (?1, ?2, ?3)",
                params![name, token_sha256, now_s],
            )
            .map_err(|e| self.err(e))?;
        Ok(self.conn.last_insert_rowid())
    }

    fn team_by_name(&self, name: &str) -> Result<Option<Team>, StoreError> {
        self.conn
            .query_row(
                "SELECT id, name, revoked, role FROM teams WHERE name = ?1",
                [name],
                row_team,
            )
            .optional()
            .map_err(|e| self.err(e))
    }

    fn team_by_token(&self, token_sha256: &str) -> Result<Option<Team>, StoreError> {
        self.conn
            .query_row(
                "SELECT id, name, revoked, role FROM teams WHERE token_sha256 = ?1 AND revoked = 0",
                [token_sha256],
                row_team,
            )
            .optional()
            .map_err(|e| self.err(e))
    }

    fn set_token(&mut self, team_id: i64, token_sha256: &str) -> Result<(), StoreError> {
        self.conn
            .execute(
                "UPDATE teams SET token_sha256 = ?2, revoked = 0 WHERE id = ?1",
                params![team_id, token_sha256],
            )
            .map(drop)
            .map_err(|e| self.err(e))
    }

    fn revoke(&mut self, team_id: i64) -> Result<(), StoreError> {
        self.conn
            .execute("UPDATE teams SET revoked = 1 WHERE id = ?1", [team_id])
            .map(drop)
            .map_err(|e| self.err(e))
    }

    fn teams(&self) -> Result<Vec<Team>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached("SELECT id, name, revoked, role FROM teams ORDER BY id")
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([], row_team)
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>());
        rows.map_err(|e| self.err(e))
    }

    fn insert_submission(
        &mut self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
    ) -> Result<i64, StoreError> {
        self.conn
            .execute(
                "INSERT INTO submissions (team_id, sha256, bytes, created_s, status) \
                 VALUES (?1, ?2, ?3, ?4, 'queued')",
                params![team_id, sha256, bytes, now_s],
            )
            .map_err(|e| self.err(e))?;
        Ok(self.conn.last_insert_rowid())
    }

    fn find_duplicate(&self, team_id: i64, sha256: &str) -> Result<Option<i64>, StoreError> {
        self.conn
            .query_row(
                "SELECT id FROM submissions WHERE team_id = ?1 AND sha256 = ?2 ORDER BY id LIMIT 1",
                params![team_id, sha256],
                |r| r.get(0),
            )
            .optional()
            .map_err(|e| self.err(e))
    }

    fn submission(&self, id: i64) -> Result<Option<Submission>, StoreError> {
        Ok(self
            .submissions_where("WHERE id = ?1", &[&id])?
            .into_iter()
            .next())
    }

    fn submissions_of(&self, team_id: i64) -> Result<Vec<Submission>, StoreError> {
        self.submissions_where(
            "WHERE team_id = ?1 ORDER BY id DESC",
            &[&team_id as &dyn rusqlite::ToSql],
        )
    }

    fn all_submissions(&self) -> Result<Vec<Submission>, StoreError> {
        self.submissions_where("ORDER BY id", &[])
    }

    fn accepted_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        self.times(
            "SELECT created_s FROM submissions WHERE team_id = ?1 AND created_s > ?2 \
             ORDER BY created_s",
            team_id,
            since_s,
        )
    }

    fn add_format_failure(
        &mut self,
        team_id: i64,
        error: &str,
        now_s: i64,
    ) -> Result<(), StoreError> {
        self.conn
            .execute(
                "INSERT INTO format_failures (team_id, created_s, error) VALUES (?1, ?2, ?3)",
                params![team_id, now_s, error],
            )
            .map(drop)
            .map_err(|e| self.err(e))
    }

    fn format_failures_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        self.times(
            "SELECT created_s FROM format_failures WHERE team_id = ?1 AND created_s > ?2 \
             ORDER BY created_s",
            team_id,
            since_s,
        )
    }

    fn format_failures(
        &self,
        team_id: Option<i64>,
        limit: usize,
    ) -> Result<Vec<FormatFailure>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT team_id, created_s, error FROM format_failures \
                 WHERE ?1 IS NULL OR team_id = ?1 ORDER BY created_s DESC, id DESC LIMIT ?2",
            )
            .map_err(|e| self.err(e))?;
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let rows = st
            .query_map(params![team_id, limit], |r| {
                Ok(FormatFailure {
                    team_id: r.get(0)?,
                    created_s: r.get(1)?,
                    error: r.get(2)?,
                })
            })
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>());
        rows.map_err(|e| self.err(e))
    }

    fn format_failure_counts(&self) -> Result<Vec<(i64, u64)>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT team_id, COUNT(*) FROM format_failures GROUP BY team_id ORDER BY team_id",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([], |r| {
                Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?.max(0) as u64))
            })
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>());
        rows.map_err(|e| self.err(e))
    }

    fn queue_counts(&self) -> Result<QueueCounts, StoreError> {
        let mut c = QueueCounts::default();
        let mut st = self
            .conn
            .prepare_cached("SELECT status, COUNT(*) FROM submissions GROUP BY status")
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)?)))
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(e))?;
        for (status, n) in rows {
            let n = n.max(0) as u64;
            match status.as_str() {
                "queued" => c.queued = n,
                "scoring" => c.scoring = n,
                "scored" => c.scored = n,
                "refused" => c.refused = n,
                _ => {}
            }
        }
        c.format_refusals = self
            .conn
            .query_row("SELECT COUNT(*) FROM format_failures", [], |r| {
                r.get::<_, i64>(0)
            })
            .map_err(|e| self.err(e))?
            .max(0) as u64;
        Ok(c)
    }

    fn claim_job(&mut self, now_s: i64) -> Result<Option<Submission>, StoreError> {
        let id: Option<i64> = self
            .conn
            .query_row(
                "UPDATE submissions SET status = 'scoring', started_s = ?1 WHERE id = (\
                   SELECT id FROM submissions WHERE status = 'queued' AND team_id NOT IN \
                   (SELECT team_id FROM submissions WHERE status = 'scoring') \
                   ORDER BY id LIMIT 1) RETURNING id",
                [now_s],
                |r| r.get(0),
            )
            .optional()
            .map_err(|e| self.err(e))?;
        match id {
            Some(id) => self.submission(id),
            None => Ok(None),
        }
    }

    fn finish_job(
        &mut self,
        id: i64,
        result: Result<(String, Option<String>), String>,
        scorer_version: &str,
        now_s: i64,
    ) -> Result<(), StoreError> {
        let (status, error, public, holdout) = match result {
            Ok((p, h)) => ("scored", None, Some(p), h),
            Err(e) => ("refused", Some(e), None, None),
        };
        let path = self.path.clone();
        let db = |e: rusqlite::Error| StoreError::Db {
            path: path.clone(),
            message: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(db)?;
        let changed = tx
            .execute(
                "UPDATE submissions SET status = ?2, error = ?3, public_json = ?4, \
                 holdout_json = ?5, scorer_version = ?6, finished_s = ?7, \
                 n_scorings = n_scorings + 1 WHERE id = ?1 AND status = 'scoring'",
                params![id, status, error, public, holdout, scorer_version, now_s],
            )
            .map_err(db)?;
        if changed == 1 {
            tx.execute(
                "INSERT INTO scores (submission_id, scorer_version, status, finished_s, error, \
                 public_json, holdout_json) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7) \
                 ON CONFLICT (submission_id, scorer_version) DO UPDATE SET \
                 status = excluded.status, finished_s = excluded.finished_s, \
                 error = excluded.error, public_json = excluded.public_json, \
                 holdout_json = excluded.holdout_json, n_scorings = scores.n_scorings + 1",
                params![id, scorer_version, status, now_s, error, public, holdout],
            )
            .map_err(db)?;
        }
        tx.commit().map_err(db)
    }

    fn requeue_interrupted(&mut self) -> Result<usize, StoreError> {
        self.conn
            .execute(
                "UPDATE submissions SET status = 'queued', started_s = NULL \
                 WHERE status = 'scoring'",
                [],
            )
            .map_err(|e| self.err(e))
    }

    fn set_role(&mut self, team_id: i64, role: Role) -> Result<(), StoreError> {
        self.conn
            .execute(
                "UPDATE teams SET role = ?2 WHERE id = ?1",
                params![team_id, role.name()],
            )
            .map(drop)
            .map_err(|e| self.err(e))
    }

    fn set_final_entries(&mut self, team_id: i64, ids: &[i64]) -> Result<(), StoreError> {
        let path = self.path.clone();
        let db = |e: rusqlite::Error| StoreError::Db {
            path: path.clone(),
            message: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(db)?;
        tx.execute(
            "UPDATE submissions SET final = 0 WHERE team_id = ?1 AND final = 1",
            [team_id],
        )
        .map_err(db)?;
        for id in ids {
            tx.execute(
                "UPDATE submissions SET final = 1 WHERE team_id = ?1 AND id = ?2",
                params![team_id, id],
            )
            .map_err(db)?;
        }
        tx.commit().map_err(db)
    }

    fn final_entries(&self, team_id: i64) -> Result<Vec<i64>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT id FROM submissions WHERE team_id = ?1 AND final = 1 ORDER BY id",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([team_id], |r| r.get(0))
            .and_then(|it| it.collect::<rusqlite::Result<Vec<i64>>>());
        rows.map_err(|e| self.err(e))
    }

    fn rescore(&mut self, scorer_version: &str) -> Result<usize, StoreError> {
        self.conn
            .execute(
                "UPDATE submissions SET status = 'queued', started_s = NULL \
                 WHERE status = 'scored' AND NOT EXISTS (SELECT 1 FROM scores \
                 WHERE scores.submission_id = submissions.id AND scores.scorer_version = ?1)",
                [scorer_version],
            )
            .map_err(|e| self.err(e))
    }

    fn scores_of(&self, submission_id: i64) -> Result<Vec<Score>, StoreError> {
        let sql = format!(
            "SELECT {SCORE_COLUMNS} FROM scores WHERE submission_id = ?1 \
             ORDER BY rowid DESC"
        );
        let mut st = self.conn.prepare_cached(&sql).map_err(|e| self.err(e))?;
        let rows = st
            .query_map([submission_id], row_score)
            .and_then(|it| it.collect::<rusqlite::Result<Vec<_>>>());
        rows.map_err(|e| self.err(e))
    }
}
