//! Configuration in two layers (see `docs/config.md` for the schema).
//!
//! 1. [`RawConfig`] mirrors the JSON file. Parsing checks only what the user
//!    wrote: syntax (with line and column), unknown keys and wrong types (with
//!    the key's dotted path). Every section has STEP1 defaults, so a file
//!    only needs what differs.
//! 2. [`Plan`] is the validated run: ranges checked with the offending key
//!    named, datasets enumerated (PSF × shear), seeds fixed.
//!
//! Overrides from the command line (`--set key.path=value`) are applied to the
//! JSON tree between the two steps; the value is parsed as JSON when it can
//! be (`--set image.n_images=4`, `--set run.name="x"`) and taken as a string
//! otherwise (`--set run.name=x`).

mod challenge;
mod image;
mod population;
mod psf;
mod render;

pub use challenge::{Part, RawChallenge};
pub use image::{RawImage, RawInstrument, RawTelescope};
pub use population::{
    Cosmology, Flattening, GalaxyType, InclinationLaw, RawGalaxies, RawPopulation, RawStars, Sizes,
    Source,
};
pub use psf::{Aberration, RawPsf, RawPsfModel};
pub use render::{Compression, RawOutput, RawRender, RenderMethod, SampleFormat};

use crate::seed::{SeedKey, Stream};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// An error in a configuration: always names the file and the key or line.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error (not a `source`: the message shows it once).
        error: std::io::Error,
    },
    /// The file is not valid JSON.
    #[error("{path}: line {line}, column {column}: malformed JSON: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What the parser said.
        message: String,
    },
    /// A key is unknown, or a value has the wrong type.
    #[error("{path}: key `{key}`{}: {message}", at_line(*line))]
    Key {
        /// The file (or `--set` for an override).
        path: PathBuf,
        /// Dotted key path, e.g. `population.stars.density_per_arcmin2`.
        key: String,
        /// Line in the file, when known.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A `--set` override is malformed.
    #[error("--set {arg}: {message}")]
    Override {
        /// The override as given.
        arg: String,
        /// What is wrong.
        message: String,
    },
    /// A section that must be a JSON object is something else (an array
    /// would otherwise be read by position).
    #[error("{path}: {}{}: expected a JSON object {{...}}, found {found}", shape_where(key), at_line(*line))]
    NotAnObject {
        /// The file (or `--set` for an override).
        path: PathBuf,
        /// Dotted key path (empty for the whole config).
        key: String,
        /// Line in the file, when known.
        line: Option<usize>,
        /// What was found ("an array", "a number", ...).
        found: &'static str,
    },
    /// The config gives no seed and the operating system gave none.
    #[error(transparent)]
    Entropy(#[from] NoEntropy),
    /// A value is out of its allowed range.
    #[error("{path}: key `{key}`: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted key path.
        key: String,
        /// What is wrong, with the offending value.
        message: String,
    },
}

fn shape_where(key: &str) -> String {
    if key.is_empty() {
        "the config".into()
    } else {
        format!("key `{key}`")
    }
}

fn at_line(line: Option<usize>) -> String {
    line.map(|l| format!(" (line {l})")).unwrap_or_default()
}

/// The whole configuration as written in the JSON file (after defaults).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawConfig {
    /// Run identity and master seed.
    pub run: RawRun,
    /// Image geometry and the number of base fields.
    pub image: RawImage,
    /// Detector, sky and exposure.
    pub instrument: RawInstrument,
    /// Telescope pupil and wavelength used by the optical PSFs.
    pub telescope: RawTelescope,
    /// Galaxy and star population.
    pub population: RawPopulation,
    /// The PSF models; each makes one group of datasets.
    pub psfs: Vec<RawPsf>,
    /// The applied shears; every PSF is run with every shear.
    pub shears: Vec<RawShear>,
    /// Accuracy of the renderer.
    pub render: RawRender,
    /// What gets written.
    pub output: RawOutput,
    /// The held-out part of a challenge run (left out of the resolved
    /// config when it is the default, so older runs keep their bytes).
    #[serde(skip_serializing_if = "RawChallenge::is_default")]
    pub challenge: RawChallenge,
}

