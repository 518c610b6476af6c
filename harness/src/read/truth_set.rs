//! The organiser's side of a run: `RUN/private/datasets.json` and the truth
//! tables `RUN/private/truth/<image-id>.fits` (see `docs/run-layout.md`).

use crate::error::HarnessError;
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use stepsim_contract::run_dir::PrivateDir;
use stepsim_contract::run_layout::{DATASETS_FORMAT, Datasets};
use stepsim_contract::truth::TruthRow;

/// One image of the run, flattened out of the datasets (dataset order, then
/// the order of `images` in `datasets.json`).
#[derive(Debug, Clone, PartialEq)]
pub struct ImageInfo {
    /// Opaque image id.
    pub image: String,
    /// Index of its dataset in [`Datasets::datasets`].
    pub dataset: usize,
    /// Base field.
    pub field: u32,
}

/// The image ids and geometry a submission is checked against.
#[derive(Debug, Clone)]
pub struct ImageIndex {
    /// Every image, in run order.
    pub images: Vec<ImageInfo>,
    /// Image id -> index into `images`.
    pub by_id: HashMap<String, usize>,
    /// NAXIS1.
    pub width_px: u32,
    /// NAXIS2.
    pub height_px: u32,
    /// Pixel scale.
    pub pixel_scale_arcsec: f64,
}

impl ImageIndex {
    /// Builds the index of a run's images. Refuses an image id that appears
    /// twice (a corrupt `datasets.json`); `path` names the file in the error.
    pub fn new(datasets: &Datasets, path: &Path) -> Result<Self, HarnessError> {
        let mut images = Vec::new();
        let mut by_id = HashMap::new();
        for (d, entry) in datasets.datasets.iter().enumerate() {
            for im in &entry.images {
                if by_id.insert(im.image.clone(), images.len()).is_some() {
                    return Err(HarnessError::truth(
                        path,
                        format!("image id `{}` appears twice", im.image),
                    ));
                }
                images.push(ImageInfo {
                    image: im.image.clone(),
                    dataset: d,
                    field: im.field,
                });
            }
        }
        Ok(Self {
            images,
            by_id,
            width_px: datasets.width_px,
            height_px: datasets.height_px,
            pixel_scale_arcsec: datasets.pixel_scale_arcsec,
        })
    }

    /// Area of one image in arcmin².
    pub fn image_area_arcmin2(&self) -> f64 {
        let s = self.pixel_scale_arcsec / 60.0;
        f64::from(self.width_px) * f64::from(self.height_px) * s * s
    }

    /// True when (x, y) lies on the image, the half-pixel border included:
    /// 0.5 ≤ x ≤ width + 0.5 and 0.5 ≤ y ≤ height + 0.5 (FITS pixels).
    pub fn on_image(&self, x: f64, y: f64) -> bool {
        (0.5..=f64::from(self.width_px) + 0.5).contains(&x)
            && (0.5..=f64::from(self.height_px) + 0.5).contains(&y)
    }
}

/// The private half of a run as the harness needs it.
#[derive(Debug, Clone)]
pub struct TruthSet {
    /// `datasets.json`.
    pub datasets: Datasets,
    /// Its images.
    pub index: ImageIndex,
    /// The private directory.
    pub dir: PathBuf,
    /// The run's identity: [`run_identity`] of the `datasets.json` bytes.
    pub run: String,
    /// True when the run lensed its galaxies' positions
    /// (`population.lens_positions` in `private/config.json`): the isolated
    /// galaxies are then classed in the source plane
    /// ([`crate::score::isolation::Plane`]).
    pub lensed_positions: bool,
}

/// The identity of a run: `sha256:` and the SHA-256 of its `datasets.json`
/// bytes, in lower-case hex. `datasets.json` holds every dataset and image
/// id, shear and PSF of the run, so two runs share an identity only when
/// they agree on all of it (and then their scores are comparable).
pub fn run_identity(datasets_json: &[u8]) -> String {
    format!(
        "sha256:{}",
        stepsim_contract::digest::sha256_hex(datasets_json)
    )
}

