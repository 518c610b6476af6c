//! A whole public run directory: read `manifest.json`, measure every image
//! in parallel, write one submission (SPEC §6) sorted by image id, then y,
//! then x. The output is the same whatever the thread count: every step is
//! deterministic and pooled inputs are taken in image-id order.
//!
//! **Stars are pooled per dataset.** All images of a dataset share their
//! PSF (SPEC: a dataset is one PSF and one shear), so the stellar locus is
//! found on the star candidates of all of them together: a first pass
//! detects every image's objects and measures their moments, keeping them
//! ([`crate::pipeline::Detections`], no pixels), the locus of each dataset
//! is found on the pooled candidates ([`crate::stars::select_stars`]), and
//! a second pass finishes every image with its dataset's locus (each image
//! reads its pixels again and
//! still models the PSF from its own stars on that locus). Datasets are
//! measured in groups of at least 64 images, so the detections kept stay
//! small. A 1024² STEP1
//! image holds only 7–15 stars with ν ≥ 50; measured alone, 10 % of the
//! images of an 8-field `step1-mini` run found no locus and 3 % took a
//! clump of galaxies for it (docs/baseline.md). If the pooled search finds
//! nothing, each image falls back to its own.

use crate::error::KsbError;
use crate::io::{
    DETAILS_HEADER, SUBMISSION_HEADER, push_details_row, push_row, read_fits_image, read_manifest,
};
use crate::params::KsbParams;
use crate::pipeline::{Detections, ImageInfo, ImageMeasurement, detect_image};
use crate::stars::{StarSelection, select_stars};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use stepsim_contract::io::{IoError, write_atomically};
use stepsim_contract::run_dir::PublicDir;

/// Summary of one measured image.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSummary {
    /// Public image id.
    pub image: String,
    /// Public id of its dataset.
    pub dataset: String,
    /// Rows written.
    pub n_objects: usize,
    /// Rows with positive weight.
    pub n_weighted: usize,
    /// PSF stars.
    pub n_stars: usize,
    /// r_g* (pixels), if a locus was found.
    pub rg_star_px: Option<f64>,
    /// PSF model order, if any.
    pub psf_order: Option<usize>,
    /// The range of the P^γ calibration's k over the image's galaxies, if
    /// it was calibrated.
    pub calibration_k: Option<[f64; 2]>,
    /// With metadetection, its dataset's response R (`None` if it has
    /// none) and R's error by the jackknife over the dataset's images
    /// (`None` with one image).
    pub response: Option<DatasetResponse>,
    /// With metadetection, the image's own version sums (Σ e₁, Σ e₂ and
    /// the count of the objects selected on each of the five versions), of
    /// which its dataset's response is the pooled ratio.
    pub version_sums: Option<crate::metadetect::VersionSums>,
    /// With metadetection's `unshear`: the shear of the one version of
    /// the second measurement (−ĝ₀ of the dataset; zero when the dataset
    /// was not measured again, and then the sums are the unsheared
    /// version's) and Σ e₁, Σ e₂ and the count of the objects it selects.
    pub unsheared: Option<([f64; 2], [f64; 3])>,
}

/// A dataset's metadetection response and its error by the delete-one
/// jackknife over the dataset's images (`metadetect::response_error`).
pub type DatasetResponse = (Option<[[f64; 2]; 2]>, Option<[[f64; 2]; 2]>);

/// Told (images measured, images in all) after each group of images, so
/// that a long measurement can say how far it is.
pub type Progress<'a> = &'a (dyn Fn(usize, usize) + Sync);

/// Measures `public_dir` (holding `manifest.json`) with `threads` threads
/// (0: rayon's default) and writes the submission to `out`.
pub fn measure_run(
    public_dir: &Path,
    out: &Path,
    threads: usize,
    params: &KsbParams,
    progress: Progress,
) -> Result<Vec<ImageSummary>, KsbError> {
    let measured = measure_datasets(public_dir, out, None, threads, params, |_| true, progress)?;
    measured.write(out, &[], None)
}

/// [`measure_run`], also writing the details table to `details`: the
/// submission's rows in its order, each followed by the pipeline's own
/// quantities (docs/ksb.md, "The details table"). The table is written
/// before the submission, so a submission written means its table is too.
pub fn measure_run_with_details(
    public_dir: &Path,
    out: &Path,
    details: &Path,
    threads: usize,
    params: &KsbParams,
    progress: Progress,
) -> Result<Vec<ImageSummary>, KsbError> {
    let measured = measure_datasets(
        public_dir,
        out,
        Some(details),
        threads,
        params,
        |_| true,
        progress,
    )?;
    measured.write(out, &[], Some(details))
}

/// The datasets of shard `k` of `n` (1-based): the dataset ids of the
/// manifest sorted, and the one at position p belongs to shard p mod n + 1.
/// Sharding by dataset keeps the star pooling (which is per dataset) whole,
/// so the shards' rows are exactly those of an unsharded run.
pub fn shard_datasets(manifest_datasets: &[&str], k: u32, n: u32) -> Vec<String> {
    let mut ids: Vec<&str> = manifest_datasets.to_vec();
    ids.sort_unstable();
    ids.dedup();
    ids.iter()
        .enumerate()
        .filter(|(p, _)| p % n as usize == (k - 1) as usize)
        .map(|(_, d)| d.to_string())
        .collect()
}

/// The part a measure shard writes: `<SUB>.shards/K-of-N.txt` (a
/// submission of the shard's datasets).
pub fn part_path(out: &Path, k: u32, n: u32) -> std::path::PathBuf {
    let mut dir = out.as_os_str().to_owned();
    dir.push(".shards");
    std::path::PathBuf::from(dir).join(format!("{k}-of-{n}.txt"))
}