impl Default for RawConfig {
    fn default() -> Self {
        Self {
            run: RawRun::default(),
            image: RawImage::default(),
            instrument: RawInstrument::default(),
            telescope: RawTelescope::default(),
            population: RawPopulation::default(),
            psfs: RawPsf::step1_set(),
            shears: RawShear::step1_set(),
            render: RawRender::default(),
            output: RawOutput::default(),
            challenge: RawChallenge::default(),
        }
    }
}

/// Run identity and master seed.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawRun {
    /// A name for humans (appears in the private half only).
    pub name: String,
    /// Master seed: every random stream derives from it (see [`crate::seed`]).
    /// Absent (the default, and the presets): [`Plan::new`] draws one from
    /// the operating system, so that a release is blind; the resolved config
    /// (`RUN/private/config.json`) records it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

impl Default for RawRun {
    fn default() -> Self {
        Self {
            name: "step1".into(),
            seed: None,
        }
    }
}

/// Where a plan's master seed came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeedOrigin {
    /// Written in the config (or a `--set run.seed=N`): anyone who knows it
    /// can rebuild the run, so the release is only as blind as it is secret.
    Config,
    /// The config gave none: drawn from the operating system's entropy.
    Drawn,
}

/// Why no seed could be drawn from the operating system.
#[derive(Debug, thiserror::Error)]
#[error("cannot draw a seed from the operating system: {0}")]
pub struct NoEntropy(pub String);

/// A fresh secret seed: 64 bits from the operating system's entropy source.
pub fn draw_seed() -> Result<u64, NoEntropy> {
    getrandom::u64().map_err(|e| NoEntropy(e.to_string()))
}

/// One applied reduced shear (κ = 0 as in STEP1).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawShear {
    /// g1: positive stretches along x.
    pub g1: f64,
    /// g2: positive stretches along y = x.
    #[serde(default)]
    pub g2: f64,
}

impl RawShear {
    /// The STEP1 shears (paper section 3): g1 = 0, 0.005, 0.01, 0.05, 0.1; g2 = 0.
    pub fn step1_set() -> Vec<Self> {
        [0.0, 0.005, 0.01, 0.05, 0.1]
            .iter()
            .map(|&g1| Self { g1, g2: 0.0 })
            .collect()
    }
}

impl RawConfig {
    /// Reads, overrides and parses a config file.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
            path: path.into(),
            error,
        })?;
        Self::parse(&text, path, overrides)
    }

    /// Parses config text; `path` is only used in messages.
    pub fn parse(text: &str, path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| ConfigError::Syntax {
                path: path.into(),
                line: e.line(),
                column: e.column(),
                message: strip_position(&e.to_string()),
            })?;
        let defaults = shape_defaults();
        check_shape(&value, &defaults, "").map_err(|(key, found)| ConfigError::NotAnObject {
            path: path.into(),
            line: line_of_key(text, &key),
            key,
            found,
        })?;
        // First pass straight from the text, so that errors carry a line.
        let mut de = serde_json::Deserializer::from_str(text);
        let raw: RawConfig =
            serde_path_to_error::deserialize(&mut de).map_err(|e| ConfigError::Key {
                path: path.into(),
                key: e.path().to_string(),
                line: Some(e.inner().line()),
                message: strip_position(&e.inner().to_string()),
            })?;
        if overrides.is_empty() {
            return Ok(raw);
        }
        // Overrides apply on top of the resolved config (defaults filled in),
        // so that `shears.1.g1` works even when the file does not list shears.
        let mut tree = serde_json::to_value(&raw).expect("config serialises");
        for arg in overrides {
            apply_override(&mut tree, arg)?;
        }
        let defaults = shape_defaults();
        check_shape(&tree, &defaults, "").map_err(|(key, found)| ConfigError::NotAnObject {
            path: PathBuf::from("--set"),
            key,
            line: None,
            found,
        })?;
        serde_path_to_error::deserialize(tree).map_err(|e| ConfigError::Key {
            path: PathBuf::from("--set"),
            key: e.path().to_string(),
            line: None,
            message: e.inner().to_string(),
        })
    }

    /// The config as pretty JSON (the "resolved copy" written beside outputs).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("config serialises")
    }
}