/// Reads `DIR/datasets.json` (DIR = `RUN/private`).
pub fn load_truth_set(dir: &Path) -> Result<TruthSet, HarnessError> {
    let path = PrivateDir::new(dir).datasets();
    let bytes =
        crate::read::input::read_regular_file(&path, crate::read::input::MAX_DATASETS_JSON_BYTES)
            .map_err(|e| HarnessError::truth(&path, e.to_string()))?;
    let datasets: Datasets = serde_json::from_slice(&bytes)
        .map_err(|e| HarnessError::truth(&path, format!("not a datasets.json: {e}")))?;
    if datasets.format != DATASETS_FORMAT {
        return Err(HarnessError::truth(
            &path,
            format!("format `{}` is not `{DATASETS_FORMAT}`", datasets.format),
        ));
    }
    if !(datasets.pixel_scale_arcsec > 0.0 && datasets.pixel_scale_arcsec.is_finite()) {
        return Err(HarnessError::truth(
            &path,
            format!(
                "pixel_scale_arcsec {} is not positive",
                datasets.pixel_scale_arcsec
            ),
        ));
    }
    let index = ImageIndex::new(&datasets, &path)?;
    let lensed_positions = lensed_positions(dir)?;
    if lensed_positions {
        // The source plane undoes each dataset's shear: it must be a shear.
        if let Some(d) = datasets.datasets.iter().find(|d| {
            let g = d.g1.hypot(d.g2);
            g >= 1.0 || g.is_nan()
        }) {
            return Err(HarnessError::truth(
                &path,
                format!(
                    "dataset `{}` has shear ({}, {}), whose modulus is not below 1",
                    d.dataset, d.g1, d.g2
                ),
            ));
        }
    }
    Ok(TruthSet {
        datasets,
        index,
        dir: dir.to_path_buf(),
        run: run_identity(&bytes),
        lensed_positions,
    })
}

/// The largest `private/config.json` the harness reads (64 MiB, as
/// `datasets.json`; a resolved config is a few kB).
pub const MAX_CONFIG_JSON_BYTES: u64 = crate::read::input::MAX_DATASETS_JSON_BYTES;

/// Whether the run of private directory `dir` lensed its galaxies'
/// positions: `population.lens_positions` of `DIR/config.json` (the run's
/// resolved config), false when the key is absent (the configs before it).
/// A missing `config.json`, one that cannot be read or is not a JSON
/// object, a `population` that is not an object, or a key that is not true
/// or false is refused by name: scoring a lensed run as an unlensed one
/// would class its isolated galaxies in the wrong plane without a word.
pub fn lensed_positions(dir: &Path) -> Result<bool, HarnessError> {
    population_switch(dir, "lens_positions")
}

/// A switch of the run's `population` section (`population.KEY` of
/// `DIR/config.json`, DIR = `RUN/private`), read and refused as
/// [`lensed_positions`] reads `lens_positions`. Messages name the JSON
/// type of a wrong value, never the value.
pub fn population_switch(dir: &Path, key: &str) -> Result<bool, HarnessError> {
    let path = PrivateDir::new(dir).config();
    let bytes = crate::read::input::read_regular_file(&path, MAX_CONFIG_JSON_BYTES)
        .map_err(|e| HarnessError::truth(&path, format!("cannot read the run's config: {e}")))?;
    let config: serde_json::Value = serde_json::from_slice(&bytes)
        .map_err(|e| HarnessError::truth(&path, format!("not a config.json: {e}")))?;
    let type_of = |v: &serde_json::Value| match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    };
    let Some(config) = config.as_object() else {
        return Err(HarnessError::truth(
            &path,
            format!("not a config.json: {}, not an object", type_of(&config)),
        ));
    };
    let population = match config.get("population") {
        None => return Ok(false),
        Some(serde_json::Value::Object(p)) => p,
        Some(other) => {
            return Err(HarnessError::truth(
                &path,
                format!("population is {}, not an object", type_of(other)),
            ));
        }
    };
    match population.get(key) {
        None => Ok(false),
        Some(serde_json::Value::Bool(b)) => Ok(*b),
        Some(other) => Err(HarnessError::truth(
            &path,
            format!("population.{key} is {}, not true or false", type_of(other)),
        )),
    }
}