/// Measures the datasets of shard `k` of `n` (`shard_datasets`) and
/// writes them to [`part_path`]`(out, k, n)`, a submission of those images
/// only; the first line after the header records the manifest's SHA-256
/// (`# manifest-sha256 <hex>`), so that [`join_parts`] refuses parts of
/// another run.
pub fn measure_shard(
    public_dir: &Path,
    out: &Path,
    k: u32,
    n: u32,
    threads: usize,
    params: &KsbParams,
    progress: Progress,
) -> Result<Vec<ImageSummary>, KsbError> {
    let manifest_path = PublicDir::new(public_dir).manifest();
    let manifest = read_manifest(&manifest_path)?;
    let all: Vec<&str> = manifest.images.iter().map(|i| i.dataset.as_str()).collect();
    let mine = shard_datasets(&all, k, n);
    let path = part_path(out, k, n);
    let measured = measure_datasets(
        public_dir,
        &path,
        None,
        threads,
        params,
        |d| mine.iter().any(|m| m == d),
        progress,
    )?;
    let sha = manifest_sha256(&manifest_path)?;
    measured.write(&path, &[format!("{MANIFEST_LINE}{sha}")], None)
}

const MANIFEST_LINE: &str = "# manifest-sha256 ";

fn manifest_sha256(path: &Path) -> Result<String, KsbError> {
    let bytes = std::fs::read(path).map_err(|e| stepsim_contract::io::IoError::os(path, e))?;
    Ok(stepsim_contract::digest::sha256_hex(&bytes))
}

/// Joins the parts of an `n`-shard measure of `public_dir` into the one
/// submission `out`: every part `1..=n` must exist and name this manifest;
/// the images' rows are taken whole and put in image-id order, so the result
/// is byte-identical to [`measure_run`]'s. Returns (parts, images) or an
/// error naming the missing or foreign part. Nothing is written on refusal.
pub fn join_parts(public_dir: &Path, out: &Path, n: u32) -> Result<(u32, usize), KsbError> {
    let manifest_path = PublicDir::new(public_dir).manifest();
    let manifest = read_manifest(&manifest_path)?;
    let sha = manifest_sha256(&manifest_path)?;
    let mut blocks: BTreeMap<String, String> = BTreeMap::new();
    let mut header = String::new();
    for k in 1..=n {
        let path = part_path(out, k, n);
        let text = std::fs::read_to_string(&path).map_err(|e| KsbError::Part {
            path: path.clone(),
            message: format!("cannot read it ({e}); run measure --shard {k}/{n} first"),
        })?;
        let mut lines = text.lines();
        header = lines.next().unwrap_or_default().to_string();
        if lines.next() != Some(&format!("{MANIFEST_LINE}{sha}")) {
            return Err(KsbError::Part {
                path,
                message: format!(
                    "it was not made from {}; run measure --shard {k}/{n} again",
                    manifest_path.display()
                ),
            });
        }
        for line in lines {
            let image = line.split_whitespace().next().unwrap_or_default();
            let block = blocks.entry(image.to_string()).or_default();
            block.push_str(line);
            block.push('\n');
        }
    }
    // Shard k measured exactly the datasets of shard_datasets(.., k, n):
    // parts 1..=n of this manifest cover every image once.
    let mut text = header;
    text.push('\n');
    for block in blocks.values() {
        text.push_str(block);
    }
    stepsim_contract::io::write_bytes_atomically(out, text.as_bytes())?;
    Ok((n, manifest.images.len()))
}

/// The number of shards of the parts found beside `out` (`<SUB>.shards/`),
/// when they all say the same N.
pub fn parts_count(out: &Path) -> Result<u32, KsbError> {
    let dir = part_path(out, 1, 1)
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let entries = std::fs::read_dir(&dir).map_err(|e| KsbError::Part {
        path: dir.clone(),
        message: format!("no measure shards found ({e}); run measure --shard K/N first"),
    })?;
    let mut ns = std::collections::BTreeSet::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(n) = name
            .strip_suffix(".txt")
            .and_then(|s| s.split_once("-of-"))
            .and_then(|(_, n)| n.parse::<u32>().ok())
        {
            ns.insert(n);
        }
    }
    match ns.len() {
        1 => Ok(*ns.iter().next().expect("one")),
        0 => Err(KsbError::Part {
            path: dir,
            message: "no measure shards found; run measure --shard K/N first".into(),
        }),
        _ => Err(KsbError::Part {
            path: dir,
            message: format!(
                "parts of different shard counts ({ns:?}); delete the directory and measure again"
            ),
        }),
    }
}

fn summary(
    im: &stepsim_contract::run_layout::ManifestImage,
    m: &ImageMeasurement,
    response: Option<DatasetResponse>,
) -> ImageSummary {
    ImageSummary {
        image: im.image.clone(),
        dataset: im.dataset.clone(),
        response,
        version_sums: m.version_sums,
        unsheared: None,
        n_objects: m.objects.len(),
        n_weighted: m.objects.iter().filter(|o| o.weight > 0.0).count(),
        n_stars: m.n_stars,
        rg_star_px: m.locus.map(|l| l.rg_star),
        psf_order: m.psf_order,
        calibration_k: m.calibration_k,
    }
}

/// The rows of measured images, kept in a file beside the submission
/// (`<SUB>.rows.tmp`) until they are written in image-id order: images are
/// measured in groups of whole datasets, scattered in id order, and the
/// rows of a full STEP1 preset (19.8 M) held in memory took 7.9 GiB. The
/// file is removed when this is dropped, whether the submission was
/// written or not.
struct Spill {
    path: PathBuf,
    file: std::fs::File,
    end: u64,
    /// (offset, length) of each image's rows, by position in id order.
    blocks: Vec<(u64, usize)>,
}

/// The file where a run's rows wait until they are written to `out`:
/// `<OUT>.rows.tmp`, removed when `measure` ends.
pub fn rows_path(out: &Path) -> PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(".rows.tmp");
    PathBuf::from(name)
}

