//! The challenge itself, knowing nothing of HTTP: its state directory and
//! the organiser's operations on it (here), where it stands ([`Phase`]),
//! what admits an upload ([`admission`]), which entries count
//! ([`final_entries_or_default`]), an entry's figures ([`figures`]), the leaderboard
//! ([`leaderboard`]) and the run's public files ([`public_data`]). It
//! stands on the store alone.

pub mod admission;
mod export;
pub mod figures;
mod finals;
pub mod leaderboard;
mod phase;
pub mod public_data;

pub use export::Export;
pub use finals::{ChoiceError, MAX_FINAL_ENTRIES, choose_final_entries, final_entries_or_default};
pub use phase::Phase;

use crate::store::{DB_FILE, Role, Store, StoreError, StoreUrl};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use stepsim_contract::digest::hex;
use stepsim_contract::run_dir::RunDir;
use stepsim_harness::{has_holdout, load_truth_set};

/// The scorer of this binary: a score records the version that made it.
pub const SCORER_VERSION: &str = concat!("stepsim-harness ", env!("CARGO_PKG_VERSION"));
/// Default rolling 24-hour quota of scored submissions per team.
pub const DEFAULT_QUOTA: u32 = 4;
/// Uploads refused by the format check allowed per team per 24 hours.
pub const DEFAULT_FORMAT_FAILURE_CAP: u32 = 20;
/// Requests allowed per token and per client address in one minute.
pub const DEFAULT_REQUESTS_PER_MINUTE: u32 = 120;
/// The window of the quota.
pub const QUOTA_WINDOW_S: i64 = 24 * 3600;

/// What can go wrong with a challenge.
#[derive(Debug, thiserror::Error)]
pub enum ChallengeError {
    /// The store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The run cannot be served (message names the file).
    #[error("{0}")]
    Run(String),
    /// The state directory is not usable.
    #[error("{path}: {message}")]
    State {
        /// The directory or file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A team name is unknown or taken.
    #[error("{0}")]
    Team(String),
}

/// The settings recorded at `init`.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// `RUN/private` of the served run.
    pub truth_dir: PathBuf,
    /// Scored submissions per team per rolling 24 hours.
    pub quota: u32,
    /// Upload cap in bytes.
    pub max_upload_bytes: u64,
    /// Refused uploads allowed per team per 24 hours.
    pub format_failure_cap: u32,
    /// Requests per token and per client address per minute.
    pub requests_per_minute: u32,
    /// Whether the run has a held-out part.
    pub holdout: bool,
}

/// An open challenge: its directory, settings and store.
pub struct Challenge {
    /// The state directory.
    pub dir: PathBuf,
    /// Its settings.
    pub settings: Settings,
    /// Its store (shared by every handler and worker of the process).
    pub store: Arc<dyn Store>,
}

impl std::fmt::Debug for Challenge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Challenge({})", self.dir.display())
    }
}

/// SHA-256 of a token, lower-case hex (what the store keeps).
pub fn token_hash(token: &str) -> String {
    hex(&Sha256::digest(token.as_bytes()))
}

/// A new random token: `stp_` and 64 hex digits (256 bits from the
/// operating system).
pub fn new_token() -> Result<String, ChallengeError> {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b)
        .map_err(|e| ChallengeError::Run(format!("cannot draw a token: {e}")))?;
    Ok(format!("stp_{}", hex(&b)))
}

impl Challenge {
    /// Creates a challenge for `run` in `dir` (which must not hold one),
    /// its store the directory's own SQLite file. Refuses a run without
    /// held-out datasets unless `no_holdout`.
    pub async fn init(
        run: &Path,
        dir: &Path,
        quota: u32,
        no_holdout: bool,
    ) -> Result<Self, ChallengeError> {
        Self::init_with_store(run, dir, quota, no_holdout, None).await
    }

