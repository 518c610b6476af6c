//! [`Store`] on one SQLite file (WAL mode; schema migrations ship in the
//! binary, [`MIGRATIONS`]). One connection, used on tokio's blocking
//! threads: a database locked by another process (an organiser's
//! `sqlite3`, a backup) waits out the busy timeout there, never on the
//! threads that answer requests.

use super::{
    Admission, FormatFailure, Lease, Ledger, QueueCounts, Role, Rule, Score, Store, StoreError,
    Submission, Team,
};
use rusqlite::{Connection, OptionalExtension, params};
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

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
    r#"
ALTER TABLE submissions ADD COLUMN lease_until_s INTEGER;
ALTER TABLE submissions ADD COLUMN worker TEXT;
"#,
];

/// The connection and its file's name: what the blocking threads use.
struct Conn {
    conn: Connection,
    path: String,
}

const SUBMISSION_COLUMNS: &str = "id, team_id, sha256, bytes, created_s, status, error, \
                                  public_json, holdout_json, n_scorings, scorer_version, final, worker";

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
        worker: r.get(12)?,
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

/// Turns SQLite's errors on the database at `path` into the store's.
fn db_error(path: &str) -> impl Fn(rusqlite::Error) -> StoreError + Copy + '_ {
    move |e| StoreError::Db {
        path: path.to_string(),
        message: e.to_string(),
    }
}

fn meta_of(conn: &Connection) -> rusqlite::Result<HashMap<String, String>> {
    let mut st = conn.prepare_cached("SELECT key, value FROM meta")?;
    let rows = st.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?;
    rows.collect()
}

fn row_team(r: &rusqlite::Row<'_>) -> rusqlite::Result<Team> {
    Ok(Team {
        id: r.get(0)?,
        name: r.get(1)?,
        revoked: r.get::<_, i64>(2)? != 0,
        role: Role::from_name(&r.get::<_, String>(3)?).unwrap_or_default(),
    })
}

impl Conn {
    fn open(path: &Path, create: bool) -> Result<Self, StoreError> {
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
        db_error(&self.path)(e)
    }

