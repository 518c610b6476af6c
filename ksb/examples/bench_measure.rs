//! Benchmark of the KSB+ pipeline on one STEP-sized image.
//!
//! ```sh
//! cargo run --release -p stepsim-ksb --example bench_measure [-- REPEATS]
//! ```
//!
//! Synthesises a 4096² image (0.206″ pixels, 0.9″ Gaussian PSF with
//! e* = (0.04, 0.02), 10 000 Gaussian galaxies, 2000 stars, sky 80 000 e⁻,
//! noise), then measures it `REPEATS` times (default 3) and prints the
//! per-stage times of each run, the median total, and the peak memory.

use std::time::Instant;
use stepsim_ksb::{ImageInfo, KsbParams, measure_image};
use stepsim_testkit::scene::{SceneSpec, synthetic_scene};

fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// CPU seconds (user + system) used by this process so far, from
/// /proc/self/stat (clock ticks of 1/100 s).
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let after = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(3);
    let spec = SceneSpec {
        width: 4096,
        height: 4096,
        n_galaxy_pairs: 5000,
        n_stars: 2000,
        ..SceneSpec::step_like([0.05, 0.0], [0.04, 0.02], 2006)
    };
    let t = Instant::now();
    let (_objects, mut img) = synthetic_scene(&spec);
    let sat = 65535.0f32 * 4.0;
    for v in &mut img.data {
        *v = v.min(sat);
    }
    println!(
        "synthesis: {:.2} s (not part of the measurement)",
        t.elapsed().as_secs_f64()
    );
    let info = ImageInfo {
        zeropoint_eff_mag: 26.0 + 2.5 * 3600f64.log10(),
        saturation_e: Some(f64::from(sat) - 2.0),
    };
    println!("threads: {}", rayon::current_num_threads());
    let mut totals = Vec::new();
    for r in 0..repeats {
        let t = Instant::now();
        let cpu0 = cpu_seconds().unwrap_or(f64::NAN);
        let m = measure_image(&img, &info, &KsbParams::default()).expect("measure");
        let total = t.elapsed().as_secs_f64();
        let cpu = cpu_seconds().unwrap_or(f64::NAN) - cpu0;
        totals.push(total);
        let stages: Vec<String> = m
            .timings
            .iter()
            .map(|(n, s)| format!("{n} {s:.3}"))
            .collect();
        let weighted = m.objects.iter().filter(|o| o.weight > 0.0).count();
        let (mut s1, mut sw) = (0.0, 0.0);
        for o in &m.objects {
            s1 += o.weight * o.e1;
            sw += o.weight;
        }
        println!(
            "run {r}: wall {total:.3} s, cpu {cpu:.2} s | {} | detections {} rows {} weighted {weighted} stars {} order {:?} <g1> {:.4}",
            stages.join(", "),
            m.n_detections,
            m.objects.len(),
            m.n_stars,
            m.psf_order,
            s1 / sw
        );
    }
    totals.sort_by(f64::total_cmp);
    println!(
        "median total: {:.3} s over {repeats} runs",
        totals[totals.len() / 2]
    );
    if let Some(mib) = peak_rss_mib() {
        println!("peak resident memory: {mib:.0} MiB");
    }
}
