//! Configuration in two layers (see `docs/config.md` for the schema).
//!
//! 1. [`RawConfig`] mirrors the JSON file. Parsing checks only what the user
//!    wrote: syntax (with line and column), unknown keys and wrong types (with
//!    the key's dotted path). Every section has STEP1 defaults, so a file
//!    only needs what differs.
//! 2. [`RawConfig::validate`] checks ranges with the offending key named;
//!    [`crate::run::plan::Plan`] then resolves the run: datasets enumerated
//!    (PSF × shear), seed fixed, input files read.
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

pub use challenge::RawChallenge;
pub use image::RawImage;
pub use population::{RawPopulation, Source};
pub use psf::{RawPsf, RawPsfModel};
pub use render::{RawOutput, RawRender};

use crate::model::noise::Instrument;
use crate::model::psf::Telescope;
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

/// A value a validator refused: the dotted key and what is wrong with it.
/// The file is named by the caller ([`Invalid::in_file`]).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Invalid {
    /// Dotted key path.
    pub key: String,
    /// What is wrong, with the offending value.
    pub message: String,
}

impl Invalid {
    pub(crate) fn new(key: String, message: String) -> Self {
        Self { key, message }
    }

    /// The same refusal for a key inside `prefix` (`psfs.2` + `name`).
    pub(crate) fn under(self, prefix: &str) -> Self {
        Self {
            key: format!("{prefix}.{}", self.key),
            message: self.message,
        }
    }

    /// The refusal as the error of the config file `path`.
    pub(crate) fn in_file(self, path: &Path) -> ConfigError {
        ConfigError::Invalid {
            path: path.into(),
            key: self.key,
            message: self.message,
        }
    }
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
    pub instrument: Instrument,
    /// Telescope pupil and wavelength used by the optical PSFs.
    pub telescope: Telescope,
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
            instrument: Instrument::default(),
            telescope: Telescope::default(),
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
    /// Master seed: every random stream derives from it (see [`stepsim_contract::seed`]).
    /// Absent (the default, and the presets): [`crate::run::plan::Plan::new`] draws one from
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

impl RawConfig {
    /// Checks every range of the config (what [`crate::run::plan::Plan::new`]
    /// refuses before resolving anything); the error names `source` and the
    /// offending key.
    pub fn validate(&self, source: &Path) -> Result<(), ConfigError> {
        self.check_ranges().map_err(|e| e.in_file(source))
    }

    /// [`RawConfig::validate`] without the file's name.
    fn check_ranges(&self) -> Result<(), Invalid> {
        self.image.validate()?;
        image::validate_instrument(&self.instrument)?;
        image::validate_telescope(&self.telescope)?;
        self.population.validate()?;
        if self.population.rotate_positions {
            if !self.population.rotated_pairs {
                return Err(Invalid::new(
                    "population.rotate_positions".into(),
                    "turns the rotated twin's positions, so it needs \
                     population.rotated_pairs = true"
                        .into(),
                ));
            }
            if self.image.width_px != self.image.height_px {
                return Err(Invalid::new(
                    "population.rotate_positions".into(),
                    format!(
                        "a 90° turn maps the image onto itself only when it is square, \
                         got {} × {} pixels",
                        self.image.width_px, self.image.height_px
                    ),
                ));
            }
            if self.challenge.holdout_fields > 0 {
                return Err(Invalid::new(
                    "population.rotate_positions".into(),
                    "is a benchmark setting, not one for a challenge (challenge.holdout_fields \
                     > 0): a turned twin at shear +g is the field at −g turned, so turning the \
                     public images would pair the datasets of opposite shear"
                        .into(),
                ));
            }
        }
        self.render.validate()?;
        self.output.validate()?;
        self.challenge.validate(self.image.n_images)?;
        if self.psfs.is_empty() {
            return Err(Invalid::new(
                "psfs".into(),
                "at least one PSF is needed".into(),
            ));
        }
        let mut names = std::collections::HashSet::new();
        for (i, p) in self.psfs.iter().enumerate() {
            p.validate().map_err(|e| e.under(&format!("psfs.{i}")))?;
            if !names.insert(p.name.clone()) {
                return Err(Invalid::new(
                    format!("psfs.{i}.name"),
                    format!("duplicate PSF name {:?}", p.name),
                ));
            }
        }
        if self.shears.is_empty() {
            return Err(Invalid::new(
                "shears".into(),
                "at least one shear is needed".into(),
            ));
        }
        for (i, s) in self.shears.iter().enumerate() {
            let g = s.g1.hypot(s.g2);
            if !s.g1.is_finite() || !s.g2.is_finite() || g >= 1.0 {
                return Err(Invalid::new(
                    format!("shears.{i}"),
                    format!("|g| must be < 1, got g1={} g2={}", s.g1, s.g2),
                ));
            }
        }
        Ok(())
    }
}

/// Checks that `value` lies in `[lo, hi]`; the error names `key`.
pub(crate) fn check_range(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), Invalid> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(Invalid::new(
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
pub(crate) fn check_positive(key: &str, value: f64) -> Result<(), Invalid> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
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
    fn rotate_positions_needs_twins_and_a_square_image_no_challenge_and_is_written_only_when_on() {
        let with = |o: &[&str]| {
            let o: Vec<String> = o.iter().map(|s| s.to_string()).collect();
            RawConfig::parse("{}", Path::new("t.json"), &o)
                .and_then(|raw| raw.validate(Path::new("t.json")).map(|()| raw))
        };
        let refused = |o: &[&str], words: &[&str]| {
            let err = with(o).unwrap_err().to_string();
            assert!(words.iter().all(|w| err.contains(w)), "{err}");
        };
        refused(
            &["population.rotate_positions=true"],
            &["population.rotate_positions", "rotated_pairs"],
        );
        refused(
            &[
                "population.rotate_positions=true",
                "population.rotated_pairs=true",
                "image.height_px=4000",
            ],
            &["square", "4096 × 4000"],
        );
        let on = with(&[
            "population.rotate_positions=true",
            "population.rotated_pairs=true",
        ])
        .unwrap();
        assert!(on.to_json().contains("\"rotate_positions\": true"));
        assert_eq!(parse(&on.to_json()).unwrap(), on);
        // Not in a challenge: its turned twins pair opposite shears.
        refused(
            &[
                "population.rotate_positions=true",
                "population.rotated_pairs=true",
                "image.n_images=2",
                "challenge.holdout_fields=1",
            ],
            &["population.rotate_positions", "benchmark", "opposite shear"],
        );
        // Off, the key is not written: older configs keep their bytes.
        let off = with(&["population.rotated_pairs=true"]).unwrap();
        assert!(!off.to_json().contains("rotate_positions"));
    }

    #[test]
    fn resolved_json_round_trips() {
        let raw = RawConfig::default();
        let again = parse(&raw.to_json()).unwrap();
        assert_eq!(raw, again);
    }
}