/// The default config as a JSON tree, with every section present (also
/// those left out of the resolved config when default), for [`check_shape`].
fn shape_defaults() -> serde_json::Value {
    let mut tree = serde_json::to_value(RawConfig::default()).expect("config serialises");
    if let serde_json::Value::Object(map) = &mut tree {
        map.insert(
            "challenge".into(),
            serde_json::to_value(RawChallenge::default()).expect("config serialises"),
        );
    }
    tree
}

/// Finds where `value` holds something other than an object where the
/// default config (`shape`) has one: serde would read an array there by
/// position (`[4096, 4096, 0.2]` as `width_px`, `height_px`, ...). Returns the
/// dotted key and what was found.
fn check_shape(
    value: &serde_json::Value,
    shape: &serde_json::Value,
    key: &str,
) -> Result<(), (String, &'static str)> {
    use serde_json::Value;
    let join = |k: &str| {
        if key.is_empty() {
            k.to_string()
        } else {
            format!("{key}.{k}")
        }
    };
    match (value, shape) {
        (Value::Object(v), Value::Object(d)) => {
            for (k, item) in v {
                if let Some(ds) = d.get(k) {
                    check_shape(item, ds, &join(k))?;
                }
            }
            Ok(())
        }
        (Value::Array(v), Value::Array(d)) => match d.first() {
            Some(first) => v
                .iter()
                .enumerate()
                .try_for_each(|(i, item)| check_shape(item, first, &join(&i.to_string()))),
            None => Ok(()),
        },
        (Value::Array(_), Value::Object(_)) => Err((key.to_string(), "an array")),
        (Value::Number(_), Value::Object(_)) if key.is_empty() => Err((key.into(), "a number")),
        (Value::String(_), Value::Object(_)) if key.is_empty() => Err((key.into(), "a string")),
        (Value::Bool(_), Value::Object(_)) if key.is_empty() => Err((key.into(), "a boolean")),
        (Value::Null, Value::Object(_)) if key.is_empty() => Err((key.into(), "null")),
        _ => Ok(()),
    }
}

/// The line of the last key of a dotted path in `text`, when that key
/// appears exactly once (for messages; `None` when unsure).
fn line_of_key(text: &str, key: &str) -> Option<usize> {
    if key.is_empty() {
        let offset = text.find(|c: char| !c.is_whitespace())?;
        return Some(text[..offset].matches('\n').count() + 1);
    }
    let last = key.rsplit('.').next()?;
    if last.parse::<usize>().is_ok() {
        return None;
    }
    let needle = format!("\"{last}\"");
    let mut hits = text.match_indices(&needle);
    let (offset, _) = hits.next()?;
    if hits.next().is_some() {
        return None;
    }
    Some(text[..offset].matches('\n').count() + 1)
}

fn strip_position(msg: &str) -> String {
    match msg.rfind(" at line ") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}

/// Applies one `key.path=value` override to a JSON tree. Array elements are
/// addressed by index (`psfs.1.target_chi=0.05`).
pub fn apply_override(tree: &mut serde_json::Value, arg: &str) -> Result<(), ConfigError> {
    let bad = |message: &str| ConfigError::Override {
        arg: arg.into(),
        message: message.into(),
    };
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| bad("expected key.path=value"))?;
    if key.is_empty() || key.split('.').any(str::is_empty) {
        return Err(bad("empty key path"));
    }
    let value: serde_json::Value =
        serde_json::from_str(value).unwrap_or_else(|_| serde_json::Value::String(value.into()));
    let parts: Vec<&str> = key.split('.').collect();
    let mut node = tree;
    for (i, part) in parts.iter().enumerate() {
        let last = i + 1 == parts.len();
        node = match node {
            serde_json::Value::Object(map) => {
                if last {
                    map.insert((*part).to_string(), value);
                    return Ok(());
                }
                map.entry((*part).to_string())
                    .or_insert_with(|| serde_json::json!({}))
            }
            serde_json::Value::Array(items) => {
                let idx: usize = part
                    .parse()
                    .map_err(|_| bad(&format!("`{part}` is not an array index")))?;
                let len = items.len();
                let slot = items
                    .get_mut(idx)
                    .ok_or_else(|| bad(&format!("index {idx} out of range (array has {len})")))?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
            _ => return Err(bad(&format!("`{}` is not an object", parts[..i].join(".")))),
        };
    }
    unreachable!("loop returns on the last part")
}

