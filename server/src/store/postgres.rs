//! [`Store`] on a PostgreSQL database, shared by several `serve` and
//! `worker` processes on several hosts. Each process keeps a few
//! connections ([`POOL_SIZE`]); every rule several processes could break
//! together is one transaction: an admission locks its team's row, a claim
//! takes its job and its team's row with `FOR UPDATE SKIP LOCKED`, a choice
//! of finals reads `closed` under a share lock. Every connection, wait and
//! statement has a bound: on the server ([`STATEMENT_TIMEOUT_MS`], an idle
//! transaction ends after [`IDLE_IN_TRANSACTION_MS`]) and on the client
//! ([`CONNECT_TIMEOUT`], [`OPERATION_TIMEOUT`], TCP keepalives and a user
//! timeout, so a database that vanishes mid-statement is an error within a
//! minute, not a hang). Leases are timed by the database's clock, so hosts
//! whose clocks disagree do not take each other's live jobs.

use super::{
    Admission, FormatFailure, Lease, Ledger, QueueCounts, Role, Rule, Score, Store, StoreError,
    Submission, Team,
};
use std::collections::HashMap;
use std::time::Duration;
use tokio_postgres::types::ToSql;
use tokio_postgres::{Client, NoTls, Row};

/// Connections one process keeps open to the database at most.
pub const POOL_SIZE: usize = 8;
/// The longest wait for a connection (a new one, or a free one).
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);
/// The longest a statement may run (and wait for a lock) before the
/// database cancels it.
pub const STATEMENT_TIMEOUT_MS: u32 = 30_000;
/// A session left inside a transaction this long is ended by the database
/// (a client that vanished mid-transaction releases its locks).
pub const IDLE_IN_TRANSACTION_MS: u32 = 60_000;
/// The longest one store call (all its statements) may take on the
/// client's side; the connection is then dropped, not reused.
pub const OPERATION_TIMEOUT: Duration = Duration::from_secs(40);

/// The database's clock in Unix seconds (SQL).
const DB_NOW: &str = "EXTRACT(EPOCH FROM clock_timestamp())::BIGINT";

/// The schema, version by version (table `schema_version` counts those
/// applied). Never edit one that has shipped: add another. The first is
/// the SQLite schema after its third migration, in PostgreSQL's types.
pub const PG_MIGRATIONS: &[&str] = &[r#"
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE teams (
    id BIGSERIAL PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    token_sha256 TEXT NOT NULL UNIQUE,
    revoked BOOLEAN NOT NULL DEFAULT FALSE,
    created_s BIGINT NOT NULL,
    role TEXT NOT NULL DEFAULT 'participant'
        CHECK (role IN ('participant', 'organisers', 'baseline'))
);
CREATE TABLE submissions (
    id BIGSERIAL PRIMARY KEY,
    team_id BIGINT NOT NULL REFERENCES teams(id),
    sha256 TEXT NOT NULL,
    bytes BIGINT NOT NULL,
    created_s BIGINT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('queued', 'scoring', 'scored', 'refused')),
    started_s BIGINT,
    finished_s BIGINT,
    error TEXT,
    public_json TEXT,
    holdout_json TEXT,
    scorer_version TEXT,
    n_scorings BIGINT NOT NULL DEFAULT 0,
    final BOOLEAN NOT NULL DEFAULT FALSE,
    lease_until_s BIGINT,
    worker TEXT
);
CREATE INDEX submissions_team ON submissions(team_id, created_s);
CREATE INDEX submissions_status ON submissions(status, id);
CREATE TABLE format_failures (
    id BIGSERIAL PRIMARY KEY,
    team_id BIGINT NOT NULL REFERENCES teams(id),
    created_s BIGINT NOT NULL,
    error TEXT NOT NULL
);
CREATE INDEX format_failures_team ON format_failures(team_id, created_s);
CREATE TABLE scores (
    submission_id BIGINT NOT NULL REFERENCES submissions(id),
    scorer_version TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('scored', 'refused')),
    finished_s BIGINT NOT NULL,
    error TEXT,
    public_json TEXT,
    holdout_json TEXT,
    n_scorings BIGINT NOT NULL DEFAULT 1,
    seq BIGSERIAL,
    PRIMARY KEY (submission_id, scorer_version)
);
"#];

