//! Writes a synthetic run of the full preset's shape and a catalogue of it,
//! for the benchmark of `stepsim score` on a full-size submission (issue
//! #23; BENCHMARKS.md "Scoring a full-size catalogue"). Not a test.
//!
//! ```sh
//! cargo run --release -p stepsim-harness --example full_catalogue -- OUT [N_FIELDS] [OBJECTS] [KEEP]
//! stepsim score --truth OUT/private --submission OUT/catalogue.txt --out OUT/report
//! # or, the same stages as `stepsim score` through the library (streamed,
//! # or `whole`: the whole-file twin, the reader before issue #23):
//! full_catalogue score OUT/private OUT/catalogue.txt REPORT_DIR [whole]
//! ```
//!
//! Defaults: 6 PSFs × 5 shears × 64 fields = 1920 images of 4096² at 0.2″;
//! `OBJECTS` = 10 000 truth objects per image (10 % stars) on a jittered
//! grid, written with only the columns the scoring reads
//! (`truth_set::SCORING_COLUMNS`); the catalogue `OUT/catalogue.txt` lists
//! `KEEP` = 96 % of them (18.4 M rows for the defaults), as `stepsim measure`
//! writes one (`# image x y e1 e2 weight flags`, 4 decimals for positions,
//! 6 for shears), each position off by up to 0.1 px and each shear with a
//! 1 % bias and noise. Deterministic: the same arguments write the same
//! bytes.

use fitsio::tables::{ColumnDataType, ColumnDescription};
use std::io::Write;
use std::path::Path;
use stepsim_contract::run_layout::{DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets, Part};