/// One dataset: a PSF and a shear. Its index `id` is stable: `psf * n_shears + shear`
/// for the public part; held-out datasets (a `challenge` section) follow as
/// `n_psfs * n_shears + psf * n_shears + slot`.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Index in [`Plan::datasets`].
    pub index: u32,
    /// Index of the PSF in [`RawConfig::psfs`].
    pub psf: usize,
    /// Index of the shear in [`RawConfig::shears`] (for a held-out dataset:
    /// its slot, 0..n_shears; its shear is drawn, not configured).
    pub shear: usize,
    /// Which part of the challenge it belongs to.
    pub part: Part,
    /// Its base fields, ascending (every field unless the run holds some out).
    pub fields: Vec<u32>,
    /// Applied g1.
    pub g1: f64,
    /// Applied g2.
    pub g2: f64,
}

/// A validated run: the raw config plus everything derived from it.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The config it came from (after overrides and defaults).
    pub raw: RawConfig,
    /// Where it came from (for messages).
    pub source: PathBuf,
    /// Every PSF × shear pair, PSF-major.
    pub datasets: Vec<Dataset>,
    /// Whether `raw.run.seed` was given or drawn by [`Plan::new`].
    pub seed_origin: SeedOrigin,
}

impl Plan {
    /// Validates a raw config. A config without `run.seed` gets one drawn
    /// from the operating system ([`draw_seed`]; [`SeedOrigin::Drawn`]), so
    /// `raw.run.seed` is always set in a plan.
    pub fn new(mut raw: RawConfig, source: &Path) -> Result<Self, ConfigError> {
        let invalid = |key: &str, message: String| ConfigError::Invalid {
            path: source.into(),
            key: key.into(),
            message,
        };
        raw.image.validate().map_err(|(k, m)| invalid(&k, m))?;
        raw.instrument.validate().map_err(|(k, m)| invalid(&k, m))?;
        check_sky_below_saturation(&raw).map_err(|(k, m)| invalid(&k, m))?;
        raw.telescope.validate().map_err(|(k, m)| invalid(&k, m))?;
        raw.population.validate().map_err(|(k, m)| invalid(&k, m))?;
        raw.render.validate().map_err(|(k, m)| invalid(&k, m))?;
        raw.output.validate().map_err(|(k, m)| invalid(&k, m))?;
        raw.challenge
            .validate(raw.image.n_images)
            .map_err(|(k, m)| invalid(&k, m))?;
        if raw.psfs.is_empty() {
            return Err(invalid("psfs", "at least one PSF is needed".into()));
        }
        let mut names = std::collections::HashSet::new();
        for (i, p) in raw.psfs.iter().enumerate() {
            p.validate()
                .map_err(|(k, m)| invalid(&format!("psfs.{i}.{k}"), m))?;
            if !names.insert(p.name.clone()) {
                return Err(invalid(
                    &format!("psfs.{i}.name"),
                    format!("duplicate PSF name {:?}", p.name),
                ));
            }
        }
        if raw.shears.is_empty() {
            return Err(invalid("shears", "at least one shear is needed".into()));
        }
        for (i, s) in raw.shears.iter().enumerate() {
            let g = s.g1.hypot(s.g2);
            if !s.g1.is_finite() || !s.g2.is_finite() || g >= 1.0 {
                return Err(invalid(
                    &format!("shears.{i}"),
                    format!("|g| must be < 1, got g1={} g2={}", s.g1, s.g2),
                ));
            }
        }
        let seed_origin = match raw.run.seed {
            Some(_) => SeedOrigin::Config,
            None => {
                raw.run.seed = Some(draw_seed()?);
                SeedOrigin::Drawn
            }
        };
        let datasets = challenge_datasets(&raw);
        Ok(Self {
            raw,
            source: source.into(),
            datasets,
            seed_origin,
        })
    }