    /// [`Challenge::init`] with its store at `store` (`None`: the
    /// directory's SQLite file). A PostgreSQL store is named in the
    /// directory's [`crate::store::STORE_FILE`] (mode 0600), so that
    /// `serve` and `worker` given the directory find it; the database must
    /// hold no challenge yet.
    pub async fn init_with_store(
        run: &Path,
        dir: &Path,
        quota: u32,
        no_holdout: bool,
        store: Option<&StoreUrl>,
    ) -> Result<Self, ChallengeError> {
        let run_dir = RunDir::new(run);
        let truth_dir = run_dir.private().path().to_path_buf();
        let truth = load_truth_set(&truth_dir).map_err(|e| ChallengeError::Run(e.to_string()))?;
        if stepsim_harness::population_switch(&truth_dir, "rotate_positions")
            .map_err(|e| ChallengeError::Run(e.to_string()))?
        {
            return Err(ChallengeError::Run(format!(
                "{}: population.rotate_positions is on, a benchmark setting: its turned twin at \
                 shear +g is the field at −g turned, so turning the public images would pair the \
                 datasets of opposite shear. Generate the challenge's run without it",
                run_dir.private().config().display()
            )));
        }
        let holdout = has_holdout(&truth.datasets);
        if !holdout && !no_holdout {
            return Err(ChallengeError::Run(format!(
                "{}: the run has no held-out datasets (config section `challenge.holdout_fields`); \
                 its public feedback would be its final score. Generate a run with held-out \
                 fields, or pass --no-holdout to serve it anyway",
                run_dir.private().datasets().display()
            )));
        }
        if quota == 0 {
            return Err(ChallengeError::Run("--quota must be at least 1".into()));
        }
        let state = |message: String| ChallengeError::State {
            path: dir.to_path_buf(),
            message,
        };
        std::fs::create_dir_all(dir).map_err(|e| state(format!("cannot create: {e}")))?;
        for held in [DB_FILE, crate::store::STORE_FILE] {
            if dir.join(held).exists() {
                return Err(state(format!(
                    "already holds a challenge ({held}); use another directory"
                )));
            }
        }
        let truth_dir = std::fs::canonicalize(&truth_dir)
            .map_err(|e| ChallengeError::Run(format!("{}: {e}", truth_dir.display())))?;
        let max_upload_bytes = stepsim_harness::run_submission_limit(&truth)
            .map_err(|e| ChallengeError::Run(e.to_string()))?;
        let url = crate::store::url_of_state(dir, store).map_err(ChallengeError::Run)?;
        let store = crate::store::open(&url, true).await?;
        if store.meta("run").await?.is_some() {
            return Err(ChallengeError::Run(format!(
                "{}: the database holds a challenge already; give an empty database",
                url.shown()
            )));
        }
        let settings = Settings {
            truth_dir,
            quota,
            max_upload_bytes,
            format_failure_cap: DEFAULT_FORMAT_FAILURE_CAP,
            requests_per_minute: DEFAULT_REQUESTS_PER_MINUTE,
            holdout,
        };
        for (k, v) in [
            ("truth_dir", settings.truth_dir.display().to_string()),
            ("run", truth.run.clone()),
            ("quota", quota.to_string()),
            ("max_upload_bytes", settings.max_upload_bytes.to_string()),
            (
                "format_failure_cap",
                settings.format_failure_cap.to_string(),
            ),
            (
                "requests_per_minute",
                settings.requests_per_minute.to_string(),
            ),
            ("holdout", holdout.to_string()),
            ("revealed", "false".into()),
            ("frozen", "false".into()),
            ("closed", "false".into()),
            // Shown to participants (`GET /api/challenge`): the run
            // directory's name until `set_name`; never the run identity,
            // which is a hash of the secret datasets.json.
            (
                "name",
                run.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "stepsim challenge".into()),
            ),
        ] {
            store.set_meta(k, &v).await?;
        }
        for sub in ["uploads", "entries"] {
            std::fs::create_dir_all(dir.join(sub)).map_err(|e| state(e.to_string()))?;
        }
        // Any store but the directory's own file is named in the
        // directory, so that every command given `--state` finds it.
        let own = StoreUrl::Sqlite(dir.join(DB_FILE));
        if url != own {
            let text = match &url {
                StoreUrl::Postgres(u) => u.clone(),
                StoreUrl::Sqlite(p) => format!("sqlite:{}", p.display()),
            };
            write_private(&dir.join(crate::store::STORE_FILE), &format!("{text}\n"))
                .map_err(|e| state(format!("cannot write {}: {e}", crate::store::STORE_FILE)))?;
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            settings,
            store,
        })
    }

    /// Opens the challenge in `dir` (its store named by the directory).
    pub async fn open(dir: &Path) -> Result<Self, ChallengeError> {
        Self::open_with_store(dir, None).await
    }

    /// Opens the challenge in `dir` with its store at `store` (`None`: the
    /// one the directory names, the store's `url_of_state`).
    pub async fn open_with_store(
        dir: &Path,
        store: Option<&StoreUrl>,
    ) -> Result<Self, ChallengeError> {
        let url = crate::store::url_of_state(dir, store).map_err(ChallengeError::Run)?;
        if let StoreUrl::Sqlite(db) = &url
            && !db.is_file()
        {
            return Err(ChallengeError::State {
                path: dir.to_path_buf(),
                message: format!(
                    "holds no challenge ({DB_FILE} missing): run `stepsim challenge init` first"
                ),
            });
        }
        let store = crate::store::open(&url, false).await?;
        let meta = store.all_meta().await?;
        let db = PathBuf::from(url.shown());
        let get = |k: &str| -> Result<String, ChallengeError> {
            meta.get(k).cloned().ok_or_else(|| ChallengeError::State {
                path: db.clone(),
                message: format!("setting `{k}` is missing"),
            })
        };
        let num = |k: &str| -> Result<u64, ChallengeError> {
            get(k)?.parse().map_err(|_| ChallengeError::State {
                path: db.clone(),
                message: format!("setting `{k}` is not a number"),
            })
        };
        let settings = Settings {
            truth_dir: PathBuf::from(get("truth_dir")?),
            quota: num("quota")? as u32,
            max_upload_bytes: num("max_upload_bytes")?,
            format_failure_cap: num("format_failure_cap")? as u32,
            // Challenges made before the setting existed take the default.
            requests_per_minute: match meta.get("requests_per_minute") {
                Some(_) => num("requests_per_minute")? as u32,
                None => DEFAULT_REQUESTS_PER_MINUTE,
            },
            holdout: get("holdout")? == "true",
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            settings,
            store,
        })
    }

    /// Adds a team; returns its token (shown once; only its hash is kept).
    pub async fn add_team(&self, name: &str) -> Result<String, ChallengeError> {
        let name = name.trim();
        if name.is_empty() || name.chars().count() > 80 || name.chars().any(char::is_control) {
            return Err(ChallengeError::Team(
                "a team name must be 1 to 80 characters without control characters".into(),
            ));
        }
        if self.store.team_by_name(name).await?.is_some() {
            return Err(ChallengeError::Team(format!(
                "a team named {name:?} exists already"
            )));
        }
        let token = new_token()?;
        self.store
            .add_team(name, &token_hash(&token), crate::now_s())
            .await?;
        Ok(token)
    }

    async fn team_id(&self, name: &str) -> Result<i64, ChallengeError> {
        self.store
            .team_by_name(name)
            .await?
            .map(|t| t.id)
            .ok_or_else(|| ChallengeError::Team(format!("no team named {name:?}")))
    }

    /// Gives a team a new token (the old one stops working).
    pub async fn rotate_token(&self, name: &str) -> Result<String, ChallengeError> {
        let id = self.team_id(name).await?;
        let token = new_token()?;
        self.store.set_token(id, &token_hash(&token)).await?;
        Ok(token)
    }

    /// Revokes a team's token.
    pub async fn revoke(&self, name: &str) -> Result<(), ChallengeError> {
        let id = self.team_id(name).await?;
        Ok(self.store.revoke(id).await?)
    }

    /// True once revealed.
    pub async fn revealed(&self) -> Result<bool, ChallengeError> {
        Ok(self.store.meta("revealed").await?.as_deref() == Some("true"))
    }

    /// Reveals: held-out scores and full reports become visible. Reveal
    /// implies close (nothing changes any more).
    pub async fn reveal(&self) -> Result<(), ChallengeError> {
        self.store.set_meta("closed", "true").await?;
        Ok(self.store.set_meta("revealed", "true").await?)
    }

    /// Sets the challenge's name (shown to participants).
    pub async fn set_name(&self, name: &str) -> Result<(), ChallengeError> {
        let name = name.trim();
        if name.is_empty() || name.chars().count() > 200 || name.chars().any(char::is_control) {
            return Err(ChallengeError::Run(
                "a challenge name must be 1 to 200 characters without control characters".into(),
            ));
        }
        Ok(self.store.set_meta("name", name).await?)
    }

    /// Sets the cap on one upload in bytes (stored and after gzip
    /// decompression), replacing the run's own limit chosen at `init`; it
    /// takes effect when the server next starts.
    pub async fn set_max_upload_bytes(&mut self, bytes: u64) -> Result<(), ChallengeError> {
        if bytes == 0 {
            return Err(ChallengeError::Run(
                "--max-upload-bytes must be at least 1".into(),
            ));
        }
        self.store
            .set_meta("max_upload_bytes", &bytes.to_string())
            .await?;
        self.settings.max_upload_bytes = bytes;
        Ok(())
    }

    /// Sets (or, with `None`, removes) the deadline (Unix seconds): uploads
    /// from then on are refused as when frozen.
    pub async fn set_deadline(&self, at_s: Option<i64>) -> Result<(), ChallengeError> {
        match at_s {
            Some(t) => self.store.set_meta("deadline", &t.to_string()).await?,
            None => self.store.set_meta("deadline", "").await?,
        }
        Ok(())
    }

    /// Freezes: no more uploads; final choices are still allowed.
    pub async fn freeze(&self) -> Result<(), ChallengeError> {
        Ok(self.store.set_meta("frozen", "true").await?)
    }

    /// Closes: no more uploads and no more final choices.
    pub async fn close(&self) -> Result<(), ChallengeError> {
        self.store.set_meta("frozen", "true").await?;
        Ok(self.store.set_meta("closed", "true").await?)
    }

    /// Marks a team as participants' (ranked), organisers' or the baseline
    /// (shown, never ranked).
    pub async fn set_role(&self, name: &str, role: Role) -> Result<(), ChallengeError> {
        let id = self.team_id(name).await?;
        Ok(self.store.set_role(id, role).await?)
    }

    /// Queues every scored entry again for this binary's scorer
    /// ([`SCORER_VERSION`]), except those it has scored
    /// already; returns how many. Old scores are kept.
    pub async fn rescore(&self) -> Result<usize, ChallengeError> {
        Ok(self.store.rescore(SCORER_VERSION).await?)
    }

    /// Stores the organiser password as an Argon2id PHC hash (a random
    /// salt; the password itself is never stored).
    pub async fn set_organiser_password(&self, password: &str) -> Result<(), ChallengeError> {
        use argon2::password_hash::{PasswordHasher, SaltString};
        if password.chars().count() < 8 {
            return Err(ChallengeError::Run(
                "the organiser password must have at least 8 characters".into(),
            ));
        }
        let mut salt = [0u8; 16];
        getrandom::fill(&mut salt)
            .map_err(|e| ChallengeError::Run(format!("cannot draw a salt: {e}")))?;
        let salt = SaltString::encode_b64(&salt)
            .map_err(|e| ChallengeError::Run(format!("cannot encode the salt: {e}")))?;
        let hash = argon2::Argon2::default()
            .hash_password(password.as_bytes(), &salt)
            .map_err(|e| ChallengeError::Run(format!("cannot hash the password: {e}")))?;
        Ok(self
            .store
            .set_meta(ORGANISER_PASSWORD_KEY, &hash.to_string())
            .await?)
    }

    /// True when `password` is the organiser password (false when none is
    /// set). See [`verify_organiser_password`].
    pub async fn verify_organiser_password(&self, password: &str) -> bool {
        verify_organiser_password(self.store.as_ref(), password).await
    }

    /// Where an upload with this SHA-256 is kept.
    pub fn upload_path(&self, sha256: &str) -> PathBuf {
        self.dir.join("uploads").join(sha256)
    }

    /// Where the reports of entry `id` for a part are kept.
    pub fn entry_dir(&self, id: i64, part: stepsim_contract::run_layout::Part) -> PathBuf {
        self.dir
            .join("entries")
            .join(id.to_string())
            .join(part.name())
    }
}

