//! `stepsim measure`: the KSB+ reference shear pipeline on a public run.

use std::path::{Path, PathBuf};
use stepsim_contract::run_dir::PublicDir;
use stepsim_ksb::{CalibrationProfile, KsbParams, Method, PgammaMode, SizeCut};

/// How P^γ is applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Pgamma {
    /// Each galaxy's own ½Tr P^γ.
    PerObject,
    /// ½Tr P^γ fitted against size r_g per image.
    FitSize,
}

/// The shear method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// KSB+ (docs/ksb.md).
    Ksb,
    /// Metacalibration: each galaxy deconvolved, sheared by ±0.01,
    /// reconvolved and measured again; rows are R⁻¹ e with R the
    /// dataset's response, selection included (docs/metacal.md).
    Metacal,
    /// Metadetection: the whole image deconvolved, sheared by ±0.01,
    /// reconvolved, and detected and measured again; the response includes
    /// the detection's (docs/metacal.md, "Metadetection").
    Metadetect,
}

/// The calibration of KSB+'s P^γ on each image's PSF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CalibrationArg {
    /// Exponential model galaxies (round and elliptical) drawn through the
    /// image's PSF stars (docs/ksb.md, step 8).
    Exponential,
    /// Gaussian model galaxies.
    Gaussian,
    /// None: P^γ as KSB+ gives it.
    None,
}

/// The size KSB+'s smallest-galaxy cut (r_g > 1.25 r_g*) compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SizeCutArg {
    /// The windowed r_g, which follows the shear to first order in g·e,
    /// so the cut selects on the shear (docs/baseline.md).
    Windowed,
    /// The r_g of the round object of the same PSF-corrected area (the
    /// PSF's second moments, from the stars' r_g* and e*, taken out as a
    /// tensor), which a shear keeps.
    PsfCorrected,
}

/// Arguments of `stepsim measure`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The public half of a run (the directory holding manifest.json).
    #[arg(long, value_name = "DIR")]
    run: PathBuf,
    /// The submission to write (SPEC §6: `# image x y e1 e2 weight flags`).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Worker threads (0: one per core; at most 1024, and at most 4 per
    /// core are used). The output does not depend on it.
    #[arg(long, default_value_t = 0, value_parser = super::threads_arg)]
    threads: usize,
    /// Order of the PSF polynomial across the field (lowered automatically
    /// when there are too few stars).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(0..=4))]
    psf_order: u8,
    /// How P^γ is applied.
    #[arg(long, value_enum, default_value_t = Pgamma::PerObject)]
    pgamma: Pgamma,
    /// The shear method.
    #[arg(long, value_enum, default_value_t = MethodArg::Ksb)]
    method: MethodArg,
    /// KSB+'s P^γ calibrated on each image's own PSF with model galaxies
    /// of this profile (no effect on metacal).
    #[arg(long, value_enum, default_value_t = CalibrationArg::Exponential)]
    calibration: CalibrationArg,
    /// The size KSB+'s cut on small galaxies compares with 1.25 r_g* (no
    /// effect on metacal).
    #[arg(long, value_enum, default_value_t = SizeCutArg::Windowed)]
    size_cut: SizeCutArg,
    /// Footprints are the pixels of the filtered image above this many of
    /// its noise σ (SExtractor's DETECT_THRESH; 2). Raise it with the S/N
    /// of a deep run to keep its isophotes where a shallow run's are
    /// (docs/ksb.md, step 2).
    #[arg(long, value_name = "SIGMA", default_value_t = 2.0, value_parser = detect_sigma_arg)]
    detect_thresh: f64,
    /// A source's filtered peak must reach this many noise σ (5).
    #[arg(long, value_name = "SIGMA", default_value_t = 5.0, value_parser = detect_sigma_arg)]
    detect_peak_sn: f64,
    /// Also write a details table: the submission's rows in its order, each
    /// followed by r_g, ν, the magnitude, P^γ, the calibration's k, e_cor
    /// and σ_γ, then metacal's five versions' e and which pass the cuts
    /// (docs/ksb.md, "The details table"). Not with --shard.
    #[arg(long, value_name = "TABLE", conflicts_with_all = ["shard", "finish"])]
    details: Option<PathBuf>,
    /// With `--method metadetect`: also write each image's version sums,
    /// one line per image (its id, its dataset's, then for each of the five
    /// versions the number of objects it selects and the sums of their e₁
    /// and e₂), from which the response of any set of images follows
    /// (docs/metacal.md, "Metadetection"). Not with --shard.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["shard", "finish"])]
    version_sums: Option<PathBuf>,
    /// With `--method metadetect`: measure each dataset a second time on
    /// its images sheared back by its first estimate ĝ₀, as one version,
    /// and write ĝ₀ + R⁻¹ e of that version's objects. R is the derivative
    /// at the shear the images have, which biases ⟨e⟩/R by a term in |g|²;
    /// sheared back, the version's own shear is near zero, and a galaxy
    /// and its turned twin cancel whatever their shapes (on isolated
    /// galaxies at g = ±(0.08, 0.08): m +0.0000 ± 0.0002 against +0.0028 ±
    /// 0.0028). Assumes one shear per dataset (a challenge's datasets have
    /// one); 1.5 times the CPU (docs/metacal.md, "The response at a finite
    /// shear").
    #[arg(long)]
    unshear: bool,
    /// Measure only the datasets of share K of N (or `auto`: this Slurm
    /// array task's), writing FILE.shards/K-of-N.txt; `--finish` joins the
    /// parts into FILE.
    #[arg(long, value_name = "K/N|auto", value_parser = super::shard_arg, conflicts_with = "finish")]
    shard: Option<stepsim_sim::run::generate::Shard>,
    /// Join the parts FILE.shards/K-of-N.txt of every shard into FILE,
    /// byte-identical to an unsharded measure (refused when one is missing).
    #[arg(long)]
    finish: bool,
}

