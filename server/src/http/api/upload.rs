//! Uploads (`POST /api/submissions`, and the page's upload form through
//! `submit`): the turn among uploads in flight, the quota, the streamed
//! copy, the harness's format check and the store's admission.

use crate::challenge::admission::{Refusal, RefusalKind, admission_refusal, limits};
use crate::challenge::{Phase, QUOTA_WINDOW_S};
use crate::http::auth::auth;
use crate::http::{ApiError, ApiResult, AppState};
use crate::store::Team;
use axum::body::Body;
use axum::extract::{FromRequest, Request, State};
use axum::http::{StatusCode, header};
use axum::response::IntoResponse;
use http_body_util::BodyExt;
use serde_json::json;
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use stepsim_contract::digest::hex;
use tokio::io::AsyncWriteExt;

/// The small form fields sent before a multipart upload's `file` (name,
/// value), as [`submit`]'s check sees them; empty for a raw body.
pub(crate) type FormFields = [(String, String)];

/// At most this many fields, of at most [`FIELD_MAX_BYTES`] each, may come
/// before a multipart upload's `file`.
const MAX_FIELDS: usize = 16;

const FIELD_MAX_BYTES: usize = 1024;

/// Streams the upload (raw body or multipart field `file`) into a temporary
/// file under `uploads/`, capped at `max` bytes; returns (path, SHA-256, size).
/// `check` sees the fields sent before `file` (nothing for a raw body) and
/// may refuse before a byte of the file is kept.
async fn receive(
    state: &AppState,
    req: Request,
    max: u64,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<(PathBuf, String, u64), ApiError> {
    let mut check = Some(check);
    let cut = req
        .extensions()
        .get::<crate::http::net::BodyCut>()
        .map(|c| c.0.clone());
    let limits = state.inner.limits.clone();
    // A body error: 408 when the body guard cut it off, else 400.
    let broke = |text: String| {
        if cut.as_ref().is_some_and(|c| c.load(Ordering::SeqCst)) {
            ApiError::new(
                StatusCode::REQUEST_TIMEOUT,
                format!(
                    "the upload arrived too slowly and was cut off: nothing for {} s, or less \
                     than {} bytes per second on average after the first {} s",
                    limits.body_stall_timeout.as_secs(),
                    limits.body_min_bytes_per_s,
                    limits.body_grace.as_secs()
                ),
            )
        } else {
            ApiError::new(StatusCode::BAD_REQUEST, text)
        }
    };
    let too_big = || {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the upload is larger than the limit of {max} bytes"),
        )
    };
    if let Some(len) = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        // A multipart body carries a little framing beyond the file.
        if len > max + 64 * 1024 {
            return Err(too_big());
        }
    }
    let mut nonce = [0u8; 12];
    getrandom::fill(&mut nonce).map_err(ApiError::internal)?;
    let tmp = state
        .inner
        .dir
        .join("uploads")
        .join(format!(".{}.tmp", hex(&nonce)));
    let mut file = tokio::fs::File::create(&tmp)
        .await
        .map_err(ApiError::internal)?;
    let result: Result<(String, u64), ApiError> = async {
        let mut hasher = Sha256::new();
        let mut size: u64 = 0;
        let mut sink = async |chunk: &[u8]| -> Result<(), ApiError> {
            size += chunk.len() as u64;
            if size > max {
                return Err(too_big());
            }
            hasher.update(chunk);
            file.write_all(chunk).await.map_err(ApiError::internal)
        };
        let multipart = req
            .headers()
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.starts_with("multipart/form-data"));
        if multipart {
            let mut mp = axum::extract::Multipart::from_request(req, state)
                .await
                .map_err(|e| broke(e.body_text()))?;
            let mut found = false;
            let mut fields: Vec<(String, String)> = Vec::new();
            while let Some(mut field) = mp.next_field().await.map_err(|e| broke(e.body_text()))? {
                if found {
                    continue;
                }
                if field.name() != Some("file") {
                    // Read in chunks, capped: a huge field is refused, never buffered.
                    if fields.len() >= MAX_FIELDS {
                        return Err(ApiError::new(
                            StatusCode::BAD_REQUEST,
                            "the multipart form has too many or too large fields before `file`",
                        ));
                    }
                    let name = field.name().unwrap_or_default().to_string();
                    let mut value = Vec::new();
                    while let Some(chunk) = field.chunk().await.map_err(|e| broke(e.body_text()))? {
                        value.extend_from_slice(&chunk);
                        if value.len() > FIELD_MAX_BYTES {
                            return Err(ApiError::new(
                                StatusCode::BAD_REQUEST,
                                "the multipart form has too many or too large fields before `file`",
                            ));
                        }
                    }
                    fields.push((name, String::from_utf8_lossy(&value).into_owned()));
                    continue;
                }
                found = true;
                if let Some(c) = check.take() {
                    c(&fields)?;
                }
                while let Some(chunk) = field.chunk().await.map_err(|e| broke(e.body_text()))? {
                    sink(chunk.as_ref()).await?;
                }
            }
            if !found {
                return Err(ApiError::new(
                    StatusCode::BAD_REQUEST,
                    "the multipart form has no field `file`",
                ));
            }
        } else {
            if let Some(c) = check.take() {
                c(&[])?;
            }
            let mut body: Body = req.into_body();
            while let Some(frame) = body.frame().await {
                let frame = frame.map_err(|e| broke(format!("the upload broke off: {e}")))?;
                if let Some(data) = frame.data_ref() {
                    sink(data.as_ref()).await?;
                }
            }
        }
        file.sync_all().await.map_err(ApiError::internal)?;
        Ok((hex(&hasher.finalize()), size))
    }
    .await;
    match result {
        Ok((sha, size)) => Ok((tmp, sha, size)),
        Err(e) => {
            let _ = tokio::fs::remove_file(&tmp).await;
            Err(e)
        }
    }
}

