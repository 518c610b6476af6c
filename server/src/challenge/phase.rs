//! Where a challenge stands: its deadline and whether it is frozen,
//! closed or revealed.

use crate::store::{Store, StoreError};

/// Where a challenge stands: its deadline and whether it is frozen, closed
/// or revealed (settings `deadline`, `frozen`, `closed`, `revealed`).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Phase {
    /// The deadline (Unix seconds), if one is set.
    pub deadline_s: Option<i64>,
    /// No more uploads (`challenge freeze`).
    pub frozen: bool,
    /// Nothing changes any more (`challenge close`, or reveal).
    pub closed: bool,
    /// Held-out scores are open.
    pub revealed: bool,
}

impl Phase {
    /// The phase recorded in a store.
    pub async fn read(store: &dyn Store) -> Result<Self, StoreError> {
        Ok(Self::of_meta(&store.all_meta().await?))
    }

    /// The phase of the settings `meta`.
    pub fn of_meta(meta: &std::collections::HashMap<String, String>) -> Self {
        let flag = |k: &str| meta.get(k).map(String::as_str) == Some("true");
        Self {
            deadline_s: meta.get("deadline").and_then(|v| v.parse().ok()),
            frozen: flag("frozen"),
            closed: flag("closed"),
            revealed: flag("revealed"),
        }
    }

    /// Why an upload at `now_s` is refused, if it is (closed, frozen, or
    /// past the deadline).
    pub fn upload_refusal(&self, now_s: i64) -> Option<String> {
        if self.closed {
            Some("the challenge is closed: no more uploads are accepted".into())
        } else if self.frozen {
            Some("the challenge is frozen: no more uploads are accepted".into())
        } else {
            self.deadline_s.filter(|&d| now_s >= d).map(|d| {
                format!(
                    "the deadline ({}) has passed: no more uploads are accepted",
                    crate::utc_text(d)
                )
            })
        }
    }

    /// True when uploads are accepted at `now_s`.
    pub fn uploads_open(&self, now_s: i64) -> bool {
        self.upload_refusal(now_s).is_none()
    }
}