/// The largest detection threshold in noise σ accepted: far beyond any use
/// (the defaults are 2 and 5; the deep lensed run of docs/metacal.md, at
/// about 167 times STEP1's S/N, uses 150 and 375).
const MAX_DETECT_SIGMA: f64 = 1e6;

/// Parses `--detect-thresh` and `--detect-peak-sn`: a number of noise σ,
/// above 0 and at most [`MAX_DETECT_SIGMA`] (a usage error, exit 2, otherwise).
fn detect_sigma_arg(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(k) if k > 0.0 && k <= MAX_DETECT_SIGMA => Ok(k),
        Ok(k) => Err(format!("{k} is not in (0, {MAX_DETECT_SIGMA}] noise σ")),
        Err(e) => Err(format!("not a number of noise σ: {e}")),
    }
}

/// Measures every image of the run and writes the submission.
pub fn run(args: &Args) -> anyhow::Result<()> {
    crate::huge_pages::keep_large_blocks();
    super::fits_path("--run", &args.run)?;
    let params = KsbParams {
        psf_order: usize::from(args.psf_order),
        pgamma_mode: match args.pgamma {
            Pgamma::PerObject => PgammaMode::PerObject,
            Pgamma::FitSize => PgammaMode::FitSize,
        },
        method: match args.method {
            MethodArg::Ksb => Method::Ksb,
            MethodArg::Metacal => Method::Metacal,
            MethodArg::Metadetect => Method::Metadetect,
        },
        calibration: match args.calibration {
            CalibrationArg::Exponential => Some(CalibrationProfile::Exponential),
            CalibrationArg::Gaussian => Some(CalibrationProfile::Gaussian),
            CalibrationArg::None => None,
        },
        size_cut: match args.size_cut {
            SizeCutArg::Windowed => SizeCut::Windowed,
            SizeCutArg::PsfCorrected => SizeCut::PsfCorrected,
        },
        detect_thresh: args.detect_thresh,
        detect_peak_sn: args.detect_peak_sn,
        unshear: args.unshear,
        ..KsbParams::default()
    };
    if args.unshear && params.method != Method::Metadetect {
        anyhow::bail!(
            "--unshear needs --method metadetect: it is metadetection's second measurement"
        );
    }
    if args.detect_peak_sn < args.detect_thresh {
        anyhow::bail!(
            "--detect-peak-sn {} is below --detect-thresh {}: a peak must lie inside its \
             footprint",
            args.detect_peak_sn,
            args.detect_thresh
        );
    }
    let threads = super::threads(args.threads);
    if !args.finish {
        file_not_directory("--out", &args.out)?;
    }
    if let Some(details) = &args.details {
        file_not_directory("--details", details)?;
        let files = |p: &Path| [resolved(p), resolved(&stepsim_ksb::rows_path(p))];
        let (sub, table) = (files(&args.out), files(details));
        if sub.iter().any(|f| table.contains(f)) {
            anyhow::bail!(
                "--details {} shares a file with the submission --out {} (the two, and \
                 their rows files {} and {}, must all differ); give the table its own file",
                details.display(),
                args.out.display(),
                stepsim_ksb::rows_path(details).display(),
                stepsim_ksb::rows_path(&args.out).display()
            );
        }
    }
    if let Some(sums) = &args.version_sums {
        if params.method != Method::Metadetect {
            anyhow::bail!(
                "--version-sums {} needs --method metadetect: only metadetection measures \
                 sheared versions of the images",
                sums.display()
            );
        }
        file_not_directory("--version-sums", sums)?;
        let mut taken = vec![
            resolved(&args.out),
            resolved(&stepsim_ksb::rows_path(&args.out)),
        ];
        if let Some(details) = &args.details {
            taken.extend([
                resolved(details),
                resolved(&stepsim_ksb::rows_path(details)),
            ]);
        }
        if taken.contains(&resolved(sums)) {
            anyhow::bail!(
                "--version-sums {} is the submission, the details table or one of their rows \
                 files; give it its own file",
                sums.display()
            );
        }
    }
    if args.finish {
        let n = stepsim_ksb::parts_count(&args.out)?;
        let (parts, images) = stepsim_ksb::join_parts(&args.run, &args.out, n)?;
        eprintln!(
            "stepsim: joined {parts} measure shards ({images} images) into {}",
            args.out.display()
        );
        return Ok(());
    }
    // An unreadable manifest is reported by the pipeline itself.
    if let Ok(m) = stepsim_ksb::read_manifest(&PublicDir::new(&args.run).manifest()) {
        super::check_memory(
            "measure",
            stepsim_sim::run::memory::measure_estimate(
                m.instrument.width_px,
                m.instrument.height_px,
                m.images.len(),
                threads,
            ),
            "lower --threads",
        )?;
    }
    // A line after each group of images (64 or more), with the time left
    // from the rate so far: measuring the full preset takes about an hour.
    let start = std::time::Instant::now();
    let progress = |done: usize, total: usize| {
        eprintln!(
            "{}",
            super::progress::count_line("images measured", done, total, start.elapsed())
        );
    };
    let (summary, written) = match args.shard {
        Some(sh) if sh.n > 1 => (
            stepsim_ksb::measure_shard(
                &args.run, &args.out, sh.k, sh.n, threads, &params, &progress,
            )?,
            stepsim_ksb::part_path(&args.out, sh.k, sh.n),
        ),
        _ => (
            match &args.details {
                Some(details) => stepsim_ksb::measure_run_with_details(
                    &args.run, &args.out, details, threads, &params, &progress,
                )?,
                None => {
                    stepsim_ksb::measure_run(&args.run, &args.out, threads, &params, &progress)?
                }
            },
            args.out.clone(),
        ),
    };
    let (mut rows, mut weighted) = (0, 0);
    for s in &summary {
        rows += s.n_objects;
        weighted += s.n_weighted;
        let locus = s.rg_star_px.map_or("no stellar locus".to_string(), |r| {
            format!("r_g* {r:.3} px")
        });
        // Only KSB+ models the PSF across the field; metacal and
        // metadetection deconvolve each image by its stars' stack.
        let order = match (params.method, s.psf_order) {
            (Method::Ksb, Some(o)) => format!(", PSF order {o}"),
            (Method::Ksb, None) => ", no PSF model".to_string(),
            _ => String::new(),
        };
        let k = match (params.method, params.calibration, s.calibration_k) {
            (Method::Ksb, Some(_), Some([lo, hi])) => format!(", P^γ k {lo:.3}–{hi:.3}"),
            (Method::Ksb, Some(_), None) => ", P^γ not calibrated".to_string(),
            _ => String::new(),
        };
        eprintln!(
            "stepsim: {}: {} objects, {} weighted, {} stars, {locus}{order}{k}",
            s.image, s.n_objects, s.n_weighted, s.n_stars
        );
    }
    // Metadetection's response, one per dataset, and its error over the
    // dataset's images: R is shared by all of a dataset's fields, so the
    // per-field errors of m do not contain it.
    let mut datasets: std::collections::BTreeMap<&str, (usize, stepsim_ksb::DatasetResponse)> =
        std::collections::BTreeMap::new();
    for s in &summary {
        if let Some(r) = s.response {
            datasets.entry(&s.dataset).or_insert((0, r)).0 += 1;
        }
    }
    let matrix = |m: [[f64; 2]; 2]| {
        format!(
            "[[{:.4}, {:.4}], [{:.4}, {:.4}]]",
            m[0][0], m[0][1], m[1][0], m[1][1]
        )
    };
    for (d, (n, (r, err))) in &datasets {
        let images = if *n == 1 { "image" } else { "images" };
        match (r, err) {
            (Some(r), Some(e)) => eprintln!(
                "stepsim: dataset {d}: R = {} ± {} (jackknife over its {n} {images}; its rows use the diagonal)",
                matrix(*r),
                matrix(*e)
            ),
            (Some(r), None) => eprintln!(
                "stepsim: dataset {d}: R = {} (its {n} {images}; no jackknife error; its rows use the diagonal)",
                matrix(*r)
            ),
            (None, _) => eprintln!(
                "stepsim: dataset {d}: no response; its rows have weight 0 and flag NO_PSF"
            ),
        }
        if params.unshear {
            match summary
                .iter()
                .find(|s| s.dataset == *d)
                .and_then(|s| s.unsheared)
            {
                Some(([g1, g2], _)) if [g1, g2] != [0.0; 2] => eprintln!(
                    "stepsim: dataset {d}: measured again sheared back by ĝ₀ = ({:.5}, {:.5})",
                    -g1, -g2
                ),
                _ => eprintln!(
                    "stepsim: dataset {d}: not measured again (no first estimate below 0.2); \
                     its rows are the first measurement's"
                ),
            }
        }
    }
    eprintln!(
        "stepsim: wrote {} ({} images, {rows} objects, {weighted} with weight > 0)",
        written.display(),
        summary.len()
    );
    if let Some(details) = &args.details {
        eprintln!("stepsim: wrote the details table {}", details.display());
    }
    if let Some(path) = &args.version_sums {
        let text = version_sums_text(&summary);
        stepsim_contract::io::write_bytes_atomically(path, text.as_bytes())?;
        eprintln!("stepsim: wrote the version sums {}", path.display());
    }
    Ok(())
}