/// Refuses with 429 when a team has used its quota of accepted uploads
/// (counting its other uploads admitted by this check and still arriving
/// or being checked), or its cap on refused ones, in the last 24 hours;
/// else admits `slot`. The count of admitted uploads is read and the
/// slot admitted under one lock, after the store's read, and an upload
/// leaves the admitted before its insert: so no upload is counted twice,
/// in the store and in flight (counting the uploads in flight when the
/// slot was taken, before the store's read, refused all but one of six
/// parallel uploads under a quota of two on a loaded machine), and one
/// this check refuses never counts against another. An upload inserted
/// between the read and the lock is in neither count and one more may be
/// admitted; the insert's transaction holds the quota then.
async fn check_limits(state: &AppState, slot: &mut UploadSlot) -> Result<(), ApiError> {
    let since = crate::now_s() - QUOTA_WINDOW_S;
    let store = state.store();
    let accepted = store
        .accepted_since(slot.team_id, since)
        .await
        .map_err(ApiError::internal)?;
    let refused = store
        .format_failures_since(slot.team_id, since)
        .await
        .map_err(ApiError::internal)?;
    let mut map = team_uploads(state);
    let team = map.entry(slot.team_id).or_default();
    match limits(&state.inner.settings, &accepted, &refused, team.admitted) {
        Some(r) => Err(refusal_answer(r)),
        None => {
            team.admitted += 1;
            slot.admitted = true;
            Ok(())
        }
    }
}

/// The answer to a refused upload: 403 for the phase, 429 for the quota
/// and the refusal cap (with the time of the next possible upload).
fn refusal_answer(r: Refusal) -> ApiError {
    let status = match r.kind {
        RefusalKind::Phase => StatusCode::FORBIDDEN,
        RefusalKind::Quota | RefusalKind::RefusalCap => StatusCode::TOO_MANY_REQUESTS,
    };
    ApiError {
        reset_s: r.reset_s,
        ..ApiError::new(status, r.message)
    }
}

/// The teams' uploads in flight, locked (a poisoned lock is taken as it
/// is: the counts stay whole, each change is one statement).
fn team_uploads(
    state: &AppState,
) -> std::sync::MutexGuard<'_, std::collections::HashMap<i64, TeamUploads>> {
    state
        .inner
        .uploads
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A team's uploads being received or checked now.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct TeamUploads {
    /// Holding a slot.
    slots: usize,
    /// Of those, admitted by the quota's check ([`check_limits`]).
    admitted: usize,
}

/// An upload of one team counted as in flight (being received or
/// checked) until it is dropped; holds a turn of all uploads at once.
struct UploadSlot {
    state: AppState,
    team_id: i64,
    /// Counted in its team's admitted uploads.
    admitted: bool,
    _all: tokio::sync::OwnedSemaphorePermit,
}

impl UploadSlot {
    /// Takes a slot for `team_id`: 429 when the team has
    /// `uploads_per_team` in flight, 503 when the server has
    /// `uploads_at_once`.
    fn take(state: &AppState, team_id: i64) -> Result<Self, ApiError> {
        let l = &state.inner.limits;
        let mut map = team_uploads(state);
        let n = map.get(&team_id).map_or(0, |t| t.slots);
        if n >= l.uploads_per_team.max(1) {
            return Err(ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "{n} upload(s) of your team are still arriving or being checked; at most {} \
                     at once: send the next when it is answered",
                    l.uploads_per_team.max(1)
                ),
            ));
        }
        let all = state
            .inner
            .uploads_all
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError {
                reset_s: Some(crate::now_s() + 60),
                ..ApiError::new(
                    StatusCode::SERVICE_UNAVAILABLE,
                    format!(
                        "the server is receiving {} uploads already; send yours again in a minute \
                         (nothing was counted)",
                        l.uploads_at_once.max(1)
                    ),
                )
            })?;
        map.entry(team_id).or_default().slots += 1;
        Ok(Self {
            state: state.clone(),
            team_id,
            admitted: false,
            _all: all,
        })
    }
}