/// SplitMix64: a small deterministic generator.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `score TRUTH SUBMISSION OUT [whole]`: what `stepsim score` does (the
/// run's own limit, 200 bootstrap resamples, every output written).
fn score(args: &[String]) -> Result<(), Box<dyn std::error::Error>> {
    use stepsim_harness::{ScoreOptions, score, score_slow, write_outputs};
    let [truth, sub, out, rest @ ..] = args else {
        return Err("usage: full_catalogue score TRUTH SUBMISSION OUT [whole]".into());
    };
    let opts = ScoreOptions::new(truth, sub);
    let t = std::time::Instant::now();
    let report = if rest.first().map(String::as_str) == Some("whole") {
        score_slow(&opts)?
    } else {
        score(&opts)?
    };
    std::fs::create_dir_all(out)?;
    write_outputs(Path::new(out), &report, true)?;
    println!(
        "scored in {:.1} s: <m> = {:?}, sigma_c = {:?}",
        t.elapsed().as_secs_f64(),
        report.summary.m_mean,
        report.summary.sigma_c
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("score") {
        return score(&args[2..]);
    }
    let out = Path::new(
        args.get(1)
            .ok_or("usage: full_catalogue OUT [N_FIELDS] [OBJECTS] [KEEP]")?,
    );
    let n_fields: u32 = args.get(2).map_or(Ok(64), |s| s.parse())?;
    let n_objects: usize = args.get(3).map_or(Ok(10_000), |s| s.parse())?;
    let keep: f64 = args.get(4).map_or(Ok(0.96), |s| s.parse())?;
    let (size, scale) = (4096u32, 0.2);
    let psfs = ["none", "coma", "jitter", "defocus", "astig", "trefoil"];
    let shears = [
        (0.0, 0.0),
        (0.005, 0.0),
        (0.01, 0.0),
        (0.05, 0.0),
        (0.1, 0.0),
    ];
    let mut datasets = Vec::new();
    for (p, psf) in psfs.iter().enumerate() {
        for (s, &(g1, g2)) in shears.iter().enumerate() {
            let d = p * shears.len() + s;
            datasets.push(DatasetEntry {
                part: Part::default(),
                dataset: format!("d{:04x}", (d * 7919) % 65_536),
                psf_id: p as u32,
                psf: (*psf).to_owned(),
                g1,
                g2,
                images: (0..n_fields)
                    .map(|f| DatasetImage {
                        image: format!(
                            "im{:06x}",
                            (d as u64 * 1000 + u64::from(f)) * 104_729 % 0xff_ffff
                        ),
                        field: f,
                        rotated: false,
                    })
                    .collect(),
            });
        }
    }
    let ds = Datasets {
        format: DATASETS_FORMAT.into(),
        width_px: size,
        height_px: size,
        pixel_scale_arcsec: scale,
        datasets,
    };
    let private = out.join("private");
    std::fs::create_dir_all(private.join("truth"))?;
    std::fs::write(
        private.join("datasets.json"),
        serde_json::to_string_pretty(&ds)?,
    )?;
    std::fs::write(private.join("config.json"), "{}\n")?;
    let cat = std::fs::File::create(out.join("catalogue.txt"))?;
    let mut cat = std::io::BufWriter::with_capacity(1 << 20, cat);
    writeln!(cat, "# image x y e1 e2 weight flags")?;
    let side = (n_objects as f64).sqrt().ceil() as usize;
    let cell = f64::from(size) / side as f64;
    let (mut n_truth, mut n_rows) = (0usize, 0usize);
    for entry in &ds.datasets {
        for im in &entry.images {
            // The same base field for every dataset (as STEP1), sheared.
            let mut rng = Rng(u64::from(im.field) * 0x1234_5678 + 1);
            let mut cols: [Vec<f64>; 7] = Default::default();
            let mut kind = Vec::with_capacity(n_objects);
            let mut noise = Rng(u64::from(im.field) * 31 + u64::from(entry.psf_id) * 7 + 99);
            for k in 0..n_objects {
                let x = 1.0 + ((k % side) as f64 + 0.2 + 0.6 * rng.unit()) * cell;
                let y = 1.0 + ((k / side) as f64 + 0.2 + 0.6 * rng.unit()) * cell;
                let x = x.min(f64::from(size));
                let y = y.min(f64::from(size));
                let star = rng.unit() < 0.1;
                let mag = 20.0 + 5.0 * rng.unit();
                let h = if star { 0.0 } else { 0.2 + 1.2 * rng.unit() };
                let (e1i, e2i) = if star {
                    (0.0, 0.0)
                } else {
                    (0.3 * (rng.unit() - 0.5), 0.3 * (rng.unit() - 0.5))
                };
                let e1 = e1i + entry.g1;
                kind.push(i32::from(!star));
                for (c, v) in cols.iter_mut().zip([x, y, mag, h, e1, e1i, e2i]) {
                    c.push(v);
                }
                if noise.unit() < keep {
                    let dx = 0.2 * (noise.unit() - 0.5);
                    let dy = 0.2 * (noise.unit() - 0.5);
                    let m1 = 1.01 * e1 + 0.05 * (noise.unit() - 0.5);
                    let m2 = e2i + entry.g2 + 0.05 * (noise.unit() - 0.5);
                    writeln!(
                        cat,
                        "{} {:.4} {:.4} {:.6} {:.6} {:.4} 0",
                        im.image,
                        (x + dx).clamp(0.5, f64::from(size) + 0.5),
                        (y + dy).clamp(0.5, f64::from(size) + 0.5),
                        m1,
                        m2,
                        0.5 + noise.unit()
                    )?;
                    n_rows += 1;
                }
            }
            n_truth += n_objects;
            let path = private.join("truth").join(format!("{}.fits", im.image));
            let _ = std::fs::remove_file(&path);
            let mut f = fitsio::FitsFile::create(&path).open()?;
            let mut descs = vec![
                ColumnDescription::new("kind")
                    .with_type(ColumnDataType::Int)
                    .create()?,
            ];
            for name in &stepsim_harness::SCORING_COLUMNS[1..] {
                descs.push(
                    ColumnDescription::new(*name)
                        .with_type(ColumnDataType::Double)
                        .create()?,
                );
            }
            let hdu = f.create_table(stepsim_contract::io::truth::TRUTH_EXTNAME, &descs)?;
            hdu.write_col(&mut f, "kind", &kind)?;
            for (name, c) in stepsim_harness::SCORING_COLUMNS[1..].iter().zip(&cols) {
                hdu.write_col(&mut f, *name, c)?;
            }
        }
    }
    cat.flush()?;
    println!(
        "{} images, {n_truth} truth objects, {n_rows} catalogue rows in {}",
        ds.datasets.len() * n_fields as usize,
        out.display()
    );
    Ok(())
}
