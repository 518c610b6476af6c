//! `challenge` section: the held-out part of a challenge run.
//!
//! A run made for `stepsim serve` keeps some base fields (each with its
//! rotated twin) apart: they appear only in datasets of their own, whose
//! shears are drawn at random in the disc |g| ≤ `holdout_g_max` from a keyed
//! stream and recorded only in `private/`. The public part keeps the
//! configured PSF × shear design on the other base fields. Nothing in
//! `public/` tells the two parts apart (docs/server.md, "Threat model").

use super::{Invalid, short_number};
use serde::{Deserialize, Serialize};

/// `challenge`: how many base fields are held out, and their shears' range.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawChallenge {
    /// Base fields (each with its rotated twin) held out; 0 (the default)
    /// makes an ordinary run. When not 0 it must be half of
    /// `image.n_images`, so that every dataset holds the same number of
    /// images and the directory sizes cannot tell the parts apart.
    pub holdout_fields: u32,
    /// Held-out datasets carry shears drawn uniformly in the disc
    /// |g| ≤ `holdout_g_max` (default 0.1, the largest STEP1 shear).
    pub holdout_g_max: f64,
}

impl Default for RawChallenge {
    fn default() -> Self {
        Self {
            holdout_fields: 0,
            holdout_g_max: 0.1,
        }
    }
}

impl RawChallenge {
    /// True for the default section (it is then left out of the resolved
    /// config, so that runs made before the section existed keep their
    /// `private/config.json`, blinding key and ids).
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Checks the section against the number of base fields.
    pub(crate) fn validate(&self, n_fields: u32) -> Result<(), Invalid> {
        let g = self.holdout_g_max;
        if !(g.is_finite() && g > 0.0 && g < 1.0) {
            return Err(Invalid::new(
                "challenge.holdout_g_max".into(),
                format!("must be > 0 and < 1, got {}", short_number(g)),
            ));
        }
        let h = self.holdout_fields;
        if h != 0 && u64::from(h) * 2 != u64::from(n_fields) {
            return Err(Invalid::new(
                "challenge.holdout_fields".into(),
                format!(
                    "must be 0 or half of image.n_images ({n_fields}), got {h}: public and \
                     held-out datasets must hold the same number of images, or the size of \
                     a dataset's directory would tell which part it belongs to"
                ),
            ));
        }
        Ok(())
    }
}