/// [`Store`] on a PostgreSQL database.
pub struct PgStore {
    config: tokio_postgres::Config,
    shown: String,
    idle: std::sync::Mutex<Vec<Client>>,
    permits: tokio::sync::Semaphore,
}

impl std::fmt::Debug for PgStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PgStore({})", self.shown)
    }
}

/// A connection taken from the pool; back in it when dropped (unless it
/// broke).
struct Held<'a> {
    store: &'a PgStore,
    client: Option<Client>,
    /// Set when the call using it ended (not cut off by a timeout): only
    /// then may the connection serve another call.
    done: bool,
    _permit: tokio::sync::SemaphorePermit<'a>,
}

impl Drop for Held<'_> {
    fn drop(&mut self) {
        if !self.done {
            return;
        }
        if let Some(c) = self.client.take().filter(|c| !c.is_closed()) {
            self.store
                .idle
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .push(c);
        }
    }
}

impl std::ops::Deref for Held<'_> {
    type Target = Client;
    fn deref(&self) -> &Client {
        self.client
            .as_ref()
            .expect("a held connection has its client")
    }
}

impl std::ops::DerefMut for Held<'_> {
    fn deref_mut(&mut self) -> &mut Client {
        self.client
            .as_mut()
            .expect("a held connection has its client")
    }
}

const SUBMISSION_COLUMNS: &str = "id, team_id, sha256, bytes, created_s, status, error, \
                                  public_json, holdout_json, n_scorings, scorer_version, final, worker";

fn row_submission(r: &Row) -> Submission {
    Submission {
        id: r.get(0),
        team_id: r.get(1),
        sha256: r.get(2),
        bytes: r.get(3),
        created_s: r.get(4),
        status: r.get(5),
        error: r.get(6),
        public_json: r.get(7),
        holdout_json: r.get(8),
        n_scorings: r.get(9),
        scorer_version: r.get(10),
        final_choice: r.get(11),
        worker: r.get(12),
    }
}

fn row_team(r: &Row) -> Team {
    Team {
        id: r.get(0),
        name: r.get(1),
        revoked: r.get(2),
        role: Role::from_name(r.get::<_, &str>(3)).unwrap_or_default(),
    }
}