    /// The same plan with master seed `seed` (the origin is kept: adopting
    /// the seed of an existing run does not make it public).
    pub fn with_seed(&self, seed: u64) -> Self {
        let mut p = self.clone();
        p.raw.run.seed = Some(seed);
        p.datasets = challenge_datasets(&p.raw);
        p
    }

    /// Loads, overrides and validates a config file in one go.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        Self::new(RawConfig::load(path, overrides)?, path)
    }

    /// Number of base fields (images per dataset).
    pub fn n_fields(&self) -> u32 {
        self.raw.image.n_images
    }

    /// Number of images in the run (every dataset's fields, twins included).
    pub fn n_images_in_run(&self) -> u64 {
        let twins = 1 + u64::from(self.raw.population.rotated_pairs);
        self.datasets
            .iter()
            .map(|d| d.fields.len() as u64)
            .sum::<u64>()
            * twins
    }

    /// Master seed ([`Plan::new`] always sets one).
    pub fn seed(&self) -> u64 {
        self.raw.run.seed.unwrap_or_default()
    }
}

/// The datasets of a validated config with its seed set: PSF × shear on
/// the public fields, then (with `challenge.holdout_fields`) PSF × slot on
/// the held-out fields with drawn shears.
fn challenge_datasets(raw: &RawConfig) -> Vec<Dataset> {
    let seed = raw.run.seed.unwrap_or_default();
    let n_fields = raw.image.n_images;
    let n_shears = raw.shears.len();
    let n_psfs = raw.psfs.len();
    let held = holdout_fields(seed, n_fields, raw.challenge.holdout_fields);
    let public: Vec<u32> = (0..n_fields).filter(|f| !held.contains(f)).collect();
    let pairs = || (0..n_psfs).flat_map(move |p| (0..n_shears).map(move |s| (p, s)));
    let mut out: Vec<Dataset> = pairs()
        .map(|(psf, shear)| Dataset {
            index: (psf * n_shears + shear) as u32,
            psf,
            shear,
            part: Part::Public,
            fields: public.clone(),
            g1: raw.shears[shear].g1,
            g2: raw.shears[shear].g2,
        })
        .collect();
    if !held.is_empty() {
        let g_max = raw.challenge.holdout_g_max;
        out.extend(pairs().map(|(psf, slot)| {
            let index = (n_psfs * n_shears + psf * n_shears + slot) as u32;
            let (g1, g2) = holdout_shear(seed, index, g_max);
            Dataset {
                index,
                psf,
                shear: slot,
                part: Part::Holdout,
                fields: held.clone(),
                g1,
                g2,
            }
        }));
    }
    out
}

/// The base fields held out: `n_held` of `0..n_fields`, chosen by a keyed
/// order (stream [`Stream::Holdout`] per field), not by position, so that
/// nothing about a field's index tells its part. Ascending.
pub fn holdout_fields(seed: u64, n_fields: u32, n_held: u32) -> Vec<u32> {
    let mut order: Vec<(u64, u32)> = (0..n_fields)
        .map(|f| (SeedKey::base(seed, f, Stream::Holdout).seed(), f))
        .collect();
    order.sort_unstable();
    let mut held: Vec<u32> = order
        .into_iter()
        .take(n_held as usize)
        .map(|(_, f)| f)
        .collect();
    held.sort_unstable();
    held
}