    fn migrate(&mut self) -> Result<(), StoreError> {
        let db = db_error(&self.path);
        let known = MIGRATIONS.len() as i64;
        // The version is read inside the write lock: two processes opening
        // an old database at once (a `serve` and a `worker` after an
        // upgrade) apply each migration once, the second finding it done.
        let tx = self
            .conn
            .transaction_with_behavior(rusqlite::TransactionBehavior::Immediate)
            .map_err(db)?;
        let version: i64 = tx
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(db)?;
        if version > known {
            return Err(StoreError::TooNew {
                path: self.path.clone(),
                found: version,
                known,
            });
        }
        for (i, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
            tx.execute_batch(sql).map_err(db)?;
            tx.pragma_update(None, "user_version", (i + 1) as i64)
                .map_err(db)?;
        }
        tx.commit().map_err(db)
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

impl Conn {
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

    fn claim_job(&mut self, lease: &Lease, now_s: i64) -> Result<Option<Submission>, StoreError> {
        // One statement: SQLite runs one writer at a time, so two claims
        // (of any processes) never take one job.
        let id: Option<i64> = self
            .conn
            .query_row(
                "UPDATE submissions SET status = 'scoring', started_s = ?1, worker = ?2, \
                 lease_until_s = ?1 + ?3 WHERE id = (\
                   SELECT s.id FROM submissions s WHERE (s.status = 'queued' OR \
                   (s.status = 'scoring' AND COALESCE(s.lease_until_s, 0) < ?1)) \
                   AND NOT EXISTS (SELECT 1 FROM submissions o WHERE o.team_id = s.team_id \
                   AND o.id <> s.id AND o.status = 'scoring' \
                   AND COALESCE(o.lease_until_s, 0) >= ?1) \
                   ORDER BY s.id LIMIT 1) RETURNING id",
                params![now_s, lease.worker, lease.seconds],
                |r| r.get(0),
            )
            .optional()
            .map_err(|e| self.err(e))?;
        match id {
            Some(id) => self.submission(id),
            None => Ok(None),
        }
    }

    fn renew_lease(&mut self, id: i64, lease: &Lease, now_s: i64) -> Result<bool, StoreError> {
        self.conn
            .execute(
                "UPDATE submissions SET lease_until_s = ?3 + ?4 \
                 WHERE id = ?1 AND status = 'scoring' AND worker = ?2",
                params![id, lease.worker, now_s, lease.seconds],
            )
            .map(|n| n == 1)
            .map_err(|e| self.err(e))
    }

    fn finish_job(
        &mut self,
        id: i64,
        worker: &str,
        result: Result<(String, Option<String>), String>,
        scorer_version: &str,
        now_s: i64,
    ) -> Result<bool, StoreError> {
        let (status, error, public, holdout) = match result {
            Ok((p, h)) => ("scored", None, Some(p), h),
            Err(e) => ("refused", Some(e), None, None),
        };
        let db = db_error(&self.path);
        let tx = self.conn.transaction().map_err(db)?;
        let changed = tx
            .execute(
                "UPDATE submissions SET status = ?2, error = ?3, public_json = ?4, \
                 holdout_json = ?5, scorer_version = ?6, finished_s = ?7, \
                 n_scorings = n_scorings + 1, lease_until_s = NULL \
                 WHERE id = ?1 AND status = 'scoring' AND worker = ?8",
                params![
                    id,
                    status,
                    error,
                    public,
                    holdout,
                    scorer_version,
                    now_s,
                    worker
                ],
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
        tx.commit().map_err(db)?;
        Ok(changed == 1)
    }

    fn admit(
        &mut self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
        since_s: i64,
        accept: &(dyn Fn(&Ledger) -> bool + Send + Sync),
    ) -> Result<Admission, StoreError> {
        let db = db_error(&self.path);
        // IMMEDIATE: the write lock from the first read, so no other
        // process inserts between this check and this insert.
        let tx = self
            .conn
            .transaction_with_behavior(rusqlite::TransactionBehavior::Immediate)
            .map_err(db)?;
        let dup: Option<(i64, String)> = tx
            .query_row(
                "SELECT id, status FROM submissions WHERE team_id = ?1 AND sha256 = ?2 \
                 ORDER BY id LIMIT 1",
                params![team_id, sha256],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()
            .map_err(db)?;
        if let Some((id, status)) = dup {
            return Ok(Admission::Duplicate(id, status));
        }
        let times = |sql: &str| -> Result<Vec<i64>, StoreError> {
            let mut st = tx.prepare_cached(sql).map_err(db)?;
            let rows = st
                .query_map(params![team_id, since_s], |r| r.get(0))
                .and_then(|it| it.collect::<rusqlite::Result<Vec<i64>>>());
            rows.map_err(db)
        };
        let ledger = Ledger {
            meta: meta_of(&tx).map_err(db)?,
            accepted: times(
                "SELECT created_s FROM submissions WHERE team_id = ?1 AND created_s > ?2 \
                 ORDER BY created_s",
            )?,
            refused: times(
                "SELECT created_s FROM format_failures WHERE team_id = ?1 AND created_s > ?2 \
                 ORDER BY created_s",
            )?,
        };
        if !accept(&ledger) {
            return Ok(Admission::Declined(ledger));
        }
        tx.execute(
            "INSERT INTO submissions (team_id, sha256, bytes, created_s, status) \
             VALUES (?1, ?2, ?3, ?4, 'queued')",
            params![team_id, sha256, bytes, now_s],
        )
        .map_err(db)?;
        let id = tx.last_insert_rowid();
        tx.commit().map_err(db)?;
        Ok(Admission::Inserted(id))
    }

    fn all_meta(&self) -> Result<HashMap<String, String>, StoreError> {
        meta_of(&self.conn).map_err(|e| self.err(e))
    }

    fn requeue_interrupted(&mut self) -> Result<usize, StoreError> {
        self.conn
            .execute(
                "UPDATE submissions SET status = 'queued', started_s = NULL, \
                 lease_until_s = NULL, worker = NULL WHERE status = 'scoring'",
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

    fn set_final_entries(&mut self, team_id: i64, ids: &[i64]) -> Result<bool, StoreError> {
        let db = db_error(&self.path);
        let tx = self
            .conn
            .transaction_with_behavior(rusqlite::TransactionBehavior::Immediate)
            .map_err(db)?;
        let closed: Option<String> = tx
            .query_row("SELECT value FROM meta WHERE key = 'closed'", [], |r| {
                r.get(0)
            })
            .optional()
            .map_err(db)?;
        if closed.as_deref() == Some("true") {
            return Ok(false);
        }
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
        tx.commit().map_err(db)?;
        Ok(true)
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
                "UPDATE submissions SET status = 'queued', started_s = NULL, \
                 lease_until_s = NULL, worker = NULL WHERE status = 'scored' AND NOT EXISTS (SELECT 1 FROM scores \
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

/// [`Store`] on one SQLite file.
#[derive(Clone)]
pub struct SqliteStore {
    inner: Arc<Mutex<Conn>>,
    path: String,
}

impl std::fmt::Debug for SqliteStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SqliteStore({})", self.path)
    }
}

impl SqliteStore {
    /// Opens (creating when `create`) the database and applies the
    /// migrations it lacks.
    pub async fn open(path: &Path, create: bool) -> Result<Self, StoreError> {
        let owned = path.to_path_buf();
        let name = path.display().to_string();
        let conn = tokio::task::spawn_blocking(move || Conn::open(&owned, create))
            .await
            .map_err(|e| StoreError::Db {
                path: name.clone(),
                message: e.to_string(),
            })??;
        Ok(Self {
            inner: Arc::new(Mutex::new(conn)),
            path: name,
        })
    }

    /// Runs `f` on the connection on a blocking thread.
    async fn run<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Conn) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, StoreError> {
        let inner = self.inner.clone();
        tokio::task::spawn_blocking(move || {
            let mut conn = inner
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            f(&mut conn)
        })
        .await
        .map_err(|e| StoreError::Db {
            path: self.path.clone(),
            message: format!("the store's thread failed: {e}"),
        })?
    }
}

#[async_trait::async_trait]
impl Store for SqliteStore {
    fn describe(&self) -> String {
        format!("sqlite:{}", self.path)
    }

    async fn meta(&self, key: &str) -> Result<Option<String>, StoreError> {
        let key = key.to_owned();
        self.run(move |c| c.meta(&key)).await
    }

    async fn all_meta(&self) -> Result<HashMap<String, String>, StoreError> {
        self.run(|c| c.all_meta()).await
    }

    async fn set_meta(&self, key: &str, value: &str) -> Result<(), StoreError> {
        let (key, value) = (key.to_owned(), value.to_owned());
        self.run(move |c| c.set_meta(&key, &value)).await
    }

    async fn add_team(
        &self,
        name: &str,
        token_sha256: &str,
        now_s: i64,
    ) -> Result<i64, StoreError> {
        let (name, token) = (name.to_owned(), token_sha256.to_owned());
        self.run(move |c| c.add_team(&name, &token, now_s)).await
    }

    async fn team_by_name(&self, name: &str) -> Result<Option<Team>, StoreError> {
        let name = name.to_owned();
        self.run(move |c| c.team_by_name(&name)).await
    }

    async fn team_by_token(&self, token_sha256: &str) -> Result<Option<Team>, StoreError> {
        let token = token_sha256.to_owned();
        self.run(move |c| c.team_by_token(&token)).await
    }

    async fn set_token(&self, team_id: i64, token_sha256: &str) -> Result<(), StoreError> {
        let token = token_sha256.to_owned();
        self.run(move |c| c.set_token(team_id, &token)).await
    }

    async fn revoke(&self, team_id: i64) -> Result<(), StoreError> {
        self.run(move |c| c.revoke(team_id)).await
    }

    async fn teams(&self) -> Result<Vec<Team>, StoreError> {
        self.run(|c| c.teams()).await
    }

    async fn admit(
        &self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
        since_s: i64,
        accept: Rule,
    ) -> Result<Admission, StoreError> {
        let sha = sha256.to_owned();
        self.run(move |c| c.admit(team_id, &sha, bytes, now_s, since_s, accept.as_ref()))
            .await
    }

    async fn insert_submission(
        &self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
    ) -> Result<i64, StoreError> {
        let sha = sha256.to_owned();
        self.run(move |c| c.insert_submission(team_id, &sha, bytes, now_s))
            .await
    }

    async fn submission(&self, id: i64) -> Result<Option<Submission>, StoreError> {
        self.run(move |c| c.submission(id)).await
    }

    async fn submissions_of(&self, team_id: i64) -> Result<Vec<Submission>, StoreError> {
        self.run(move |c| c.submissions_of(team_id)).await
    }

    async fn all_submissions(&self) -> Result<Vec<Submission>, StoreError> {
        self.run(|c| c.all_submissions()).await
    }

    async fn accepted_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        self.run(move |c| c.accepted_since(team_id, since_s)).await
    }

    async fn add_format_failure(
        &self,
        team_id: i64,
        error: &str,
        now_s: i64,
    ) -> Result<(), StoreError> {
        let error = error.to_owned();
        self.run(move |c| c.add_format_failure(team_id, &error, now_s))
            .await
    }

    async fn format_failures_since(
        &self,
        team_id: i64,
        since_s: i64,
    ) -> Result<Vec<i64>, StoreError> {
        self.run(move |c| c.format_failures_since(team_id, since_s))
            .await
    }

    async fn format_failures(
        &self,
        team_id: Option<i64>,
        limit: usize,
    ) -> Result<Vec<FormatFailure>, StoreError> {
        self.run(move |c| c.format_failures(team_id, limit)).await
    }

    async fn queue_counts(&self) -> Result<QueueCounts, StoreError> {
        self.run(|c| c.queue_counts()).await
    }

    async fn format_failure_counts(&self) -> Result<Vec<(i64, u64)>, StoreError> {
        self.run(|c| c.format_failure_counts()).await
    }

    async fn claim_job(&self, lease: &Lease, now_s: i64) -> Result<Option<Submission>, StoreError> {
        let lease = lease.clone();
        self.run(move |c| c.claim_job(&lease, now_s)).await
    }

    async fn renew_lease(&self, id: i64, lease: &Lease, now_s: i64) -> Result<bool, StoreError> {
        let lease = lease.clone();
        self.run(move |c| c.renew_lease(id, &lease, now_s)).await
    }

    async fn finish_job(
        &self,
        id: i64,
        worker: &str,
        result: Result<(String, Option<String>), String>,
        scorer_version: &str,
        now_s: i64,
    ) -> Result<bool, StoreError> {
        let (worker, version) = (worker.to_owned(), scorer_version.to_owned());
        self.run(move |c| c.finish_job(id, &worker, result, &version, now_s))
            .await
    }

    async fn requeue_interrupted(&self) -> Result<usize, StoreError> {
        self.run(|c| c.requeue_interrupted()).await
    }

    async fn set_role(&self, team_id: i64, role: Role) -> Result<(), StoreError> {
        self.run(move |c| c.set_role(team_id, role)).await
    }

    async fn set_final_entries(&self, team_id: i64, ids: &[i64]) -> Result<bool, StoreError> {
        let ids = ids.to_vec();
        self.run(move |c| c.set_final_entries(team_id, &ids)).await
    }

    async fn final_entries(&self, team_id: i64) -> Result<Vec<i64>, StoreError> {
        self.run(move |c| c.final_entries(team_id)).await
    }

    async fn rescore(&self, scorer_version: &str) -> Result<usize, StoreError> {
        let version = scorer_version.to_owned();
        self.run(move |c| c.rescore(&version)).await
    }

    async fn scores_of(&self, submission_id: i64) -> Result<Vec<Score>, StoreError> {
        self.run(move |c| c.scores_of(submission_id)).await
    }
}