type Params<'a> = &'a [&'a (dyn ToSql + Sync)];

impl PgStore {
    /// Connects to the database at `url` (libpq's URL form) and applies the
    /// schema versions it lacks. The database itself must exist (an
    /// organiser's `createdb`); its tables are made here when `create`, and
    /// a database without them is refused otherwise (nothing is written
    /// to a wrong database).
    pub async fn open(url: &str, create: bool) -> Result<Self, StoreError> {
        let shown = super::hide_password(url);
        let mut config: tokio_postgres::Config = url.parse().map_err(|e| StoreError::Db {
            path: shown.clone(),
            message: format!("not a PostgreSQL address: {e}"),
        })?;
        config.connect_timeout(CONNECT_TIMEOUT);
        config.keepalives(true);
        config.keepalives_idle(Duration::from_secs(15));
        config.tcp_user_timeout(Duration::from_secs(30));
        let own = format!(
            "-c statement_timeout={STATEMENT_TIMEOUT_MS} -c lock_timeout={STATEMENT_TIMEOUT_MS} \
             -c idle_in_transaction_session_timeout={IDLE_IN_TRANSACTION_MS}"
        );
        // Options given in the URL are kept, after these.
        let given = config.get_options().map(str::to_string);
        config.options(match given {
            Some(g) if !g.is_empty() => format!("{own} {g}"),
            _ => own,
        });
        config.application_name("stepsim");
        let store = Self {
            config,
            shown,
            idle: std::sync::Mutex::new(Vec::new()),
            permits: tokio::sync::Semaphore::new(POOL_SIZE),
        };
        store.migrate(create).await?;
        Ok(store)
    }

    fn err(&self, e: impl std::fmt::Display) -> StoreError {
        StoreError::Db {
            path: self.shown.clone(),
            message: e.to_string(),
        }
    }

    /// A connection: a free one of the pool, or a new one.
    async fn conn(&self) -> Result<Held<'_>, StoreError> {
        let permit = tokio::time::timeout(CONNECT_TIMEOUT, self.permits.acquire())
            .await
            .map_err(|_| {
                self.err(format!(
                    "no connection free after {} s",
                    CONNECT_TIMEOUT.as_secs()
                ))
            })?
            .map_err(|e| self.err(e))?;
        let idle = self
            .idle
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop();
        let client = match idle.filter(|c| !c.is_closed()) {
            Some(c) => c,
            None => {
                let (client, connection) =
                    tokio::time::timeout(CONNECT_TIMEOUT, self.config.connect(NoTls))
                        .await
                        .map_err(|_| {
                            self.err(format!(
                                "cannot connect within {} s",
                                CONNECT_TIMEOUT.as_secs()
                            ))
                        })?
                        .map_err(|e| self.err(e))?;
                tokio::spawn(async move {
                    if let Err(e) = connection.await {
                        tracing::warn!(error = %e, "store: a database connection ended");
                    }
                });
                client
            }
        };
        Ok(Held {
            store: self,
            client: Some(client),
            done: false,
            _permit: permit,
        })
    }

    async fn migrate(&self, create: bool) -> Result<(), StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = async {
                let tx = c.transaction().await.map_err(|e| self.err(e))?;
                // One process at a time applies the schema (others wait here).
                tx.execute("SELECT pg_advisory_xact_lock(7305262006)", &[])
                    .await
                    .map_err(|e| self.err(e))?;
                tx.batch_execute(
                    "CREATE TABLE IF NOT EXISTS schema_version (version BIGINT NOT NULL)",
                )
                .await
                .map_err(|e| self.err(e))?;
                let version: i64 = tx
                    .query_opt("SELECT version FROM schema_version", &[])
                    .await
                    .map_err(|e| self.err(e))?
                    .map_or(0, |r| r.get(0));
                let known = PG_MIGRATIONS.len() as i64;
                if version == 0 && !create {
                    return Err(self.err(
                        "holds no challenge (no stepsim tables): give the database that \
                         `stepsim challenge init --store` was given",
                    ));
                }
                if version > known {
                    return Err(StoreError::TooNew {
                        path: self.shown.clone(),
                        found: version,
                        known,
                    });
                }
                for sql in PG_MIGRATIONS.iter().skip(version as usize) {
                    tx.batch_execute(sql).await.map_err(|e| self.err(e))?;
                }
                if version < known {
                    tx.execute("DELETE FROM schema_version", &[])
                        .await
                        .map_err(|e| self.err(e))?;
                    tx.execute("INSERT INTO schema_version VALUES ($1)", &[&known])
                        .await
                        .map_err(|e| self.err(e))?;
                }
                tx.commit().await.map_err(|e| self.err(e))
            }
            .await;
            c.done = true;
            r
        })
        .await
    }

    /// `f` cut off after [`OPERATION_TIMEOUT`] (its connection is then
    /// dropped with it).
    async fn timed<T>(
        &self,
        f: impl std::future::Future<Output = Result<T, StoreError>>,
    ) -> Result<T, StoreError> {
        tokio::time::timeout(OPERATION_TIMEOUT, f)
            .await
            .unwrap_or_else(|_| {
                Err(self.err(format!(
                    "no answer within {} s",
                    OPERATION_TIMEOUT.as_secs()
                )))
            })
    }

    async fn rows(&self, sql: &str, p: Params<'_>) -> Result<Vec<Row>, StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = c.query(sql, p).await.map_err(|e| self.err(e));
            c.done = true;
            r
        })
        .await
    }

    async fn opt(&self, sql: &str, p: Params<'_>) -> Result<Option<Row>, StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = c.query_opt(sql, p).await.map_err(|e| self.err(e));
            c.done = true;
            r
        })
        .await
    }

    async fn exec(&self, sql: &str, p: Params<'_>) -> Result<u64, StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = c.execute(sql, p).await.map_err(|e| self.err(e));
            c.done = true;
            r
        })
        .await
    }

    async fn times(&self, sql: &str, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        Ok(self
            .rows(sql, &[&team_id, &since_s])
            .await?
            .iter()
            .map(|r| r.get(0))
            .collect())
    }

    async fn submissions_where(
        &self,
        clause: &str,
        p: Params<'_>,
    ) -> Result<Vec<Submission>, StoreError> {
        let sql = format!("SELECT {SUBMISSION_COLUMNS} FROM submissions {clause}");
        Ok(self
            .rows(&sql, p)
            .await?
            .iter()
            .map(row_submission)
            .collect())
    }
}

const ACCEPTED_SINCE: &str = "SELECT created_s FROM submissions WHERE team_id = $1 \
                              AND created_s > $2 ORDER BY created_s";
