//! The figures of a scored entry, typed.
//!
//! The worker stores the harness's result as JSON text: the public part as
//! `stepsim_harness::PublicFeedback`, the held-out part as
//! `stepsim_harness::Summary` (or `{"error": ...}` when that part
//! could not be scored). They are read back here, once, into the harness's
//! own types; the ranking and the pages read fields, never keys, so a
//! renamed figure is a compile error and not a blank cell. The JSON API
//! still sends the stored text as it is ([`stored_json`]).

#[cfg(test)]
use crate::store::Submission;
use serde::Deserialize;
use stepsim_harness::{PublicFeedback, Summary};

/// An entry's public feedback: the harness's rounded aggregate.
pub type PublicFigures = PublicFeedback;

/// An entry's held-out result.
#[derive(Debug, Clone, PartialEq)]
pub enum HoldoutFigures {
    /// The harness's summary of the held-out part.
    Summary(Box<Summary>),
    /// The held-out part could not be scored: the message, kept secret
    /// until reveal like any held-out figure.
    Failed(String),
}

/// The stored form of [`HoldoutFigures::Failed`].
#[derive(Deserialize)]
struct FailedPart {
    error: String,
}

impl HoldoutFigures {
    /// The held-out figures of a stored text; `None` when there is none or
    /// it cannot be read.
    pub fn of_text(text: Option<&str>) -> Option<Self> {
        let text = text?;
        // A summary has no `error` key, so this reads only a failure.
        if let Ok(f) = serde_json::from_str::<FailedPart>(text) {
            return Some(Self::Failed(f.error));
        }
        serde_json::from_str::<Summary>(text)
            .ok()
            .map(|s| Self::Summary(Box::new(s)))
    }

    /// The summary, when the part was scored.
    pub fn summary(&self) -> Option<&Summary> {
        match self {
            Self::Summary(s) => Some(s),
            Self::Failed(_) => None,
        }
    }

    /// The held-out ⟨m⟩.
    pub fn m_mean(&self) -> Option<f64> {
        self.summary().and_then(|s| s.m_mean)
    }

    /// The held-out σ_c.
    pub fn sigma_c(&self) -> Option<f64> {
        self.summary().and_then(|s| s.sigma_c)
    }

    /// The held-out Q_c.
    pub fn q_c(&self) -> Option<f64> {
        self.summary().and_then(|s| s.q_c)
    }

    /// The 95 % bootstrap interval of Q_c, when the report has one with
    /// finite ends.
    pub fn q_c_interval(&self) -> Option<[f64; 2]> {
        let [lo, hi] = self.summary()?.bootstrap.as_ref()?.q_c?;
        (lo.is_finite() && hi.is_finite()).then_some([lo, hi])
    }
}

/// The public feedback of a stored text; `None` when there is none or it
/// cannot be read.
pub fn public_of_text(text: Option<&str>) -> Option<PublicFigures> {
    text.and_then(|t| serde_json::from_str(t).ok())
}

/// Both parts' figures of an entry, as far as it has them (the tests'
/// view of what is stored).
#[cfg(test)]
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Figures {
    /// The public feedback (once scored).
    pub public: Option<PublicFigures>,
    /// The held-out result (once scored, on a run with a held-out part).
    pub holdout: Option<HoldoutFigures>,
}

#[cfg(test)]
impl Figures {
    /// The figures stored for `sub`.
    pub fn of(sub: &Submission) -> Self {
        Self {
            public: public_of_text(sub.public_json.as_deref()),
            holdout: HoldoutFigures::of_text(sub.holdout_json.as_deref()),
        }
    }
}

/// The key by which entries are compared on `q_c` and `m_mean` (smaller
/// is better): higher Q_c, then smaller |⟨m⟩|. A figure missing counts as
/// the worst.
pub fn rank_key(q_c: Option<f64>, m_mean: Option<f64>) -> (f64, f64) {
    (
        -q_c.unwrap_or(f64::NEG_INFINITY),
        m_mean.map_or(f64::INFINITY, f64::abs),
    )
}

/// [`rank_key`] of a public feedback (the worst when there is none).
pub fn public_rank_key(public: Option<&PublicFigures>) -> (f64, f64) {
    rank_key(public.and_then(|p| p.q_c), public.and_then(|p| p.m_mean))
}

/// [`rank_key`] of a held-out result (the worst when there is none or it
/// failed).
pub fn holdout_rank_key(holdout: Option<&HoldoutFigures>) -> (f64, f64) {
    rank_key(
        holdout.and_then(HoldoutFigures::q_c),
        holdout.and_then(HoldoutFigures::m_mean),
    )
}