/// The version sums of every measured image, in the submission's image
/// order: a header naming the columns, then `image dataset` and, for the
/// versions 0, 1p, 1m, 2p, 2m in turn, `n Σe₁ Σe₂` (n an integer, the
/// sums as Rust writes an f64: the shortest text that reads back to the
/// same bits). An image without sums (no PSF) writes no line.
fn version_sums_text(summary: &[stepsim_ksb::ImageSummary]) -> String {
    use std::fmt::Write;
    let mut text = String::from("# image dataset");
    for v in ["0", "1p", "1m", "2p", "2m"] {
        write!(text, " n_{v} sum_e1_{v} sum_e2_{v}").expect("writing to a String");
    }
    let unshear = summary.iter().any(|s| s.unsheared.is_some());
    if unshear {
        text.push_str(" shear1_u shear2_u n_u sum_e1_u sum_e2_u");
    }
    text.push('\n');
    for s in summary {
        let Some(sums) = &s.version_sums else {
            continue;
        };
        write!(text, "{} {}", s.image, s.dataset).expect("writing to a String");
        for [e1, e2, n] in sums {
            write!(text, " {n} {e1:?} {e2:?}").expect("writing to a String");
        }
        // With `--unshear` the run gives every image with sums its second
        // measurement's (a zero shear and the unsheared version's sums
        // where its dataset was not measured again).
        if let Some(([g1, g2], [e1, e2, n])) = s.unsheared {
            write!(text, " {g1:?} {g2:?} {n} {e1:?} {e2:?}").expect("writing to a String");
        }
        text.push('\n');
    }
    text
}