const REFUSED_SINCE: &str = "SELECT created_s FROM format_failures WHERE team_id = $1 \
                             AND created_s > $2 ORDER BY created_s";

#[async_trait::async_trait]
impl Store for PgStore {
    fn describe(&self) -> String {
        self.shown.clone()
    }

    async fn meta(&self, key: &str) -> Result<Option<String>, StoreError> {
        Ok(self
            .opt("SELECT value FROM meta WHERE key = $1", &[&key])
            .await?
            .map(|r| r.get(0)))
    }

    async fn all_meta(&self) -> Result<HashMap<String, String>, StoreError> {
        Ok(self
            .rows("SELECT key, value FROM meta", &[])
            .await?
            .iter()
            .map(|r| (r.get(0), r.get(1)))
            .collect())
    }

    async fn set_meta(&self, key: &str, value: &str) -> Result<(), StoreError> {
        self.exec(
            "INSERT INTO meta (key, value) VALUES ($1, $2) \
             ON CONFLICT (key) DO UPDATE SET value = excluded.value",
            &[&key, &value],
        )
        .await
        .map(drop)
    }

    async fn add_team(
        &self,
        name: &str,
        token_sha256: &str,
        now_s: i64,
    ) -> Result<i64, StoreError> {
        let row = self
            .opt(
                "INSERT INTO teams (name, token_sha256, created_s) VALUES ($1, $2, $3) \
                 RETURNING id",
                &[&name, &token_sha256, &now_s],
            )
            .await?;
        row.map(|r| r.get(0))
            .ok_or_else(|| self.err("the insert returned no id"))
    }

    async fn team_by_name(&self, name: &str) -> Result<Option<Team>, StoreError> {
        Ok(self
            .opt(
                "SELECT id, name, revoked, role FROM teams WHERE name = $1",
                &[&name],
            )
            .await?
            .as_ref()
            .map(row_team))
    }

    async fn team_by_token(&self, token_sha256: &str) -> Result<Option<Team>, StoreError> {
        Ok(self
            .opt(
                "SELECT id, name, revoked, role FROM teams \
                 WHERE token_sha256 = $1 AND NOT revoked",
                &[&token_sha256],
            )
            .await?
            .as_ref()
            .map(row_team))
    }

    async fn set_token(&self, team_id: i64, token_sha256: &str) -> Result<(), StoreError> {
        self.exec(
            "UPDATE teams SET token_sha256 = $2, revoked = FALSE WHERE id = $1",
            &[&team_id, &token_sha256],
        )
        .await
        .map(drop)
    }

    async fn revoke(&self, team_id: i64) -> Result<(), StoreError> {
        self.exec("UPDATE teams SET revoked = TRUE WHERE id = $1", &[&team_id])
            .await
            .map(drop)
    }

    async fn teams(&self) -> Result<Vec<Team>, StoreError> {
        Ok(self
            .rows("SELECT id, name, revoked, role FROM teams ORDER BY id", &[])
            .await?
            .iter()
            .map(row_team)
            .collect())
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
        self.timed(async {
            let mut c = self.conn().await?;
            let r = async {
                let tx = c.transaction().await.map_err(|e| self.err(e))?;
                // The team's row, locked to the end: admissions of one team, on
                // any host, run one after the other.
                tx.execute("SELECT id FROM teams WHERE id = $1 FOR UPDATE", &[&team_id])
                    .await
                    .map_err(|e| self.err(e))?;
                let dup = tx
                    .query_opt(
                        "SELECT id, status FROM submissions WHERE team_id = $1 AND sha256 = $2 \
                         ORDER BY id LIMIT 1",
                        &[&team_id, &sha256],
                    )
                    .await
                    .map_err(|e| self.err(e))?;
                if let Some(r) = dup {
                    return Ok(Admission::Duplicate(r.get(0), r.get(1)));
                }
                let times = |rows: Vec<Row>| rows.iter().map(|r| r.get(0)).collect::<Vec<i64>>();
                let meta = tx
                    // Under a share lock: a `freeze` or `close` on another
                    // host waits for this admission, or this one sees it.
                    .query("SELECT key, value FROM meta FOR SHARE", &[])
                    .await
                    .map_err(|e| self.err(e))?
                    .iter()
                    .map(|r| (r.get(0), r.get(1)))
                    .collect();
                let accepted = tx
                    .query(ACCEPTED_SINCE, &[&team_id, &since_s])
                    .await
                    .map_err(|e| self.err(e))?;
                let refused = tx
                    .query(REFUSED_SINCE, &[&team_id, &since_s])
                    .await
                    .map_err(|e| self.err(e))?;
                let ledger = Ledger {
                    meta,
                    accepted: times(accepted),
                    refused: times(refused),
                };
                if !accept(&ledger) {
                    return Ok(Admission::Declined(ledger));
                }
                let id: i64 = tx
                    .query_one(
                        "INSERT INTO submissions (team_id, sha256, bytes, created_s, status) \
                         VALUES ($1, $2, $3, $4, 'queued') RETURNING id",
                        &[&team_id, &sha256, &bytes, &now_s],
                    )
                    .await
                    .map_err(|e| self.err(e))?
                    .get(0);
                tx.commit().await.map_err(|e| self.err(e))?;
                Ok(Admission::Inserted(id))
            }
            .await;
            c.done = true;
            r
        })
        .await
    }