impl Spill {
    fn beside(sub: &Path, n_images: usize) -> Result<Self, KsbError> {
        let path = rows_path(sub);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
        }
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(|e| IoError::os(&path, e))?;
        Ok(Self {
            path,
            file,
            end: 0,
            blocks: vec![(0, 0); n_images],
        })
    }

    /// Keeps the rows of image `i` (position in id order).
    fn put(&mut self, i: usize, rows: &str) -> Result<(), KsbError> {
        self.file
            .write_all(rows.as_bytes())
            .map_err(|e| IoError::os(&self.path, e))?;
        self.blocks[i] = (self.end, rows.len());
        self.end += rows.len() as u64;
        Ok(())
    }

    /// Copies every image's rows, in id order, to `w` (writing `dest`).
    fn copy_in_order(&mut self, w: &mut impl Write, dest: &Path) -> Result<(), KsbError> {
        let mut buf = Vec::new();
        for &(at, len) in &self.blocks {
            buf.resize(len, 0);
            self.file
                .seek(SeekFrom::Start(at))
                .and_then(|_| self.file.read_exact(&mut buf))
                .map_err(|e| IoError::os(&self.path, e))?;
            w.write_all(&buf).map_err(|e| IoError::os(dest, e))?;
        }
        Ok(())
    }
}

impl Drop for Spill {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// What [`measure_datasets`] made: each image's summary, its rows, and
/// their details lines when asked for.
struct Measured {
    summaries: Vec<ImageSummary>,
    rows: Spill,
    details: Option<Spill>,
}

impl Measured {
    /// Writes the submission `sub` atomically: the header, the `extra`
    /// lines, then the rows of every image in image-id order (each image's
    /// sorted by y, then x); first the details table to `details`, the
    /// same way, when it was kept, removed again if the submission cannot
    /// be written (so that a table is never left beside another run's
    /// submission, or none).
    fn write(
        mut self,
        sub: &Path,
        extra: &[String],
        details: Option<&Path>,
    ) -> Result<Vec<ImageSummary>, KsbError> {
        if let (Some(spill), Some(path)) = (self.details.as_mut(), details) {
            write_in_order(path, &format!("{DETAILS_HEADER}\n"), spill)?;
        }
        let mut head = format!("{SUBMISSION_HEADER}\n");
        for line in extra {
            head.push_str(line);
            head.push('\n');
        }
        let written = write_in_order(sub, &head, &mut self.rows);
        if let (Err(_), Some(path)) = (&written, details) {
            let _ = std::fs::remove_file(path);
        }
        written?;
        Ok(self.summaries)
    }
}

/// Writes `head`, then every image's rows kept in `spill` in image-id
/// order, to `path` atomically.
fn write_in_order(path: &Path, head: &str, spill: &mut Spill) -> Result<(), KsbError> {
    write_atomically(path, |tmp| -> Result<(), KsbError> {
        let file = std::fs::File::create(tmp).map_err(|e| IoError::os(tmp, e))?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        w.write_all(head.as_bytes())
            .map_err(|e| IoError::os(tmp, e))?;
        spill.copy_in_order(&mut w, tmp)?;
        w.flush().map_err(|e| IoError::os(tmp, e))?;
        Ok(())
    })
}

/// Measures the images of the datasets `keep` accepts (in image-id order),
/// pooling star candidates per dataset (two passes), keeping their rows
/// beside the submission `sub` ([`Spill`]), and their details lines beside
/// `details` when given.
fn measure_datasets(
    public_dir: &Path,
    sub: &Path,
    details: Option<&Path>,
    threads: usize,
    params: &KsbParams,
    keep: impl Fn(&str) -> bool,
    progress: Progress,
) -> Result<Measured, KsbError> {
    params.validate()?;
    let public = PublicDir::new(public_dir);
    let manifest_path = public.manifest();
    let manifest = read_manifest(&manifest_path)?;
    let inst = &manifest.instrument;
    let gain = inst.gain_e_per_adu;
    let info = ImageInfo {
        zeropoint_eff_mag: inst.zeropoint_mag + 2.5 * inst.exposure_s.max(1e-30).log10(),
        saturation_e: (inst.saturation_adu > 0.0).then_some((inst.saturation_adu - 0.5) * gain),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| KsbError::Threads {
            threads,
            message: e.to_string(),
        })?;
    let mut images: Vec<stepsim_contract::run_layout::ManifestImage> = manifest
        .images
        .iter()
        .filter(|im| keep(&im.dataset))
        .cloned()
        .collect();
    images.sort_by(|a, b| a.image.cmp(&b.image));
    let read =
        |im: &stepsim_contract::run_layout::ManifestImage| -> Result<crate::image::Image, KsbError> {
            let path = public.file(&im.file);
            let img = read_fits_image(&path)?;
            if img.width != inst.width_px as usize || img.height != inst.height_px as usize {
                return Err(KsbError::Image {
                    path,
                    message: format!(
                        "image is {} × {}, the manifest says {} × {}",
                        img.width, img.height, inst.width_px, inst.height_px
                    ),
                });
            }
            Ok(img.scaled(gain as f32))
        };
    // Datasets in groups of at least GROUP_IMAGES images (so that the
    // images in flight fill the threads while the detections kept stay
    // small); within a group, pass 1 detects and measures every image once
    // and keeps the result, the locus of each dataset is found on the
    // pooled candidates, and pass 2 finishes every image with it.
    const GROUP_IMAGES: usize = 64;
    let mut rows = Spill::beside(sub, images.len())?;
    let mut details = details
        .map(|d| Spill::beside(d, images.len()))
        .transpose()?;
    let mut by_dataset: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, im) in images.iter().enumerate() {
        by_dataset.entry(im.dataset.as_str()).or_default().push(i);
    }
    let mut slots: Vec<Option<ImageSummary>> = vec![None; images.len()];
    let mut responses: Vec<Option<DatasetResponse>> = vec![None; images.len()];
    let mut unsheared: Vec<Option<([f64; 2], [f64; 3])>> = vec![None; images.len()];
    let mut group: Vec<usize> = Vec::new();
    let datasets: Vec<&Vec<usize>> = by_dataset.values().collect();
    let mut n_done = 0;
    let mut group_start = 0;
    for (n, members) in datasets.iter().enumerate() {
        if group.is_empty() {
            group_start = n;
        }
        group.extend_from_slice(members);
        if group.len() < GROUP_IMAGES && n + 1 < datasets.len() {
            continue;
        }
        group.sort_unstable();
        let mut done = pool.install(|| measure_group(&images, &group, &read, &info, params))?;
        if params.method == crate::params::Method::Metacal {
            // One response per dataset: its images share the PSF and the shear.
            for members in datasets[group_start..=n].iter() {
                let objs = group
                    .iter()
                    .zip(done.iter_mut())
                    .filter(|(i, _)| members.contains(i))
                    .flat_map(|(_, m)| m.objects.iter_mut());
                crate::metacal::apply_response(objs);
            }
        }
        if params.method == crate::params::Method::Metadetect {
            // One response per dataset, from its images' version sums.
            for members in datasets[group_start..=n].iter() {
                let sums: Vec<crate::metadetect::VersionSums> = group
                    .iter()
                    .zip(done.iter())
                    .filter(|(i, _)| members.contains(i))
                    .filter_map(|(_, m)| m.version_sums)
                    .collect();
                let r = crate::metadetect::response(&sums);
                let err = crate::metadetect::response_error(&sums);
                for &i in members.iter() {
                    responses[i] = Some((r, err));
                }
                let applied = r.and_then(crate::metadetect::applied_response);
                let origin = if params.unshear {
                    first_estimate(&sums, applied)
                } else {
                    None
                };
                if let Some(g0) = origin {
                    // The second measurement: each image once more, as one
                    // version sheared by −ĝ₀, whose detections are the rows.
                    let again = KsbParams {
                        metadetect_origin: [-g0[0], -g0[1]],
                        ..params.clone()
                    };
                    let own: Vec<usize> = members.to_vec();
                    let second =
                        pool.install(|| measure_group(&images, &own, &read, &info, &again))?;
                    for (i, m2) in own.iter().zip(second) {
                        let k = group.binary_search(i).expect("a member of the group");
                        unsheared[*i] = Some((
                            again.metadetect_origin,
                            m2.version_sums.map_or([0.0; 3], |v| v[0]),
                        ));
                        done[k].objects = m2.objects;
                    }
                } else if params.unshear {
                    for &i in members.iter() {
                        let k = group.binary_search(&i).expect("a member of the group");
                        unsheared[i] =
                            Some(([0.0; 2], done[k].version_sums.map_or([0.0; 3], |v| v[0])));
                    }
                }
                let objs = group
                    .iter()
                    .zip(done.iter_mut())
                    .filter(|(i, _)| members.contains(i))
                    .flat_map(|(_, m)| m.objects.iter_mut());
                crate::metacal::set_rows_about(objs, applied, origin.unwrap_or([0.0; 2]));
            }
        }
        for (&i, m) in group.iter().zip(done) {
            let mut text = String::new();
            for o in &m.objects {
                push_row(&mut text, &images[i].image, o);
            }
            rows.put(i, &text)?;
            if let Some(d) = details.as_mut() {
                text.clear();
                for o in &m.objects {
                    push_details_row(&mut text, &images[i].image, o);
                }
                d.put(i, &text)?;
            }
            let mut sm = summary(&images[i], &m, responses[i]);
            sm.unsheared = unsheared[i];
            slots[i] = Some(sm);
        }
        n_done += group.len();
        progress(n_done, images.len());
        group.clear();
    }
    let summaries = slots
        .into_iter()
        .map(|m| m.expect("every image is in one group"))
        .collect();
    Ok(Measured {
        summaries,
        rows,
        details,
    })
}

