//! The organiser's side of a run: `RUN/private/datasets.json` and the truth
//! tables `RUN/private/truth/<image-id>.fits` (see `docs/run-layout.md`).

use crate::error::HarnessError;
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use stepsim_sim::run_layout::{DATASETS_FORMAT, Datasets};
use stepsim_sim::truth::TruthRow;

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
}

/// Reads `DIR/datasets.json` (DIR = `RUN/private`).
pub fn load_truth_set(dir: &Path) -> Result<TruthSet, HarnessError> {
    let path = dir.join("datasets.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| HarnessError::truth(&path, format!("cannot read: {e}")))?;
    let datasets: Datasets = serde_json::from_str(&text)
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
    Ok(TruthSet {
        datasets,
        index,
        dir: dir.to_path_buf(),
    })
}

impl TruthSet {
    /// Path of the truth table of an image.
    pub fn truth_path(&self, image: &str) -> PathBuf {
        self.dir.join("truth").join(format!("{image}.fits"))
    }

    /// Reads the truth tables of the images `which` (indices into
    /// `index.images`), in parallel, returned in the order of `which`. Each
    /// thread opens its own file; the result does not depend on the thread
    /// count.
    pub fn load_tables(&self, which: &[usize]) -> Result<Vec<Vec<TruthRow>>, HarnessError> {
        which
            .par_iter()
            .map(|&i| {
                let path = self.truth_path(&self.index.images[i].image);
                stepsim_sim::io::truth::read_truth_fits(&path).map_err(HarnessError::from)
            })
            .collect()
    }
}