    async fn insert_submission(
        &self,
        team_id: i64,
        sha256: &str,
        bytes: i64,
        now_s: i64,
    ) -> Result<i64, StoreError> {
        let row = self
            .opt(
                "INSERT INTO submissions (team_id, sha256, bytes, created_s, status) \
                 VALUES ($1, $2, $3, $4, 'queued') RETURNING id",
                &[&team_id, &sha256, &bytes, &now_s],
            )
            .await?;
        row.map(|r| r.get(0))
            .ok_or_else(|| self.err("the insert returned no id"))
    }

    async fn submission(&self, id: i64) -> Result<Option<Submission>, StoreError> {
        Ok(self
            .submissions_where("WHERE id = $1", &[&id])
            .await?
            .into_iter()
            .next())
    }

    async fn submissions_of(&self, team_id: i64) -> Result<Vec<Submission>, StoreError> {
        self.submissions_where("WHERE team_id = $1 ORDER BY id DESC", &[&team_id])
            .await
    }

    async fn all_submissions(&self) -> Result<Vec<Submission>, StoreError> {
        self.submissions_where("ORDER BY id", &[]).await
    }

    async fn accepted_since(&self, team_id: i64, since_s: i64) -> Result<Vec<i64>, StoreError> {
        self.times(ACCEPTED_SINCE, team_id, since_s).await
    }

    async fn add_format_failure(
        &self,
        team_id: i64,
        error: &str,
        now_s: i64,
    ) -> Result<(), StoreError> {
        self.exec(
            "INSERT INTO format_failures (team_id, created_s, error) VALUES ($1, $2, $3)",
            &[&team_id, &now_s, &error],
        )
        .await
        .map(drop)
    }

    async fn format_failures_since(
        &self,
        team_id: i64,
        since_s: i64,
    ) -> Result<Vec<i64>, StoreError> {
        self.times(REFUSED_SINCE, team_id, since_s).await
    }

    async fn format_failures(
        &self,
        team_id: Option<i64>,
        limit: usize,
    ) -> Result<Vec<FormatFailure>, StoreError> {
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        Ok(self
            .rows(
                "SELECT team_id, created_s, error FROM format_failures \
                 WHERE $1::BIGINT IS NULL OR team_id = $1 \
                 ORDER BY created_s DESC, id DESC LIMIT $2",
                &[&team_id, &limit],
            )
            .await?
            .iter()
            .map(|r| FormatFailure {
                team_id: r.get(0),
                created_s: r.get(1),
                error: r.get(2),
            })
            .collect())
    }

    async fn queue_counts(&self) -> Result<QueueCounts, StoreError> {
        let mut c = QueueCounts::default();
        for r in self
            .rows(
                "SELECT status, COUNT(*) FROM submissions GROUP BY status",
                &[],
            )
            .await?
        {
            let n = r.get::<_, i64>(1).max(0) as u64;
            match r.get::<_, &str>(0) {
                "queued" => c.queued = n,
                "scoring" => c.scoring = n,
                "scored" => c.scored = n,
                "refused" => c.refused = n,
                _ => {}
            }
        }
        c.format_refusals = self
            .opt("SELECT COUNT(*) FROM format_failures", &[])
            .await?
            .map_or(0, |r| r.get::<_, i64>(0).max(0) as u64);
        Ok(c)
    }