/// The shear of held-out dataset `index`: uniform in the disc |g| ≤ `g_max`
/// (radius g_max·√u, angle 2πv), from the keyed stream
/// `SeedKey::image(seed, 0, index, Stream::Holdout)`.
pub fn holdout_shear(seed: u64, index: u32, g_max: f64) -> (f64, f64) {
    use rand::RngExt;
    let mut rng = SeedKey::image(seed, 0, index, Stream::Holdout).rng();
    let u: f64 = rng.random();
    let v: f64 = rng.random();
    let r = g_max * u.sqrt();
    let phi = std::f64::consts::TAU * v;
    (r * phi.cos(), r * phi.sin())
}

/// The sky alone must stay below the clip level, or every pixel of every
/// image is the saturation value (a blank image).
fn check_sky_below_saturation(raw: &RawConfig) -> Result<(), (String, String)> {
    let ins = &raw.instrument;
    let sky_adu =
        crate::noise::sky_e_per_pixel(ins, raw.image.pixel_scale_arcsec) / ins.gain_e_per_adu;
    if sky_adu.is_finite() && sky_adu < ins.saturation_adu {
        return Ok(());
    }
    Err((
        "instrument".into(),
        format!(
            "the sky alone gives {sky_adu:.4e} ADU per pixel, at or above instrument.saturation_adu = {}: every pixel would be clipped (a blank image); lower instrument.exposure_s or image.pixel_scale_arcsec, or raise instrument.sky_mag_arcsec2 or instrument.gain_e_per_adu",
            ins.saturation_adu
        ),
    ))
}

/// Checks that `value` lies in `[lo, hi]`; the error names `key`.
pub(crate) fn check_range(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), (String, String)> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err((
            key.into(),
            format!(
                "must be in [{}, {}], got {}",
                short_number(lo),
                short_number(hi),
                short_number(value)
            ),
        ))
    }
}

