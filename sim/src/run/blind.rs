//! Opaque dataset and image ids (SPEC §5): the public half of a run must not
//! reveal which PSF or shear an image has, nor the order of the datasets.
//!
//! A secret 32-byte blinding key derives from the run seed and the resolved
//! config, and is kept in `RUN/private/blinding.key` as 64 hex digits:
//!
//! ```text
//! s   = 32 bytes: four u64 LE drawn from SeedKey::base(seed, 0, Stream::Blinding)
//! key = SHA-256("stepsim-blinding-key" ‖ s ‖ SHA-256(config))
//! ```
//!
//! where `config` is the bytes of `RUN/private/config.json` (the resolved
//! config, seed included). Two runs with the same seed and different configs
//! therefore share no id, and a submission cannot be scored against the wrong
//! run by accident. Ids are truncated hex SHA-256 digests of the key followed
//! by a domain tag and the indices:
//!
//! ```text
//! dataset id = "d" + hex(SHA-256(key ‖ "stepsim-dataset" ‖ dataset as u32 LE))[..12]
//! image id   = "i" + hex(SHA-256(key ‖ "stepsim-image" ‖ dataset u32 LE ‖ field u32 LE ‖ rotated u8))[..16]
//! ```
//!
//! Without the key the ids are unrelated random strings; with it, the
//! organiser can recompute them. Since the key derives from `run.seed`, a real
//! challenge needs a secret seed: a config without one gets a seed drawn from
//! the operating system (`plan::Plan::new`).

use rand::RngExt;
use sha2::{Digest, Sha256};
use stepsim_contract::digest::hex;
use stepsim_contract::seed::{SeedKey, Stream};

/// Hex digits of a dataset id after its `d` prefix (48 bits).
pub const DATASET_ID_HEX: usize = 12;
/// Hex digits of an image id after its `i` prefix (64 bits).
pub const IMAGE_ID_HEX: usize = 16;

/// A malformed blinding key file.
#[derive(Debug, thiserror::Error)]
#[error("blinding key must be 64 hex digits, got {got:?}")]
pub struct BadKey {
    /// What was found (trimmed).
    pub got: String,
}

/// The secret from which the opaque ids derive.
#[derive(Clone, PartialEq, Eq)]
pub struct BlindingKey([u8; 32]);

impl std::fmt::Debug for BlindingKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BlindingKey(…)")
    }
}

impl BlindingKey {
    /// The key of a run from its master seed and the bytes of its resolved
    /// config (`private/config.json`); see the module documentation.
    pub fn for_run(run_seed: u64, config: &[u8]) -> Self {
        let mut rng = SeedKey::base(run_seed, 0, Stream::Blinding).rng();
        let mut h = Sha256::new();
        h.update(b"stepsim-blinding-key");
        for _ in 0..4 {
            h.update(rng.random::<u64>().to_le_bytes());
        }
        h.update(Sha256::digest(config));
        Self(h.finalize().into())
    }

    /// The key as 64 lower-case hex digits (the content of `blinding.key`
    /// without its trailing newline).
    pub fn to_hex(&self) -> String {
        hex(&self.0)
    }