impl UploadSlot {
    /// No longer counted among its team's admitted uploads (it is about
    /// to be in the store, or is gone).
    fn leave_admitted(&mut self) {
        if !std::mem::take(&mut self.admitted) {
            return;
        }
        if let Some(t) = team_uploads(&self.state).get_mut(&self.team_id) {
            t.admitted = t.admitted.saturating_sub(1);
        }
    }
}

impl Drop for UploadSlot {
    fn drop(&mut self) {
        self.leave_admitted();
        let mut map = team_uploads(&self.state);
        if let Some(t) = map.get_mut(&self.team_id) {
            t.slots = t.slots.saturating_sub(1);
            if t.slots == 0 {
                map.remove(&self.team_id);
            }
        }
    }
}

/// The harness's format check of the upload at `tmp`, at most
/// `checks_at_once` at a time, within `check_budget` of wall-clock time
/// (its wait for a turn included). `Ok(Err(message))` is the harness's
/// refusal; `Err` is the server's (the budget, 503), not the participant's.
async fn format_check(
    state: &AppState,
    tmp: &std::path::Path,
) -> Result<Result<(), String>, ApiError> {
    let l = &state.inner.limits;
    let settings = state.inner.settings.clone();
    let checks = state.inner.checks.clone();
    let tmp2 = tmp.to_path_buf();
    let run = async move {
        let permit = checks.acquire_owned().await.map_err(ApiError::internal)?;
        // The harness call cannot be stopped: past the budget it goes on
        // (holding its turn, so checks at once stay bounded) and its
        // result is dropped.
        tokio::task::spawn_blocking(move || {
            let _turn = permit;
            let opts = crate::worker::upload_options(&settings, &tmp2);
            stepsim_harness::prepare(&opts).map(drop).map_err(|e| {
                if crate::worker::organisers_fault(&e) {
                    tracing::error!(error = %e, "the run cannot be read: uploads are not checked");
                    None
                } else {
                    Some(crate::worker::participant_message(
                        &e.to_string(),
                        &tmp2,
                        &settings.truth_dir,
                    ))
                }
            })
        })
        .await
        .map_err(ApiError::internal)
    };
    match tokio::time::timeout(l.check_budget, run).await {
        // The run itself cannot be read: not the upload's fault, so it is
        // neither counted nor told what is wrong with the private files.
        Ok(Err(e)) => Err(e),
        Ok(Ok(Ok(()))) => Ok(Ok(())),
        Ok(Ok(Err(Some(message)))) => Ok(Err(message)),
        Ok(Ok(Err(None))) => Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the server cannot check uploads now (its run cannot be read; the organisers are \
             told); the upload was not kept and not counted against your team"
                .to_string(),
        )),
        Err(_) => Err(ApiError {
            reset_s: Some(crate::now_s() + 60),
            ..ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the server could not check the upload within {} s (it is busy); it was not \
                     kept and not counted against your team: send it again later",
                    l.check_budget.as_secs()
                ),
            )
        }),
    }
}

pub(crate) async fn post_submission(State(state): State<AppState>, req: Request) -> ApiResult {
    let team = auth(&state, req.headers()).await?;
    let accepted = submit(&state, &team, req, |_| Ok(())).await?;
    Ok(if accepted.duplicate {
        (
            StatusCode::OK,
            axum::Json(json!({"id": accepted.id, "status": accepted.status, "duplicate": true})),
        )
    } else {
        (
            StatusCode::ACCEPTED,
            axum::Json(json!({"id": accepted.id, "status": "queued"})),
        )
    }
    .into_response())
}

/// What [`submit`] made of an upload.
#[derive(Debug)]
pub(crate) struct Accepted {
    /// The entry's id.
    pub(crate) id: i64,
    /// Its status now (`queued` for a new one).
    pub(crate) status: String,
    /// True when the team had uploaded these bytes before (that entry).
    pub(crate) duplicate: bool,
}