/// A number as people write it: plain when that is short (`0.206`,
/// `65535`), else in exponent form (`1e300`, not 301 digits).
pub fn short_number(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 || !v.is_finite() || (1e-4..1e12).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Checks that `value` is finite and strictly positive; the error names `key`.
pub(crate) fn check_positive(key: &str, value: f64) -> Result<(), (String, String)> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err((
            key.into(),
            format!("must be > 0, got {}", short_number(value)),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<RawConfig, ConfigError> {
        RawConfig::parse(text, Path::new("test.json"), &[])
    }

    #[test]
    fn empty_object_gives_step1_defaults() {
        let raw = parse("{}").unwrap();
        assert_eq!(raw, RawConfig::default());
        let plan = Plan::new(raw, Path::new("test.json")).unwrap();
        assert_eq!(plan.datasets.len(), 30);
        assert_eq!(plan.datasets[7].psf, 1);
        assert_eq!(plan.datasets[7].shear, 2);
        assert_eq!(plan.datasets[7].g1, 0.01);
    }

    #[test]
    fn unknown_key_is_named_with_its_path_and_line() {
        let err = parse("{\n  \"image\": {\n    \"widht_px\": 10\n  }\n}").unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("image.widht_px"), "{msg}");
        assert!(msg.contains("line 3"), "{msg}");
    }

    #[test]
    fn malformed_json_names_the_line() {
        let err = parse("{\n \"run\": {\n \"seed\": 1,\n }\n}").unwrap_err();
        assert!(matches!(err, ConfigError::Syntax { line: 4, .. }), "{err}");
    }

    #[test]
    fn overrides_reach_nested_keys_and_array_elements() {
        let raw = RawConfig::parse(
            "{}",
            Path::new("t.json"),
            &[
                "image.n_images=4".into(),
                "run.name=abc".into(),
                "shears.1.g1=0.02".into(),
            ],
        )
        .unwrap();
        assert_eq!(raw.image.n_images, 4);
        assert_eq!(raw.run.name, "abc");
        assert_eq!(raw.shears[1].g1, 0.02);
    }

    #[test]
    fn bad_overrides_are_refused() {
        for arg in [
            "noequals",
            "=3",
            "image..x=1",
            "shears.9.g1=0",
            "image.nope=1",
        ] {
            assert!(
                RawConfig::parse("{}", Path::new("t.json"), &[arg.into()]).is_err(),
                "{arg}"
            );
        }
    }

    #[test]
    fn out_of_range_values_name_the_key() {
        let raw = RawConfig::parse("{}", Path::new("t.json"), &["shears.0.g1=1.5".into()]).unwrap();
        let err = Plan::new(raw, Path::new("t.json")).unwrap_err().to_string();
        assert!(err.contains("shears.0"), "{err}");
        let raw = RawConfig::parse(
            "{}",
            Path::new("t.json"),
            &["image.pixel_scale_arcsec=-1".into()],
        )
        .unwrap();
        let err = Plan::new(raw, Path::new("t.json")).unwrap_err().to_string();
        assert!(err.contains("image.pixel_scale_arcsec"), "{err}");
    }

    #[test]
    fn arrays_are_never_read_by_position() {
        // serde would map these onto the structs field by field.
        let err = parse("[{}, {}, {}, {}]").unwrap_err();
        assert!(
            matches!(&err, ConfigError::NotAnObject { key, line: Some(1), found: "an array", .. } if key.is_empty()),
            "{err}"
        );
        let err = parse("{\n \"instrument\": [19.2, 26, 1e300, 4, 5, 65535]\n}").unwrap_err();
        assert_eq!(
            err.to_string(),
            "test.json: key `instrument` (line 2): expected a JSON object {...}, found an array"
        );
        let err = parse("{\"shears\": [[0.1, 0.0]]}").unwrap_err();
        assert!(err.to_string().contains("key `shears.0`"), "{err}");
        // Arrays where the schema has arrays stay fine.
        let raw = parse("{\"shears\": [{\"g1\": 0.1}], \"population\": {\"galaxies\": {\"abs_mag_limits\": [-25, -14]}}}").unwrap();
        assert_eq!(raw.shears.len(), 1);
    }

    #[test]
    fn numbers_in_messages_are_short() {
        assert_eq!(short_number(0.206), "0.206");
        assert_eq!(short_number(65535.0), "65535");
        assert_eq!(short_number(2_147_483_647.0), "2147483647");
        assert_eq!(short_number(1e300), "1e300");
        assert_eq!(short_number(1e-9), "1e-9");
        assert_eq!(short_number(-0.5), "-0.5");
        assert_eq!(short_number(f64::NAN), "NaN");
    }

    #[test]
    fn a_config_without_seed_gets_a_fresh_one_and_records_it() {
        let raw = parse("{}").unwrap();
        assert_eq!(raw.run.seed, None);
        assert!(!raw.to_json().contains("seed"), "no seed key when absent");
        let a = Plan::new(raw.clone(), Path::new("t.json")).unwrap();
        let b = Plan::new(raw, Path::new("t.json")).unwrap();
        assert_eq!(
            (a.seed_origin, b.seed_origin),
            (SeedOrigin::Drawn, SeedOrigin::Drawn)
        );
        assert_eq!(a.raw.run.seed, Some(a.seed()));
        // 64 bits from the OS: two draws agreeing would be a broken source.
        assert_ne!(a.seed(), b.seed());
        assert!(a.raw.to_json().contains(&format!("\"seed\": {}", a.seed())));
        // The resolved JSON gives the same seed back, now as given.
        let again = Plan::new(parse(&a.raw.to_json()).unwrap(), Path::new("c.json")).unwrap();
        assert_eq!(
            (again.seed(), again.seed_origin),
            (a.seed(), SeedOrigin::Config)
        );
        let given = parse("{\"run\": {\"seed\": 7}}").unwrap();
        let p = Plan::new(given, Path::new("t.json")).unwrap();
        assert_eq!((p.seed(), p.seed_origin), (7, SeedOrigin::Config));
        assert_eq!(p.with_seed(9).seed(), 9);
    }

    #[test]
    fn resolved_json_round_trips() {
        let raw = RawConfig::default();
        let again = parse(&raw.to_json()).unwrap();
        assert_eq!(raw, again);
    }
}