/// Writes `text` to a new file at `path` readable by its owner only.
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut o, 0o600);
    let mut f = o.open(path)?;
    f.write_all(text.as_bytes())?;
    f.sync_all()
}

/// The setting that holds the organiser password's PHC hash.
pub const ORGANISER_PASSWORD_KEY: &str = "organiser_password_phc";

/// True when `password` is the organiser password stored by
/// [`Challenge::set_organiser_password`]; false when none is set, the
/// store fails or the hash cannot be read (never panics).
pub async fn verify_organiser_password(store: &dyn Store, password: &str) -> bool {
    let Ok(Some(phc)) = store.meta(ORGANISER_PASSWORD_KEY).await else {
        return false;
    };
    let password = password.to_owned();
    tokio::task::spawn_blocking(move || verify_phc(&phc, &password))
        .await
        .unwrap_or(false)
}

/// True when `password` matches the PHC hash `phc` (Argon2). Slow by
/// design (tens of ms): callers do not hold the store while it runs.
pub fn verify_phc(phc: &str, password: &str) -> bool {
    use argon2::password_hash::{PasswordHash, PasswordVerifier};
    let Ok(hash) = PasswordHash::new(phc) else {
        return false;
    };
    argon2::Argon2::default()
        .verify_password(password.as_bytes(), &hash)
        .is_ok()
}