    async fn format_failure_counts(&self) -> Result<Vec<(i64, u64)>, StoreError> {
        Ok(self
            .rows(
                "SELECT team_id, COUNT(*) FROM format_failures GROUP BY team_id ORDER BY team_id",
                &[],
            )
            .await?
            .iter()
            .map(|r| (r.get(0), r.get::<_, i64>(1).max(0) as u64))
            .collect())
    }

    async fn claim_job(&self, lease: &Lease, now_s: i64) -> Result<Option<Submission>, StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = async {
                let tx = c.transaction().await.map_err(|e| self.err(e))?;
                // The lease is timed by the database's clock (`now_s` is
                // this host's, and hosts' clocks may disagree).
                let now: i64 = tx
                    .query_one(&format!("SELECT {DB_NOW}"), &[])
                    .await
                    .map_err(|e| self.err(e))?
                    .get(0);
                let _ = now_s;
                // The job's row and its team's row, skipping those another
                // claim holds: two workers never take one job.
                let row = tx
                    .query_opt(
                        "SELECT s.id, s.team_id FROM submissions s JOIN teams t ON t.id = s.team_id \
                         WHERE (s.status = 'queued' OR \
                         (s.status = 'scoring' AND COALESCE(s.lease_until_s, 0) < $1)) \
                         AND NOT EXISTS (SELECT 1 FROM submissions o WHERE o.team_id = s.team_id \
                         AND o.id <> s.id AND o.status = 'scoring' \
                         AND COALESCE(o.lease_until_s, 0) >= $1) \
                         ORDER BY s.id LIMIT 1 FOR UPDATE OF s, t SKIP LOCKED",
                        &[&now],
                    )
                    .await
                    .map_err(|e| self.err(e))?;
                let Some(row) = row else {
                    return Ok(None);
                };
                let (id, team): (i64, i64) = (row.get(0), row.get(1));
                // The query above saw the table as it was when it started:
                // a claim of another job of this team that committed since
                // (it held the team's row, which this one now holds) shows
                // only to a new statement. Seen, this claim takes nothing.
                let busy = tx
                    .query_opt(
                        "SELECT 1 FROM submissions WHERE team_id = $1 AND id <> $2 \
                         AND status = 'scoring' AND COALESCE(lease_until_s, 0) >= $3",
                        &[&team, &id, &now],
                    )
                    .await
                    .map_err(|e| self.err(e))?;
                if busy.is_some() {
                    return Ok(None);
                }
                let until = now.saturating_add(lease.seconds);
                let sql = format!(
                    "UPDATE submissions SET status = 'scoring', started_s = $2, worker = $3, \
                     lease_until_s = $4 WHERE id = $1 RETURNING {SUBMISSION_COLUMNS}"
                );
                let sub = tx
                    .query_one(&sql, &[&id, &now, &lease.worker, &until])
                    .await
                    .map_err(|e| self.err(e))?;
                tx.commit().await.map_err(|e| self.err(e))?;
                Ok(Some(row_submission(&sub)))
            }
            .await;
            c.done = true;
            r
        })
        .await
    }

    async fn renew_lease(&self, id: i64, lease: &Lease, now_s: i64) -> Result<bool, StoreError> {
        // The database's clock, as for the claim (`now_s` is this host's).
        let _ = now_s;
        let sql = format!(
            "UPDATE submissions SET lease_until_s = {DB_NOW} + $3 \
             WHERE id = $1 AND status = 'scoring' AND worker = $2"
        );
        Ok(self
            .exec(&sql, &[&id, &lease.worker, &lease.seconds])
            .await?
            == 1)
    }

    async fn finish_job(
        &self,
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
        self.timed(async {
            let mut c = self.conn().await?;
            let r = async {
                let tx = c.transaction().await.map_err(|e| self.err(e))?;
                let changed = tx
                    .execute(
                        "UPDATE submissions SET status = $2, error = $3, public_json = $4, \
                         holdout_json = $5, scorer_version = $6, finished_s = $7, \
                         n_scorings = n_scorings + 1, lease_until_s = NULL \
                         WHERE id = $1 AND status = 'scoring' AND worker = $8",
                        &[
                            &id,
                            &status,
                            &error,
                            &public,
                            &holdout,
                            &scorer_version,
                            &now_s,
                            &worker,
                        ],
                    )
                    .await
                    .map_err(|e| self.err(e))?;
                if changed == 1 {
                    tx.execute(
                        "INSERT INTO scores (submission_id, scorer_version, status, finished_s, error, \
                         public_json, holdout_json) VALUES ($1, $2, $3, $4, $5, $6, $7) \
                         ON CONFLICT (submission_id, scorer_version) DO UPDATE SET \
                         status = excluded.status, finished_s = excluded.finished_s, \
                         error = excluded.error, public_json = excluded.public_json, \
                         holdout_json = excluded.holdout_json, n_scorings = scores.n_scorings + 1",
                        &[
                            &id,
                            &scorer_version,
                            &status,
                            &now_s,
                            &error,
                            &public,
                            &holdout,
                        ],
                    )
                    .await
                    .map_err(|e| self.err(e))?;
                }
                tx.commit().await.map_err(|e| self.err(e))?;
                Ok(changed == 1)
            }
            .await;
            c.done = true;
            r
        })
        .await
    }

    async fn requeue_interrupted(&self) -> Result<usize, StoreError> {
        Ok(self
            .exec(
                "UPDATE submissions SET status = 'queued', started_s = NULL, \
                 lease_until_s = NULL, worker = NULL WHERE status = 'scoring'",
                &[],
            )
            .await? as usize)
    }

    async fn set_role(&self, team_id: i64, role: Role) -> Result<(), StoreError> {
        self.exec(
            "UPDATE teams SET role = $2 WHERE id = $1",
            &[&team_id, &role.name()],
        )
        .await
        .map(drop)
    }

    async fn set_final_entries(&self, team_id: i64, ids: &[i64]) -> Result<bool, StoreError> {
        self.timed(async {
            let mut c = self.conn().await?;
            let r = async {
                let tx = c.transaction().await.map_err(|e| self.err(e))?;
                // `closed` under a share lock: a `challenge close` on another host
                // waits for this choice, or this choice sees it closed.
                let closed = tx
                    .query_opt("SELECT value FROM meta WHERE key = 'closed' FOR SHARE", &[])
                    .await
                    .map_err(|e| self.err(e))?
                    .is_some_and(|r| r.get::<_, &str>(0) == "true");
                if closed {
                    return Ok(false);
                }
                tx.execute(
                    "UPDATE submissions SET final = FALSE WHERE team_id = $1 AND final",
                    &[&team_id],
                )
                .await
                .map_err(|e| self.err(e))?;
                tx.execute(
                    "UPDATE submissions SET final = TRUE WHERE team_id = $1 AND id = ANY($2)",
                    &[&team_id, &ids],
                )
                .await
                .map_err(|e| self.err(e))?;
                tx.commit().await.map_err(|e| self.err(e))?;
                Ok(true)
            }
            .await;
            c.done = true;
            r
        })
        .await
    }

    async fn final_entries(&self, team_id: i64) -> Result<Vec<i64>, StoreError> {
        Ok(self
            .rows(
                "SELECT id FROM submissions WHERE team_id = $1 AND final ORDER BY id",
                &[&team_id],
            )
            .await?
            .iter()
            .map(|r| r.get(0))
            .collect())
    }

    async fn rescore(&self, scorer_version: &str) -> Result<usize, StoreError> {
        Ok(self
            .exec(
                "UPDATE submissions SET status = 'queued', started_s = NULL, \
                 lease_until_s = NULL, worker = NULL WHERE status = 'scored' AND NOT EXISTS \
                 (SELECT 1 FROM scores WHERE scores.submission_id = submissions.id \
                 AND scores.scorer_version = $1)",
                &[&scorer_version],
            )
            .await? as usize)
    }

    async fn scores_of(&self, submission_id: i64) -> Result<Vec<Score>, StoreError> {
        Ok(self
            .rows(
                "SELECT submission_id, scorer_version, status, finished_s, error, \
                 public_json, holdout_json, n_scorings FROM scores \
                 WHERE submission_id = $1 ORDER BY seq DESC",
                &[&submission_id],
            )
            .await?
            .iter()
            .map(|r| Score {
                submission_id: r.get(0),
                scorer_version: r.get(1),
                status: r.get(2),
                finished_s: r.get(3),
                error: r.get(4),
                public_json: r.get(5),
                holdout_json: r.get(6),
                n_scorings: r.get(7),
            })
            .collect())
    }
}