/// Truth columns the metrics use ([`crate::score::metrics::image_stats`]).
pub const SCORING_COLUMNS: [&str; 8] = [
    "kind",
    "x",
    "y",
    "mag",
    "disk_h_arcsec",
    "e1",
    "e1_int",
    "e2_int",
];

/// Reads only the [`SCORING_COLUMNS`] of a truth table (the other fields of
/// each row stay at their default). About 3.5 × faster than
/// `stepsim_contract::io::truth::read_truth_fits` on a 32-column table, whose
/// complete rows the scoring does not need. Errors name the file and column.
pub fn read_scoring_columns(path: &Path) -> Result<Vec<TruthRow>, HarnessError> {
    use stepsim_contract::io::IoError;
    use stepsim_contract::io::truth::TRUTH_EXTNAME;
    let fe = |e: fitsio::errors::Error| {
        HarnessError::from(IoError::format(
            path,
            crate::read::fits_table::fitsio_sentence(&e),
        ))
    };
    let mut f = stepsim_contract::io::fits::open_fits(path)?;
    let hdu = f.hdu(TRUTH_EXTNAME).map_err(fe)?;
    let col = |f: &mut fitsio::FitsFile, name: &str| -> Result<Vec<f64>, HarnessError> {
        hdu.read_col(f, name).map_err(|e| {
            IoError::format(
                path,
                format!(
                    "column `{name}`: {}",
                    crate::read::fits_table::fitsio_sentence(&e)
                ),
            )
            .into()
        })
    };
    let kind: Vec<i32> = hdu.read_col(&mut f, "kind").map_err(|e| {
        HarnessError::from(IoError::format(
            path,
            format!(
                "column `kind`: {}",
                crate::read::fits_table::fitsio_sentence(&e)
            ),
        ))
    })?;
    let mut rows = vec![TruthRow::default(); kind.len()];
    for (r, k) in rows.iter_mut().zip(kind) {
        r.kind = k;
    }
    for name in &SCORING_COLUMNS[1..] {
        let v = col(&mut f, name)?;
        if v.len() != rows.len() {
            return Err(
                IoError::format(path, format!("column `{name}` has {} rows", v.len())).into(),
            );
        }
        for (r, x) in rows.iter_mut().zip(v) {
            match *name {
                "x" => r.x = x,
                "y" => r.y = x,
                "mag" => r.mag = x,
                "disk_h_arcsec" => r.disk_h_arcsec = x,
                "e1" => r.e1 = x,
                "e1_int" => r.e1_int = x,
                _ => r.e2_int = x,
            }
        }
    }
    Ok(rows)
}

/// Bytes of submission allowed per truth object by [`run_submission_limit`]:
/// 256. A text row of `stepsim measure`'s catalogue takes about 65 bytes, and
/// one with every number at full precision (`%.17g`) and a long image id
/// about 128; a catalogue may list up to twice as many rows as the truth
/// has objects (stars, noise peaks, split objects), hence 2 × 128.
pub const SUBMISSION_BYTES_PER_TRUTH_ROW: u64 = 256;

/// Bytes of submission allowed per image on top of the rows (64 KiB: the
/// header and comments of a file in a per-image directory).
pub const SUBMISSION_BYTES_PER_IMAGE: u64 = 64 << 10;

