//! The images of a run in canonical order ([`Job`]), with their opaque ids
//! from the run's blinding key.

use super::{GenerateError, claim};
use crate::run::blind::BlindingKey;
use crate::run::plan::Plan;
use stepsim_contract::digest::sha256_hex;
use stepsim_contract::run_dir::PublicDir;
use stepsim_contract::seed::{SeedKey, Stream};

/// One image of the run.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// Position in the canonical order (for sharding).
    pub order: usize,
    /// Base field.
    pub field: u32,
    /// 90°-rotated twin of the base field.
    pub rotated: bool,
    /// Dataset index in [`Plan::datasets`].
    pub dataset: u32,
    /// Opaque dataset id.
    pub dataset_id: String,
    /// Opaque image id.
    pub image_id: String,
}

impl Job {
    /// Image path relative to `public/`.
    pub fn public_file(&self) -> String {
        PublicDir::image_file(&self.dataset_id, &self.image_id)
    }
    /// Key of the image's noise.
    pub fn noise_key(&self, run_seed: u64) -> SeedKey {
        SeedKey::image(run_seed, self.field, self.dataset, Stream::Noise)
            .with_index(u64::from(self.rotated))
    }
}

/// The blinding key of a run: from its seed and resolved config
/// ([`BlindingKey::for_run`] of `claim::config_json`).
pub fn blinding_key(plan: &Plan) -> BlindingKey {
    BlindingKey::for_run(plan.seed(), claim::config_json(plan).as_bytes())
}

/// SHA-256 of a run's `private/config.json` (recorded in every sidecar).
pub fn config_sha256(plan: &Plan) -> String {
    sha256_hex(claim::config_json(plan).as_bytes())
}

/// Every image of a plan in canonical order, with its opaque ids.
pub fn jobs(plan: &Plan, key: &BlindingKey) -> Result<Vec<Job>, GenerateError> {
    let rotations: &[bool] = if plan.rotated_pairs() {
        &[false, true]
    } else {
        &[false]
    };
    let dataset_ids: Vec<String> = plan
        .datasets()
        .iter()
        .map(|d| key.dataset_id(d.index))
        .collect();
    let mut out = Vec::new();
    for field in 0..plan.n_fields() {
        for &rotated in rotations {
            for d in plan.datasets().iter().filter(|d| d.fields.contains(&field)) {
                out.push(Job {
                    order: out.len(),
                    field,
                    rotated,
                    dataset: d.index,
                    dataset_id: dataset_ids[d.index as usize].clone(),
                    image_id: key.image_id(d.index, field, rotated),
                });
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    for id in dataset_ids.iter().chain(out.iter().map(|j| &j.image_id)) {
        if !seen.insert(id.as_str()) {
            return Err(GenerateError::IdCollision { id: id.clone() });
        }
    }
    Ok(out)
}
