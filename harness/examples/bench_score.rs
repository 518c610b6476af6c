//! Benchmark of `stepsim score` on a STEP1-sized synthetic run (not a test).
//!
//! ```sh
//! cargo run --release -p stepsim-harness --example bench_score [N_FIELDS] [SPACING_PX]
//! ```
//!
//! Defaults: 6 PSFs × 5 shears × 64 fields = 1920 images of 4096², objects
//! every 74 px (≈ 3000 per image, 10 % stars); the submission is a directory
//! of per-image whitespace tables holding every object. Builds the run in a
//! temporary directory, then scores it 3 times and prints the median time of
//! each stage: parse (datasets.json + submission), match (truth tables +
//! matching), metrics (fits + 200 bootstrap resamples), report (JSON,
//! Markdown, 8 plot files). Set `STEPSIM_BENCH_KEEP=1` to keep the run.

use std::time::Instant;
use stepsim_contract::truth::TruthRow;
use stepsim_harness::{ScoreOptions, build_report, match_images, prepare, write_outputs};
use stepsim_testkit::synthetic::{SynthSpec, make_run};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let n_fields: u32 = args.get(1).map_or(Ok(64), |s| s.parse())?;
    let spacing: f64 = args.get(2).map_or(Ok(74.0), |s| s.parse())?;
    let mut spec = SynthSpec::small(n_fields);
    spec.width_px = 4096;
    spec.height_px = 4096;
    spec.spacing_px = spacing;
    spec.shape_noise = true;
    let t0 = Instant::now();
    let run = make_run(&spec);
    let dir = tempfile::tempdir()?;
    let private = dir.path().join("private");
    run.write(&private)?;
    let sub = dir.path().join("submission");
    std::fs::create_dir(&sub)?;
    let rows = run.submission(&|t: &TruthRow, _| Some((t.e1 * 1.01, t.e2, 1.0)));
    let index = run.index();
    let mut n_rows = 0;
    for (info, rows) in index.images.iter().zip(&rows) {
        let mut s = String::from("# x y e1 e2 weight\n");
        for r in rows {
            s.push_str(&format!(
                "{:.4} {:.4} {:.6} {:.6} {}\n",
                r.x, r.y, r.e1, r.e2, r.weight
            ));
        }
        n_rows += rows.len();
        std::fs::write(sub.join(format!("{}.txt", info.image)), s)?;
    }
    println!(
        "built {} images, {} submitted rows, {} truth rows in {:.1} s (threads: {})",
        index.images.len(),
        n_rows,
        run.truth.iter().map(Vec::len).sum::<usize>(),
        t0.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    let mut times: Vec<[f64; 4]> = Vec::new();
    for rep in 0..3 {
        let opts = ScoreOptions::new(&private, &sub);
        let t = Instant::now();
        let p = prepare(&opts)?;
        let t_parse = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let stats = match_images(&p, opts.match_radius_arcsec)?;
        let t_match = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let report = build_report(&p, &stats, &opts);
        let t_metrics = t.elapsed().as_secs_f64();
        let t = Instant::now();
        write_outputs(&dir.path().join(format!("out{rep}")), &report, false)?;
        let t_report = t.elapsed().as_secs_f64();
        println!(
            "run {rep}: parse {t_parse:.2} s, match {t_match:.2} s, metrics {t_metrics:.2} s, \
             report {t_report:.2} s; <m> = {:?}",
            report.summary.m_mean
        );
        times.push([t_parse, t_match, t_metrics, t_report]);
    }
    let median = |k: usize| {
        let mut v: Vec<f64> = times.iter().map(|t| t[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (a, b, c, d) = (median(0), median(1), median(2), median(3));
    println!(
        "median of 3: parse {a:.2} s, match {b:.2} s, metrics {c:.2} s, report {d:.2} s, total {:.2} s",
        a + b + c + d
    );
    // Peak resident memory of the whole process (building the run included).
    if let Ok(status) = std::fs::read_to_string("/proc/self/status") {
        if let Some(l) = status.lines().find(|l| l.starts_with("VmHWM")) {
            println!("peak memory ({l})");
        }
    }
    if std::env::var_os("STEPSIM_BENCH_KEEP").is_some() {
        println!("kept {}", dir.keep().display());
    }
    Ok(())
}
