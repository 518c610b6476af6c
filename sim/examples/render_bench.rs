//! Renderer benchmark: a STEP1-like 4096² image of a typical faint
//! population, drawn with a round 0.9″ Gaussian PSF.
//!
//! ```sh
//! cargo run --release -p stepsim-sim --example render_bench [n_galaxies] [threads] [kvalue_threshold]
//! ```
//!
//! Prints the wall time of `draw_image` at the requested thread count, the
//! single-thread CPU time per object by stage (`Renderer::draw_timed`), and
//! the stamp sizes. The population is a deterministic stand-in (counts slope
//! 0.33 over 20 < I < 26, disk scale length ≈ 0.2″ at I = 24, growing 10^(−0.1 ΔI) to
//! brighter magnitudes, bulge r_e = 0.6 h, B/T from 0 to 1) so that the
//! benchmark does not depend on the population module.

use rand::{RngExt, SeedableRng};
use std::sync::Arc;
use std::time::Instant;
use stepsim_contract::seed::SimRng;
use stepsim_contract::truth::TruthRow;
use stepsim_sim::model::psf::GaussianPsf;
use stepsim_sim::model::render::{Accuracy, Renderer, StageTimes, draw_image};

fn population(n_gal: usize, n_star: usize, side: f64) -> Vec<TruthRow> {
    let mut rng = SimRng::seed_from_u64(4);
    let zp = 26.0 + 2.5 * 3600f64.log10();
    let mut rows = Vec::with_capacity(n_gal + n_star);
    for k in 0..n_gal + n_star {
        let x = rng.random_range(-20.0..side + 20.0);
        let y = rng.random_range(-20.0..side + 20.0);
        // dN/dm ∝ 10^(0.33 m) on [20, 26]: inverse CDF.
        let a = 0.33 * std::f64::consts::LN_10;
        let u: f64 = rng.random();
        let lo = (a * 20.0).exp();
        let hi = (a * 26.0).exp();
        let mag = (lo + u * (hi - lo)).ln() / a;
        let flux_e = 10f64.powf(0.4 * (zp - mag));
        let mut row = TruthRow {
            id: k as i64,
            x,
            y,
            mag,
            flux_e,
            ..TruthRow::default()
        };
        if k < n_gal {
            let h = 0.2 * 10f64.powf(-0.1 * (mag - 24.0)) * (0.5 + rng.random::<f64>());
            row.kind = 1;
            row.bt = rng.random::<f64>().powi(2);
            row.disk_h_arcsec = h;
            row.bulge_re_arcsec = 0.6 * h;
            row.disk_ba = rng.random_range(0.0f64..85.0).to_radians().cos();
            row.bulge_ba = rng.random_range(0.5..1.0);
            row.pa_deg = rng.random_range(0.0..180.0);
            row.g1 = 0.05;
        } else {
            row.kind = 0;
            row.hubble_type = -1;
            let u: f64 = rng.random();
            let a = 0.3 * std::f64::consts::LN_10;
            let (lo, hi) = ((a * 17.0).exp(), (a * 25.0).exp());
            row.mag = (lo + u * (hi - lo)).ln() / a;
            row.flux_e = 10f64.powf(0.4 * (zp - row.mag));
        }
        rows.push(row);
    }
    rows
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n_gal: usize = args.get(1).and_then(|v| v.parse().ok()).unwrap_or(20_000);
    let threads: usize = args.get(2).and_then(|v| v.parse().ok()).unwrap_or(2);
    let mut acc = Accuracy::default();
    if let Some(t) = args.get(3).and_then(|v| v.parse().ok()) {
        acc.kvalue_threshold = t;
    }
    let side = 4096u32;
    let p = 0.206;
    let rows = population(n_gal, 2000, f64::from(side));
    let sky_sigma = (1.89e6f64 * p * p + 25.0).sqrt();
    let psf = Arc::new(GaussianPsf::round(0.9));
    let renderer = Renderer::new(psf, p, acc, sky_sigma);
    // Warm the caches (PSF transfers, FFT plans, de Vaucouleurs table).
    for row in rows.iter().take(500) {
        let _ = renderer.draw(row);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let mut walls = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        let img = pool.install(|| draw_image(&renderer, &rows, side, side));
        walls.push(t.elapsed().as_secs_f64());
        std::hint::black_box(img);
    }
    walls.sort_by(f64::total_cmp);
    // Single-thread per-stage CPU time.
    let mut gal = StageTimes::default();
    let mut sta = StageTimes::default();
    let mut sides = Vec::new();
    let t = Instant::now();
    for row in &rows {
        let (s, times) = renderer.draw_timed(row).expect("valid row");
        sides.push(s.nx);
        if row.kind == 1 {
            gal += times;
        } else {
            sta += times;
        }
    }
    let serial = t.elapsed().as_secs_f64();
    sides.sort_unstable();
    let per = |t: StageTimes, n: usize| {
        let n = n as f64 * 1e3;
        format!(
            "setup {:.1} µs, k-space {:.1} µs, FFT {:.1} µs, total {:.1} µs",
            t.setup_ns as f64 / n,
            t.kspace_ns as f64 / n,
            t.fft_ns as f64 / n,
            (t.setup_ns + t.kspace_ns + t.fft_ns) as f64 / n
        )
    };
    println!(
        "objects: {} galaxies + 2000 stars on {side}², kvalue_threshold {:e}",
        n_gal, acc.kvalue_threshold
    );
    println!(
        "draw_image wall (median of 3, {threads} threads): {:.3} s  ({:.1} µs wall per object)",
        walls[1],
        walls[1] * 1e6 / rows.len() as f64
    );
    println!(
        "serial draw of every object: {:.3} s = {:.1} µs CPU per object",
        serial,
        serial * 1e6 / rows.len() as f64
    );
    println!("galaxies: {}", per(gal, n_gal));
    println!("stars:    {}", per(sta, 2000));
    let q = |f: f64| sides[((sides.len() - 1) as f64 * f) as usize];
    println!(
        "stamp side: median {}, 90% {}, 99% {}, max {}",
        q(0.5),
        q(0.9),
        q(0.99),
        sides[sides.len() - 1]
    );
}