/// A dataset's first estimate ĝ₀ = R⁻¹ ⟨e⟩ (R's diagonal, as the rows
/// use it; ⟨e⟩ over the objects its images' unsheared versions select),
/// the shear its images are sheared back by in metadetection's second
/// measurement (`KsbParams::unshear`). `None`, and no second measurement,
/// without a response or a selected object, or when |ĝ₀| is not below
/// [`crate::params::MAX_ORIGIN_SHEAR`].
fn first_estimate(
    sums: &[crate::metadetect::VersionSums],
    applied: Option<[[f64; 2]; 2]>,
) -> Option<[f64; 2]> {
    let r = applied?;
    let mut tot = [0.0; 3];
    for s in sums {
        for (t, v) in tot.iter_mut().zip(s[0]) {
            *t += v;
        }
    }
    if tot[2] <= 0.0 {
        return None;
    }
    let g0 = [tot[0] / tot[2] / r[0][0], tot[1] / tot[2] / r[1][1]];
    let modulus = g0[0].hypot(g0[1]);
    (modulus.is_finite() && modulus > 0.0 && modulus < crate::params::MAX_ORIGIN_SHEAR)
        .then_some(g0)
}

/// Measures the images `group` (indices into `images`, ascending; whole
/// datasets): pass 1 detects and measures each image once and keeps its
/// [`Detections`], the locus of each dataset comes from the pooled
/// candidates (image-id order), and pass 2 reads each image again,
/// subtracts its background and finishes it with its dataset's locus, or
/// with its own when the pooled search finds none. The same rows as
/// measuring every image twice from scratch.
fn measure_group(
    images: &[stepsim_contract::run_layout::ManifestImage],
    group: &[usize],
    read: &(
         dyn Fn(
        &stepsim_contract::run_layout::ManifestImage,
    ) -> Result<crate::image::Image, KsbError>
             + Sync
     ),
    info: &ImageInfo,
    params: &KsbParams,
) -> Result<Vec<ImageMeasurement>, KsbError> {
    let first: Vec<Result<Detections, KsbError>> = group
        .par_iter()
        .map(|&i| Ok(detect_image(&read(&images[i])?, info, params)?.0))
        .collect();
    let mut kept = Vec::with_capacity(first.len());
    for r in first {
        kept.push(r?);
    }
    let mut pooled: BTreeMap<&str, Vec<crate::stars::SizeMag>> = BTreeMap::new();
    for (&i, d) in group.iter().zip(&kept) {
        pooled
            .entry(images[i].dataset.as_str())
            .or_default()
            .extend_from_slice(d.star_candidates());
    }
    let selection: BTreeMap<&str, Option<StarSelection>> = pooled
        .iter()
        .map(|(d, objs)| (*d, select_stars(objs, params)))
        .collect();
    let second: Vec<Result<ImageMeasurement, KsbError>> = group
        .par_iter()
        .zip(kept)
        .map(|(&i, d)| {
            let sub = d.subtract_background(read(&images[i])?);
            Ok(d.finish(&sub, info, params, selection[images[i].dataset.as_str()]))
        })
        .collect();
    second.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::pipeline::measure_image;
    use crate::scene::{SceneSpec, synthetic_scene, write_public_run};

    fn spec(n_stars: usize, seed: u64) -> SceneSpec {
        SceneSpec {
            width: 512,
            height: 512,
            n_galaxy_pairs: 60,
            n_stars,
            star_flux_e: (1e5, 3e6),
            ..SceneSpec::step_like([0.0, 0.0], [0.04, 0.01], seed)
        }
    }

    #[test]
    fn the_details_table_is_the_submission_with_the_estimate_s_parts() {
        // Two images of one dataset: the table has the submission's lines
        // (its first seven columns) in its order, and every weighted row's
        // γ̂ is its e_cor / P^γ (P^γ with the calibration's k in it, k near
        // 1) and its weight 1 / (σ_int² + σ_γ²), as written to six decimals;
        // the table does not change the submission. Without the
        // calibration k is 1, P^γ is the calibrated one over k and e_cor is
        // the same.
        let dir = tempfile::tempdir().unwrap();
        let scenes: Vec<(&str, &str, Image)> = [("ia", 11), ("ib", 12)]
            .into_iter()
            .map(|(id, seed)| ("d0", id, synthetic_scene(&spec(80, seed)).1))
            .collect();
        let refs: Vec<(&str, &str, &Image)> =
            scenes.iter().map(|(d, i, img)| (*d, *i, img)).collect();
        write_public_run(dir.path(), &refs).unwrap();
        let (plain, out, details) = (
            dir.path().join("plain.txt"),
            dir.path().join("sub.txt"),
            dir.path().join("sub.details"),
        );
        let params = KsbParams::default();
        measure_run(dir.path(), &plain, 2, &params, &|_, _| {}).unwrap();
        measure_run_with_details(dir.path(), &out, &details, 1, &params, &|_, _| {}).unwrap();
        let sub = std::fs::read_to_string(&out).unwrap();
        assert_eq!(sub, std::fs::read_to_string(&plain).unwrap());
        let table = std::fs::read_to_string(&details).unwrap();
        let mut lines = table.lines();
        assert_eq!(lines.next(), Some(DETAILS_HEADER));
        let (mut weighted, mut n) = (0, 0);
        for (d, s) in lines.zip(sub.lines().skip(1)) {
            n += 1;
            let cols: Vec<&str> = d.split(' ').collect();
            assert_eq!(cols.len(), 26, "{d}");
            assert_eq!(cols[..7].join(" "), s);
            // Metacal's columns are empty under KSB+.
            assert!(
                cols[15..25].iter().all(|c| *c == "nan") && cols[25] == "0",
                "{d}"
            );
            let v = |i: usize| cols[i].parse::<f64>().unwrap();
            if v(5) > 0.0 {
                weighted += 1;
                let (pg, e1, e2, sg) = (v(10), v(12), v(13), v(14));
                assert!(
                    v(7) > 1.0 && v(8) >= params.ksb_min_sn && v(9) > 15.0,
                    "{d}"
                );
                assert!((0.5..1.5).contains(&v(11)), "{d}");
                assert!(
                    (v(3) - e1 / pg).abs() < 2e-5 * (1.0 + v(3).abs()) / pg,
                    "{d}"
                );
                assert!(
                    (v(4) - e2 / pg).abs() < 2e-5 * (1.0 + v(4).abs()) / pg,
                    "{d}"
                );
                let w = 1.0 / (params.sigma_int.powi(2) + sg * sg);
                assert!((v(5) / w - 1.0).abs() < 1e-4, "{d}");
            }
        }
        assert_eq!(n, sub.lines().count() - 1);
        assert!(weighted > 50, "{weighted}");
        let rows = |text: &str| -> Vec<Vec<String>> {
            text.lines()
                .skip(1)
                .map(|l| l.split(' ').map(str::to_string).collect())
                .collect()
        };
        let cal = rows(&table);
        let num = |c: &[String], i: usize| c[i].parse::<f64>().unwrap();
        // ν is the column LOW_SN compares (rows with no moments have 0).
        for c in cal.iter().filter(|c| (num(c, 8) - 20.0).abs() > 0.01) {
            let low_sn = num(c, 6) as u32 & crate::flags::LOW_SN != 0;
            assert_eq!(low_sn, num(c, 8) < params.ksb_min_sn, "{c:?}");
        }
        // The calibration is on (k ≠ 1 somewhere), and P^γ is k times the
        // uncalibrated one, e_cor the same, row by row.
        let k_off = cal
            .iter()
            .filter(|c| num(c, 5) > 0.0 && (num(c, 11) - 1.0).abs() > 1e-3)
            .count();
        assert!(k_off > 10, "{k_off}");
        let none = dir.path().join("none.details");
        let uncal = KsbParams {
            calibration: None,
            ..params
        };
        let none_sub = dir.path().join("none.txt");
        measure_run_with_details(dir.path(), &none_sub, &none, 2, &uncal, &|_, _| {}).unwrap();
        let uncal_rows = rows(&std::fs::read_to_string(&none).unwrap());
        assert_eq!(uncal_rows.len(), cal.len());
        let mut compared = 0;
        for (c, u) in cal.iter().zip(&uncal_rows) {
            assert_eq!((&c[..3], &c[12..14]), (&u[..3], &u[12..14]));
            if c[10] != "nan" {
                assert_eq!(u[11], "1.000000");
                let (pc, pu, k) = (num(c, 10), num(u, 10), num(c, 11));
                assert!((pc - k * pu).abs() < 2e-6 * (1.0 + k), "{c:?} {u:?}");
                compared += 1;
            }
        }
        assert!(compared > 50, "{compared}");
        // Nothing is left beside the outputs but the outputs.
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect();
        left.sort();
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn an_image_poor_in_stars_takes_the_locus_of_its_dataset() {
        // Dataset d0: image "ia" with 80 stars, image "ib" with the same PSF
        // and only 2 stars. Alone, "ib" has no locus (fewer than 3
        // candidates on it); pooled with "ia" it gets r_g* = 1.856 px
        // (the PSF's σ) within 1 %. Image "ic" of another dataset with 2
        // stars is not helped.
        let dir = tempfile::tempdir().unwrap();
        let info = ImageInfo {
            zeropoint_eff_mag: 26.0 + 2.5 * 3600f64.log10(),
            saturation_e: Some(65534.5 * 4.0),
        };
        let mut scenes = Vec::new();
        for (id, dataset, n_stars, seed) in
            [("ia", "d0", 80, 1), ("ib", "d0", 2, 2), ("ic", "d1", 2, 3)]
        {
            let (_, img) = synthetic_scene(&spec(n_stars, seed));
            if id == "ib" {
                let alone = measure_image(&img, &info, &KsbParams::default()).unwrap();
                assert_eq!(alone.locus, None);
            }
            scenes.push((dataset, id, img));
        }
        let refs: Vec<(&str, &str, &Image)> =
            scenes.iter().map(|(d, i, img)| (*d, *i, img)).collect();
        write_public_run(dir.path(), &refs).unwrap();
        let out = dir.path().join("sub.txt");
        let told = std::sync::Mutex::new(Vec::new());
        let s = measure_run(dir.path(), &out, 1, &KsbParams::default(), &|d, n| {
            told.lock().unwrap().push((d, n))
        })
        .unwrap();
        // Three images (fewer than a group of 64): told once, at the end.
        assert_eq!(told.into_inner().unwrap(), [(3, 3)]);
        let rg = |id: &str| s.iter().find(|x| x.image == id).unwrap().rg_star_px;
        let a = rg("ia").expect("locus of ia");
        assert!((a / 1.856 - 1.0).abs() < 0.01, "{a}");
        assert_eq!(rg("ib"), Some(a));
        assert_eq!(rg("ic"), None);
    }

    #[test]
    fn metacal_rows_are_one_response_per_dataset_at_any_thread_count() {
        // Two datasets of two images each, measured with --method metacal
        // on 1 and on 2 threads: the same bytes. Every weighted row has
        // weight 1 and is R⁻¹ e(0) with R its dataset's response, computed
        // here from the images measured alone.
        let dir = tempfile::tempdir().unwrap();
        let params = KsbParams {
            method: crate::params::Method::Metacal,
            ..KsbParams::default()
        };
        let mut scenes = Vec::new();
        for (id, dataset, seed) in [
            ("ia", "d0", 21),
            ("ib", "d0", 22),
            ("ic", "d1", 23),
            ("id", "d1", 24),
        ] {
            let (_, img) = synthetic_scene(&spec(80, seed));
            scenes.push((dataset, id, img));
        }
        let refs: Vec<(&str, &str, &Image)> =
            scenes.iter().map(|(d, i, img)| (*d, *i, img)).collect();
        write_public_run(dir.path(), &refs).unwrap();
        let one = dir.path().join("one.txt");
        let two = dir.path().join("two.txt");
        measure_run(dir.path(), &one, 1, &params, &|_, _| {}).unwrap();
        measure_run(dir.path(), &two, 2, &params, &|_, _| {}).unwrap();
        let text = std::fs::read_to_string(&one).unwrap();
        assert_eq!(text, std::fs::read_to_string(&two).unwrap());

        let manifest = read_manifest(&PublicDir::new(dir.path()).manifest()).unwrap();
        let gain = manifest.instrument.gain_e_per_adu as f32;
        let info = ImageInfo {
            zeropoint_eff_mag: 26.0 + 2.5 * 3600f64.log10(),
            saturation_e: Some(65534.5 * 4.0),
        };
        let mut weighted = 0;
        for dataset in ["d0", "d1"] {
            let ims: Vec<_> = manifest
                .images
                .iter()
                .filter(|im| im.dataset == dataset)
                .collect();
            let mut all = Vec::new();
            let mut rows = Vec::new();
            let mut pooled = Vec::new();
            let dets: Vec<_> = ims
                .iter()
                .map(|im| {
                    let img = read_fits_image(&PublicDir::new(dir.path()).file(&im.file))
                        .unwrap()
                        .scaled(gain);
                    let (d, sub) = detect_image(&img, &info, &params).unwrap();
                    pooled.extend_from_slice(d.star_candidates());
                    (im.image.clone(), d, sub)
                })
                .collect();
            let sel = select_stars(&pooled, &params);
            for (id, d, sub) in dets {
                let m = d.finish(&sub, &info, &params, sel);
                all.extend(m.objects.iter().filter_map(|o| o.metacal));
                rows.extend(m.objects.into_iter().map(|o| (id.clone(), o)));
            }
            let r = crate::metacal::response(&all).expect("a response");
            for (id, o) in rows {
                let Some((mc, sel)) = o.metacal else {
                    continue;
                };
                if !(sel[0] && o.flags == 0) {
                    continue;
                }
                let e = crate::metacal::apply_inverse(&r, mc.e[0]);
                let line = format!(
                    "{id} {:.3} {:.3} {:.6} {:.6} 1.000000 0",
                    o.x, o.y, e[0], e[1]
                );
                assert!(
                    text.lines().any(|l| l == line),
                    "{line} not in the submission"
                );
                weighted += 1;
            }
        }
        let n = text
            .lines()
            .filter(|l| !l.starts_with('#') && l.split(' ').nth(5) != Some("0.000000"))
            .count();
        assert_eq!(n, weighted);
        assert!(weighted > 60, "{weighted}");
    }

    #[test]
    fn keeping_the_first_pass_gives_the_rows_of_measuring_twice() {
        // The slow, obvious twin of measure_group: every image measured
        // alone from its pixels, the pooled locus per dataset, then every
        // image measured again from its pixels with it. Three datasets
        // (rich, poor, and one poor alone), identical submissions.
        let dir = tempfile::tempdir().unwrap();
        let info = ImageInfo {
            zeropoint_eff_mag: 26.0 + 2.5 * 3600f64.log10(),
            saturation_e: Some(65534.5 * 4.0),
        };
        let params = KsbParams::default();
        let mut scenes = Vec::new();
        for (id, dataset, n_stars, seed) in [
            ("ia", "d0", 80, 11),
            ("ib", "d0", 2, 12),
            ("ic", "d1", 2, 13),
            ("id", "d2", 40, 14),
            ("ie", "d2", 30, 15),
        ] {
            let (_, img) = synthetic_scene(&spec(n_stars, seed));
            scenes.push((dataset, id, img));
        }
        let refs: Vec<(&str, &str, &Image)> =
            scenes.iter().map(|(d, i, img)| (*d, *i, img)).collect();
        write_public_run(dir.path(), &refs).unwrap();
        let out = dir.path().join("sub.txt");
        measure_run(dir.path(), &out, 2, &params, &|_, _| {}).unwrap();
        // The rows kept beside it while measuring are gone.
        assert!(!dir.path().join("sub.txt.rows.tmp").exists());

        // A damaged image: refused, and neither the submission nor the
        // kept rows are left.
        let manifest = read_manifest(&PublicDir::new(dir.path()).manifest()).unwrap();
        let damaged = PublicDir::new(dir.path()).file(&manifest.images[3].file);
        let bytes = std::fs::read(&damaged).unwrap();
        std::fs::write(&damaged, &bytes[..bytes.len() / 2]).unwrap();
        let bad = dir.path().join("bad.txt");
        assert!(measure_run(dir.path(), &bad, 2, &params, &|_, _| {}).is_err());
        assert!(!bad.exists() && !dir.path().join("bad.txt.rows.tmp").exists());
        std::fs::write(&damaged, &bytes).unwrap();

        // The electrons measure_run sees: the written file, read back.
        let manifest = read_manifest(&PublicDir::new(dir.path()).manifest()).unwrap();
        let gain = manifest.instrument.gain_e_per_adu as f32;
        let mut images = manifest.images.clone();
        images.sort_by(|a, b| a.image.cmp(&b.image));
        let pixels: Vec<Image> = images
            .iter()
            .map(|im| {
                read_fits_image(&PublicDir::new(dir.path()).file(&im.file))
                    .unwrap()
                    .scaled(gain)
            })
            .collect();
        let alone: Vec<ImageMeasurement> = pixels
            .iter()
            .map(|img| crate::pipeline::measure_image_with(img, &info, &params, None).unwrap())
            .collect();
        let mut pooled: BTreeMap<&str, Vec<crate::stars::SizeMag>> = BTreeMap::new();
        for (im, m) in images.iter().zip(&alone) {
            pooled
                .entry(im.dataset.as_str())
                .or_default()
                .extend_from_slice(&m.star_candidates);
        }
        let twice: Vec<ImageMeasurement> = images
            .iter()
            .zip(&pixels)
            .zip(alone)
            .map(
                |((im, img), a)| match select_stars(&pooled[im.dataset.as_str()], &params) {
                    Some(s) => {
                        crate::pipeline::measure_image_with(img, &info, &params, Some(s)).unwrap()
                    }
                    None => a,
                },
            )
            .collect();
        let want = dir.path().join("twice.txt");
        let rows = images
            .iter()
            .zip(&twice)
            .flat_map(|(im, m)| m.objects.iter().map(move |o| (im.image.as_str(), o)));
        crate::io::write_submission(&want, rows).unwrap();
        let (got, want) = (std::fs::read(&out).unwrap(), std::fs::read(&want).unwrap());
        assert!(got.len() > 500);
        assert!(got == want, "submissions differ");
    }

    #[test]
    fn the_first_estimate_is_the_unsheared_versions_mean_over_r_or_none() {
        let r = Some([[0.5, 0.0], [0.0, 0.25]]);
        let image = |e1: f64, e2: f64, n: f64| {
            let mut s = [[1.0; 3]; 5];
            s[0] = [e1, e2, n];
            s
        };
        // Pooled over the images: (0.02 + 0.06) / 4 / 0.5, (0.01 + 0.01) / 4 / 0.25.
        let g0 = first_estimate(&[image(0.02, 0.01, 1.0), image(0.06, 0.01, 3.0)], r).unwrap();
        assert!(
            (g0[0] - 0.04).abs() < 1e-15 && (g0[1] - 0.02).abs() < 1e-15,
            "{g0:?}"
        );
        // No response, nothing selected, a zero estimate, or |ĝ₀| ≥ 0.2.
        assert_eq!(first_estimate(&[image(0.02, 0.01, 1.0)], None), None);
        assert_eq!(first_estimate(&[image(0.0, 0.0, 0.0)], r), None);
        assert_eq!(first_estimate(&[image(0.0, 0.0, 5.0)], r), None);
        assert_eq!(first_estimate(&[image(0.1, 0.0, 1.0)], r), None);
        assert!(first_estimate(&[image(0.099, 0.0, 1.0)], r).is_some());
        assert_eq!(first_estimate(&[image(f64::NAN, 0.0, 1.0)], r), None);
    }

    #[test]
    fn unshear_measures_again_about_the_images_sheared_back() {
        // Two datasets, g = ±(0.1, 0.1), one image each: the same 225
        // bright round galaxies on a grid (σ 4.5 – 6 px, far from every
        // cut) and the same noise (`pipeline`'s grid scene), through a round
        // PSF. The second measurement makes one version of each image,
        // sheared by −ĝ₀ of its dataset (ĝ₀ the first measurement's mean
        // row), and writes ĝ₀ + R⁻¹ e of its objects. At this diagonal
        // shear the first measurement of round Gaussians is near m = 0, so
        // both measurements must agree; a version sheared the wrong way
        // (2g) or rows taken to the wrong frame would not (the rows'
        // places are checked too). Measured: m = (+0.0003, −0.0029)
        // first, (+0.0010, −0.0021) after; c within 2e-4 both ways
        // ((−0.0000, −0.0050) and (+0.0008, −0.0041) through the 32² stack
        // metadetection had until 2026-12-07). The
        // same bytes at one and two threads, the first measurement's sums
        // unchanged, and every image measured again.
        let dir = tempfile::tempdir().unwrap();
        let g = 0.1;
        let psf = crate::scene::covariance(4.37 / 2.3548, [0.0, 0.0]);
        let scenes: Vec<(&str, &str, Image)> = [("dm", "dm0", -g), ("dp", "dp0", g)]
            .map(|(d, i, s)| {
                (
                    d,
                    i,
                    crate::pipeline::tests::grid_scene_with([s, s], &psf, (4.5, 6.0), 0.0),
                )
            })
            .into();
        let refs: Vec<(&str, &str, &Image)> =
            scenes.iter().map(|(d, i, img)| (*d, *i, img)).collect();
        write_public_run(dir.path(), &refs).unwrap();
        let plain = KsbParams {
            method: crate::params::Method::Metadetect,
            ..KsbParams::default()
        };
        let unshear = KsbParams {
            unshear: true,
            ..plain.clone()
        };
        let mean = |path: &Path| -> [[f64; 2]; 2] {
            let text = std::fs::read_to_string(path).unwrap();
            let mut acc = [[0.0; 3]; 2];
            for l in text.lines().filter(|l| !l.starts_with('#')) {
                let w: Vec<&str> = l.split(' ').collect();
                let d = usize::from(w[0].starts_with("dp"));
                let weight: f64 = w[5].parse().unwrap();
                acc[d][0] += weight * w[3].parse::<f64>().unwrap();
                acc[d][1] += weight * w[4].parse::<f64>().unwrap();
                acc[d][2] += weight;
            }
            assert!(acc[0][2] > 200.0 && acc[1][2] > 200.0, "{acc:?}");
            acc.map(|a| [a[0] / a[2], a[1] / a[2]])
        };
        let m_c = |[minus, plus]: [[f64; 2]; 2]| {
            [0, 1].map(|i| {
                (
                    (plus[i] - minus[i]) / (2.0 * g) - 1.0,
                    (plus[i] + minus[i]) / 2.0,
                )
            })
        };
        let (a, b, c) = (
            dir.path().join("plain.txt"),
            dir.path().join("unshear.txt"),
            dir.path().join("unshear2.txt"),
        );
        let sa = measure_run(dir.path(), &a, 2, &plain, &|_, _| {}).unwrap();
        let sb = measure_run(dir.path(), &b, 1, &unshear, &|_, _| {}).unwrap();
        measure_run(dir.path(), &c, 2, &unshear, &|_, _| {}).unwrap();
        assert!(std::fs::read(&b).unwrap() == std::fs::read(&c).unwrap());
        let (before, after) = (m_c(mean(&a)), m_c(mean(&b)));
        eprintln!("unshear: m, c before {before:?} after {after:?}");
        for i in 0..2 {
            assert!(before[i].0.abs() < 0.008, "m before {before:?}");
            assert!(after[i].0.abs() < 0.008, "m after {after:?}");
            assert!(
                (after[i].0 - before[i].0).abs() < 0.002,
                "{before:?} {after:?}"
            );
            assert!(before[i].1.abs() < 5e-4 && after[i].1.abs() < 5e-4);
        }
        // The second measurement's rows are placed in the image as given:
        // each weighted one within 0.2 px of a weighted row of the first.
        let places = |path: &Path| -> Vec<(String, f64, f64)> {
            std::fs::read_to_string(path)
                .unwrap()
                .lines()
                .filter(|l| !l.starts_with('#'))
                .map(|l| l.split(' ').collect::<Vec<_>>())
                .filter(|w| w[5] != "0.000000")
                .map(|w| {
                    (
                        w[0].to_string(),
                        w[1].parse().unwrap(),
                        w[2].parse().unwrap(),
                    )
                })
                .collect()
        };
        let (first_rows, second_rows) = (places(&a), places(&b));
        for (id, x, y) in &second_rows {
            assert!(
                first_rows
                    .iter()
                    .any(|(i, u, v)| i == id && (u - x).hypot(v - y) < 0.2),
                "{id} {x} {y}: no row of the first measurement there"
            );
        }
        // The first measurement's sums are the same with and without the
        // second; its version is sheared by −ĝ₀ of its dataset, which is
        // the mean row of the first measurement.
        let first = mean(&a);
        for (x, y) in sa.iter().zip(&sb) {
            assert_eq!(x.version_sums, y.version_sums);
            let (origin, sums) = y.unsheared.expect("measured again");
            let d = usize::from(y.dataset == "dp");
            for i in 0..2 {
                assert!(
                    (origin[i] + first[d][i]).abs() < 1e-5,
                    "{origin:?} {first:?}"
                );
            }
            assert!(sums[2] > 200.0, "{sums:?}");
        }
    }
}