/// Refuses an output `path` (given as `option`) that is a directory or ends
/// in a separator: it is found out before anything is measured, not when
/// the file is renamed into place at the end.
fn file_not_directory(option: &str, path: &Path) -> anyhow::Result<()> {
    let ends_in_separator = path
        .as_os_str()
        .as_encoded_bytes()
        .last()
        .is_some_and(|&b| std::path::is_separator(b as char));
    if path.is_dir() || ends_in_separator {
        anyhow::bail!(
            "{option} {} is a directory; give a file name",
            path.display()
        );
    }
    Ok(())
}

/// `path` made absolute, its longest existing ancestor with symbolic links
/// and `..` resolved, the rest normalised by its names: two paths to one
/// file come out equal (`d/x/../sub.txt` and `d/sub.txt`, a linked
/// directory and its target), whether the file exists yet or not.
fn resolved(path: &Path) -> PathBuf {
    use std::path::Component;
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let parts: Vec<Component> = abs.components().collect();
    for cut in (0..=parts.len()).rev() {
        let head: PathBuf = parts[..cut].iter().collect();
        if let Ok(mut out) = head.canonicalize() {
            for part in &parts[cut..] {
                match part {
                    Component::ParentDir => {
                        out.pop();
                    }
                    Component::CurDir => {}
                    other => out.push(other),
                }
            }
            return out;
        }
    }
    abs
}