/// A stored JSON text as the API sends it: the value as written (`null`
/// when absent or unreadable).
pub fn stored_json(text: Option<&str>) -> serde_json::Value {
    text.and_then(|t| serde_json::from_str(t).ok())
        .unwrap_or(serde_json::Value::Null)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stepsim_harness::BootstrapCi;

    /// A submission holding `public` and `holdout` as the worker stores
    /// them.
    fn stored(public: Option<String>, holdout: Option<String>) -> Submission {
        Submission {
            id: 7,
            team_id: 1,
            sha256: "00".into(),
            bytes: 1,
            created_s: 0,
            status: "scored".into(),
            error: None,
            public_json: public,
            holdout_json: holdout,
            n_scorings: 1,
            scorer_version: Some(crate::challenge::SCORER_VERSION.into()),
            final_choice: false,
            worker: None,
        }
    }

    /// Every figure set, each to a value of its own.
    fn full_summary() -> Summary {
        let ci = |k: f64| Some([k, k + 0.5]);
        Summary {
            m_mean: Some(0.011),
            q_mean: Some(0.012),
            sigma_c: Some(0.0013),
            m_uncontaminated_mean: Some(0.014),
            m_selc_mean: Some(0.015),
            sigma_c_selc: Some(0.0016),
            m_weight_mean: Some(0.017),
            m_isolated_mean: Some(0.018),
            sigma_c_isolated: Some(0.0019),
            q_c: Some(123.25),
            pct_chance_match: Some(0.2),
            bootstrap: Some(BootstrapCi {
                n_resamples: 200,
                seed: 3,
                confidence: 0.95,
                base_fields: Some(8),
                widening: Some(1.1),
                m_mean: ci(1.0),
                q_mean: ci(2.0),
                sigma_c: ci(3.0),
                m_uncontaminated_mean: ci(4.0),
                m_selc_mean: ci(5.0),
                sigma_c_selc: ci(6.0),
                m_weight_mean: ci(7.0),
                q_c: Some([110.5, 140.75]),
                m_isolated_mean: ci(8.0),
                sigma_c_isolated: ci(9.0),
            }),
        }
    }

    #[test]
    fn the_harness_figures_read_back_field_for_field() {
        let public = PublicFeedback {
            m_mean: Some(-0.012),
            sigma_c: Some(0.0021),
            q_c: Some(87.0),
            pct_stars: Some(1.5),
            pct_false: Some(0.25),
        };
        let summary = full_summary();
        // As the worker writes them (worker::score_upload_unless).
        let sub = stored(
            Some(serde_json::to_string(&public).unwrap()),
            Some(serde_json::to_string(&summary).unwrap()),
        );
        let f = Figures::of(&sub);
        let p = f.public.as_ref().unwrap();
        assert_eq!(p, &public);
        assert_eq!(
            [p.m_mean, p.sigma_c, p.q_c, p.pct_stars, p.pct_false],
            [
                public.m_mean,
                public.sigma_c,
                public.q_c,
                public.pct_stars,
                public.pct_false
            ]
        );
        let h = f.holdout.as_ref().unwrap();
        assert_eq!(h.summary(), Some(&summary));
        assert_eq!(h.m_mean(), summary.m_mean);
        assert_eq!(h.sigma_c(), summary.sigma_c);
        assert_eq!(h.q_c(), summary.q_c);
        assert_eq!(h.q_c_interval(), Some([110.5, 140.75]));
        assert_eq!(public_rank_key(Some(p)), (-87.0, 0.012));
        assert_eq!(holdout_rank_key(Some(h)), (-123.25, 0.011));
        // The API sends the stored text as it is.
        assert_eq!(
            stored_json(sub.public_json.as_deref()),
            serde_json::from_str::<serde_json::Value>(sub.public_json.as_deref().unwrap()).unwrap()
        );
    }

    #[test]
    fn a_failed_part_missing_figures_and_bad_text_read_as_such() {
        let sub = stored(
            Some(
                r#"{"m_mean":null,"sigma_c":null,"q_c":null,"pct_stars":null,"pct_false":null}"#
                    .into(),
            ),
            Some(r#"{"error":"the scorer failed on the held-out part"}"#.into()),
        );
        let f = Figures::of(&sub);
        assert_eq!(f.public.as_ref().unwrap().q_c, None);
        assert_eq!(
            f.holdout,
            Some(HoldoutFigures::Failed(
                "the scorer failed on the held-out part".into()
            ))
        );
        let h = f.holdout.as_ref().unwrap();
        assert_eq!((h.q_c(), h.m_mean(), h.q_c_interval()), (None, None, None));
        // Missing figures rank last.
        assert_eq!(holdout_rank_key(Some(h)), (f64::INFINITY, f64::INFINITY));
        assert_eq!(public_rank_key(None), (f64::INFINITY, f64::INFINITY));
        let none = Figures::of(&stored(None, Some("not json".into())));
        assert_eq!(none, Figures::default());
        assert_eq!(stored_json(Some("not json")), serde_json::Value::Null);
        // An interval with an end that is not finite is none.
        let mut s = full_summary();
        s.bootstrap.as_mut().unwrap().q_c = Some([f64::NEG_INFINITY, 1.0]);
        assert_eq!(HoldoutFigures::Summary(Box::new(s)).q_c_interval(), None);
    }
}