    /// Parses 64 hex digits (surrounding whitespace ignored).
    pub fn from_hex(text: &str) -> Result<Self, BadKey> {
        let t = text.trim();
        let bad = || BadKey { got: t.into() };
        if t.len() != 64 || !t.is_ascii() {
            return Err(bad());
        }
        let mut k = [0u8; 32];
        for (i, b) in k.iter_mut().enumerate() {
            *b = u8::from_str_radix(&t[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
        }
        Ok(Self(k))
    }

    fn digest(&self, tag: &str, parts: &[&[u8]]) -> String {
        let mut h = Sha256::new();
        h.update(self.0);
        h.update(tag.as_bytes());
        for p in parts {
            h.update(p);
        }
        hex(&h.finalize())
    }

    /// Opaque id of dataset `dataset` (its index in the plan).
    pub fn dataset_id(&self, dataset: u32) -> String {
        let d = self.digest("stepsim-dataset", &[&dataset.to_le_bytes()]);
        format!("d{}", &d[..DATASET_ID_HEX])
    }

    /// Opaque id of the image of base field `field` in dataset `dataset`
    /// (`rotated`: the 90°-rotated twin).
    pub fn image_id(&self, dataset: u32, field: u32, rotated: bool) -> String {
        let d = self.digest(
            "stepsim-image",
            &[
                &dataset.to_le_bytes(),
                &field.to_le_bytes(),
                &[u8::from(rotated)],
            ],
        );
        format!("i{}", &d[..IMAGE_ID_HEX])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;
    use stepsim_contract::digest::sha256_hex;

    #[test]
    fn the_participants_example_row_names_an_image_id_of_the_real_shape() {
        // The submission format's example (what participants copy) must
        // carry an id a generated run could hold: `i` and 16 hex digits.
        let k = BlindingKey::for_run(20060101, b"{}");
        let real = k.image_id(0, 0, false);
        let line = stepsim_contract::SUBMISSION_FORMAT_MD
            .lines()
            .find(|l| l.trim_start().starts_with('i') && l.contains(" 1021.37 "))
            .expect("an example row");
        let example = line.split_whitespace().next().unwrap();
        assert_eq!(example.len(), real.len(), "{example} against {real}");
        assert!(example.starts_with('i') && example[1..].bytes().all(|b| b.is_ascii_hexdigit()));
        assert!(!example[1..].bytes().any(|b| b.is_ascii_uppercase()));
    }

    #[test]
    fn sha256_of_known_strings() {
        // FIPS 180-2 test vectors.
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
    }

    #[test]
    fn key_round_trips_through_hex_and_depends_on_seed_and_config() {
        let k = BlindingKey::for_run(20060101, b"{}");
        assert_eq!(k.to_hex().len(), 64);
        assert_eq!(
            BlindingKey::from_hex(&format!(" {}\n", k.to_hex())).unwrap(),
            k
        );
        assert_eq!(BlindingKey::for_run(20060101, b"{}"), k);
        assert_ne!(BlindingKey::for_run(20060102, b"{}"), k);
        // Same seed, another config: another key and no shared id.
        let other = BlindingKey::for_run(20060101, b"{ }");
        assert_ne!(other, k);
        assert_ne!(other.dataset_id(0), k.dataset_id(0));
        assert_ne!(other.image_id(0, 0, false), k.image_id(0, 0, false));
        // The documented formula, restated.
        let mut rng = SeedKey::base(20060101, 0, Stream::Blinding).rng();
        let mut bytes = b"stepsim-blinding-key".to_vec();
        for _ in 0..4 {
            bytes.extend(rng.random::<u64>().to_le_bytes());
        }
        bytes.extend(Sha256::digest(b"{}"));
        assert_eq!(k.to_hex(), sha256_hex(&bytes));
        for bad in ["", "abc", &"g".repeat(64), &"0".repeat(63)] {
            assert!(BlindingKey::from_hex(bad).is_err(), "{bad:?}");
        }
        assert!(!format!("{k:?}").contains(&k.to_hex()[..8]));
    }

    #[test]
    fn ids_are_unique_well_formed_and_unordered() {
        let k = BlindingKey::for_run(1, b"{}");
        let mut seen = HashSet::new();
        // STEP1 with rotated pairs: 30 datasets × 64 fields × 2.
        for d in 0..30 {
            let id = k.dataset_id(d);
            assert_eq!(id.len(), 1 + DATASET_ID_HEX);
            assert!(id.starts_with('d'));
            assert!(seen.insert(id));
            for f in 0..64 {
                for rot in [false, true] {
                    let id = k.image_id(d, f, rot);
                    assert_eq!(id.len(), 1 + IMAGE_ID_HEX);
                    assert!(id[1..].chars().all(|c| c.is_ascii_hexdigit()));
                    assert!(seen.insert(id));
                }
            }
        }
        assert_eq!(seen.len(), 30 + 30 * 64 * 2);
        // Sorting ids does not give the dataset order back: the rank
        // correlation of 30 dataset ids with their index is small.
        let ids: Vec<String> = (0..30).map(|d| k.dataset_id(d)).collect();
        let mut sorted = ids.clone();
        sorted.sort();
        assert_ne!(ids, sorted);
        let ranks: Vec<usize> = ids
            .iter()
            .map(|id| sorted.iter().position(|s| s == id).unwrap())
            .collect();
        let n = 30.0;
        let d2: f64 = ranks
            .iter()
            .enumerate()
            .map(|(i, &r)| (i as f64 - r as f64).powi(2))
            .sum();
        let spearman = 1.0 - 6.0 * d2 / (n * (n * n - 1.0));
        assert!(spearman.abs() < 0.6, "rank correlation {spearman}");
        // Another key gives other ids.
        assert_ne!(
            BlindingKey::for_run(2, b"{}").dataset_id(0),
            k.dataset_id(0)
        );
    }
}