/// The largest submission a run takes, in bytes (as stored and after gzip
/// decompression): [`SUBMISSION_BYTES_PER_TRUTH_ROW`] × the objects of its
/// truth tables + [`SUBMISSION_BYTES_PER_IMAGE`] × its images, and never
/// less than [`crate::read::input::MAX_SUBMISSION_BYTES`] (256 MiB). The object
/// counts come from the NAXIS2 of each truth table's header (no rows are
/// read). Errors name the truth table.
pub fn run_submission_limit(truth: &TruthSet) -> Result<u64, HarnessError> {
    use fitsio::hdu::HduInfo;
    use stepsim_contract::io::truth::TRUTH_EXTNAME;
    let rows: Vec<Result<u64, HarnessError>> = truth
        .index
        .images
        .par_iter()
        .map(|im| {
            let path = truth.truth_path(&im.image);
            let mut f = stepsim_contract::io::fits::open_fits(&path)?;
            let hdu = f.hdu(TRUTH_EXTNAME).map_err(|e| {
                HarnessError::truth(&path, crate::read::fits_table::fitsio_sentence(&e))
            })?;
            match hdu.info {
                HduInfo::TableInfo { num_rows, .. } => Ok(num_rows as u64),
                _ => Err(HarnessError::truth(
                    &path,
                    format!("the `{TRUTH_EXTNAME}` extension is not a table"),
                )),
            }
        })
        .collect();
    let mut n_rows = 0u64;
    for r in rows {
        n_rows = n_rows.saturating_add(r?);
    }
    let n_images = truth.index.images.len() as u64;
    Ok(SUBMISSION_BYTES_PER_TRUTH_ROW
        .saturating_mul(n_rows)
        .saturating_add(SUBMISSION_BYTES_PER_IMAGE.saturating_mul(n_images))
        .max(crate::read::input::MAX_SUBMISSION_BYTES))
}

impl TruthSet {
    /// Path of the truth table of an image.
    pub fn truth_path(&self, image: &str) -> PathBuf {
        PrivateDir::new(&self.dir).truth(image)
    }