/// An upload of `team` (raw body or multipart field `file`): the limits,
/// the streamed copy with its SHA-256, the harness's format check, the
/// duplicate check, the immutable file and the queue. The one path of both
/// `POST /api/submissions` and the page's upload form; `check` sees the
/// form's fields before the file (the form's CSRF token).
pub(crate) async fn submit(
    state: &AppState,
    team: &Team,
    req: Request,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<Accepted, ApiError> {
    let result = receive_and_queue(state, team, req, check).await;
    let status = match &result {
        Ok(a) if a.duplicate => {
            tracing::info!(
                team = team.id,
                entry = a.id,
                "upload: a duplicate of an entry"
            );
            StatusCode::OK
        }
        Ok(a) => {
            tracing::info!(team = team.id, entry = a.id, "upload accepted and queued");
            StatusCode::ACCEPTED
        }
        Err(e) => {
            tracing::info!(
                team = team.id,
                status = e.status.as_u16(),
                reason = %crate::observe::first_line(&e.message),
                "upload refused"
            );
            e.status
        }
    };
    state.metrics().upload(status.as_u16());
    result
}

/// [`submit`]'s work, before it is logged and counted.
async fn receive_and_queue(
    state: &AppState,
    team: &Team,
    req: Request,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<Accepted, ApiError> {
    if state.live_workers() == Some(0) {
        tracing::error!("no scoring worker runs; uploads are refused");
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the scoring queue is not running, so uploads are not accepted; nothing was \
             counted. The organisers have been told by the server's log",
        ));
    }
    let phase = Phase::read(state.store())
        .await
        .map_err(ApiError::internal)?;
    if let Some(why) = phase.upload_refusal(crate::now_s()) {
        return Err(ApiError::new(StatusCode::FORBIDDEN, why));
    }
    // Before a byte of the body is read: a turn among the team's and all
    // uploads at once, and the quota counting the team's uploads in flight.
    let mut slot = UploadSlot::take(state, team.id)?;
    check_limits(state, &mut slot).await?;
    let max = state.inner.settings.max_upload_bytes;
    let (tmp, sha, size) = receive(state, req, max, check).await?;
    // The format check: the harness reads the whole upload against every
    // image of the run, as `stepsim score` does.
    let check = match format_check(state, &tmp).await {
        Ok(c) => c,
        Err(e) => {
            let _ = tokio::fs::remove_file(&tmp).await;
            return Err(e);
        }
    };
    if let Err(message) = check {
        let _ = tokio::fs::remove_file(&tmp).await;
        state
            .store()
            .add_format_failure(team.id, &message, crate::now_s())
            .await
            .map_err(ApiError::internal)?;
        return Err(ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, message));
    }
    // The phase, the duplicate check, the quota and the insert again, in
    // one transaction of the store that holds the team: the phase may have
    // changed during a slow upload (a body sent until after the deadline
    // or the reveal), and parallel uploads of one team, on any host, must
    // not all pass the quota. Only accepted entries count here: the uploads
    // admitted while this one was (`check_limits`) have been counted
    // before its body was read, and those that finished since are in the
    // store (counting them again refused the second of two parallel
    // uploads under a quota of 2).
    let refuse = |e: ApiError| {
        let _ = std::fs::remove_file(&tmp);
        e
    };
    let final_path = state.inner.dir.join("uploads").join(&sha);
    // The file goes in place first (named by its hash: the same bytes are
    // the same file), so that no worker of any host finds an entry without
    // its upload.
    if final_path.exists() {
        let _ = std::fs::remove_file(&tmp);
    } else {
        std::fs::rename(&tmp, &final_path).map_err(|e| refuse(ApiError::internal(e)))?;
        if let Ok(d) = std::fs::File::open(state.inner.dir.join("uploads")) {
            let _ = d.sync_all();
        }
    }
    let now = crate::now_s();
    let settings = state.inner.settings.clone();
    let rule: crate::store::Rule =
        Arc::new(move |l| admission_refusal(&settings, l, now).is_none());
    // From here the store counts it: an upload whose check reads the
    // store after this insert must not count it among the admitted too.
    slot.leave_admitted();
    let admitted = state
        .store()
        .admit(team.id, &sha, size as i64, now, now - QUOTA_WINDOW_S, rule)
        .await
        .map_err(ApiError::internal)?;
    match admitted {
        crate::store::Admission::Inserted(id) => Ok(Accepted {
            id,
            status: "queued".into(),
            duplicate: false,
        }),
        crate::store::Admission::Duplicate(id, status) => Ok(Accepted {
            id,
            status,
            duplicate: true,
        }),
        // The file stays: it is named by its hash, and an entry of this or
        // another team may hold the same bytes.
        crate::store::Admission::Declined(ledger) => {
            Err(admission_refusal(&state.inner.settings, &ledger, now)
                .map(refusal_answer)
                .unwrap_or_else(|| {
                    ApiError::internal("the admission was declined without a reason")
                }))
        }
    }
}