    /// Reads the truth tables (scoring columns only) of the images `which`
    /// (indices into `index.images`), in parallel, in the order of `which`. Each
    /// thread opens its own file; the result does not depend on the thread
    /// count.
    pub fn load_tables(&self, which: &[usize]) -> Result<Vec<Vec<TruthRow>>, HarnessError> {
        which
            .par_iter()
            .map(|&i| {
                let path = self.truth_path(&self.index.images[i].image);
                read_scoring_columns(&path)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scoring_columns_read_back_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.fits");
        let rows: Vec<TruthRow> = (0..20)
            .map(|i| TruthRow {
                id: i,
                kind: (i % 2) as i32,
                x: 1.5 * i as f64,
                y: 2.5 * i as f64,
                mag: 20.0 + 0.1 * i as f64,
                disk_h_arcsec: 0.01 * i as f64,
                e1: 0.02 * i as f64,
                e1_int: -0.01 * i as f64,
                e2_int: 0.03 * i as f64,
                e2: 9.0,
                ..Default::default()
            })
            .collect();
        stepsim_contract::io::truth::write_truth_fits(&p, &rows, &[]).unwrap();
        let got = read_scoring_columns(&p).unwrap();
        for (a, b) in got.iter().zip(&rows) {
            assert_eq!(
                (
                    a.kind,
                    a.x,
                    a.y,
                    a.mag,
                    a.disk_h_arcsec,
                    a.e1,
                    a.e1_int,
                    a.e2_int
                ),
                (
                    b.kind,
                    b.x,
                    b.y,
                    b.mag,
                    b.disk_h_arcsec,
                    b.e1,
                    b.e1_int,
                    b.e2_int
                )
            );
            assert_eq!(a.e2, 0.0, "columns not needed are not read");
        }
        let e = read_scoring_columns(&dir.path().join("none.fits")).unwrap_err();
        assert!(e.to_string().contains("none.fits: no such file"), "{e}");
    }

    #[test]
    fn lensed_positions_come_from_the_config_and_a_bad_one_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let e = lensed_positions(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("config.json") && e.contains("cannot read"),
            "{e}"
        );
        let config = PrivateDir::new(dir.path()).config();
        for (text, want) in [
            (r#"{"population": {"lens_positions": true}}"#, Ok(true)),
            (r#"{"population": {"lens_positions": false}}"#, Ok(false)),
            (r#"{"population": {"rotated_pairs": true}}"#, Ok(false)),
            (r#"{"image": {}}"#, Ok(false)),
            (
                r#"{"population": {"lens_positions": "secret"}}"#,
                Err("population.lens_positions is a string, not true or false"),
            ),
            (
                r#"{"population": 5}"#,
                Err("population is a number, not an object"),
            ),
            ("[]", Err("an array, not an object")),
            (r#""x""#, Err("a string, not an object")),
            ("null", Err("null, not an object")),
            ("{\"population\": ", Err("not a config.json")),
        ] {
            std::fs::write(&config, text).unwrap();
            match (lensed_positions(dir.path()), want) {
                (Ok(got), Ok(w)) => assert_eq!(got, w, "{text}"),
                (Err(e), Err(w)) => {
                    let e = e.to_string();
                    assert!(e.contains("config.json") && e.contains(w), "{e}");
                    assert!(!e.contains("secret"), "the value is not echoed: {e}");
                }
                (got, w) => panic!("{text}: {got:?} against {w:?}"),
            }
        }
        std::fs::remove_file(&config).unwrap();
        std::fs::create_dir(&config).unwrap();
        let e = lensed_positions(dir.path()).unwrap_err().to_string();
        assert!(e.contains("config.json"), "{e}");
    }

    #[test]
    fn bad_datasets_json_is_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let e = load_truth_set(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("datasets.json") && e.contains("cannot read"),
            "{e}"
        );
        let p = PrivateDir::new(dir.path()).datasets();
        let entry = |id: &str| {
            format!(
                "{{\"dataset\": \"d{id}\", \"psf_id\": 0, \"psf\": \"none\", \"g1\": 0.0, \"g2\": 0.0, \
                 \"images\": [{{\"image\": \"i1\", \"field\": 0}}]}}"
            )
        };
        let doc = |fmt: &str, scale: f64, ds: &str| {
            format!(
                "{{\"format\": \"{fmt}\", \"width_px\": 10, \"height_px\": 10, \
                 \"pixel_scale_arcsec\": {scale}, \"datasets\": [{ds}]}}"
            )
        };
        let cases = [
            (doc("other-1", 0.2, &entry("a")), "format `other-1`"),
            (
                doc(DATASETS_FORMAT, 0.0, &entry("a")),
                "pixel_scale_arcsec 0",
            ),
            (
                doc(
                    DATASETS_FORMAT,
                    0.2,
                    &format!("{},{}", entry("a"), entry("b")),
                ),
                "image id `i1` appears twice",
            ),
            ("{\"format\": 1}".to_owned(), "not a datasets.json"),
        ];
        for (text, want) in cases {
            std::fs::write(&p, &text).unwrap();
            let e = load_truth_set(dir.path()).unwrap_err().to_string();
            assert!(e.contains("datasets.json") && e.contains(want), "{e}");
        }
        std::fs::write(&p, doc(DATASETS_FORMAT, 0.2, &entry("a"))).unwrap();
        // Without the run's config.json the plane of the isolated galaxies
        // is unknown: refused.
        let e = load_truth_set(dir.path()).unwrap_err().to_string();
        assert!(e.contains("config.json"), "{e}");
        let config = PrivateDir::new(dir.path()).config();
        std::fs::write(&config, r#"{"population": {"lens_positions": true}}"#).unwrap();
        let t = load_truth_set(dir.path()).unwrap();
        assert!(t.lensed_positions);
        // Lensed positions need shears below 1 to be undone.
        let big = entry("a").replace("\"g1\": 0.0, \"g2\": 0.0", "\"g1\": 0.8, \"g2\": 0.6");
        std::fs::write(&p, doc(DATASETS_FORMAT, 0.2, &big)).unwrap();
        let e = load_truth_set(dir.path()).unwrap_err().to_string();
        assert!(e.contains("dataset `da` has shear (0.8, 0.6)"), "{e}");
        std::fs::write(&config, "{}").unwrap();
        assert!(!load_truth_set(dir.path()).unwrap().lensed_positions);
        std::fs::write(&p, doc(DATASETS_FORMAT, 0.2, &entry("a"))).unwrap();
        let t = load_truth_set(dir.path()).unwrap();
        assert_eq!(t.index.images.len(), 1);
        assert!((t.index.image_area_arcmin2() - (2.0f64 / 60.0).powi(2)).abs() < 1e-15);
        assert!(t.index.on_image(0.5, 10.5) && !t.index.on_image(0.49, 1.0));
    }
}
