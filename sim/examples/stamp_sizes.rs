//! Stamp sizes and per-stage costs of galaxy stamps on one STEP1 field:
//! whole-PSF stamps (method `stamp`) for a 0.9″ Gaussian and the coma PSF,
//! and the split method's stamps (object ⊗ L) for the coma PSF.
//!
//! ```sh
//! cargo run --release -p stepsim-sim --example stamp_sizes
//! ```
use std::path::Path;
use std::sync::Arc;
use stepsim_sim::Plan;
use stepsim_sim::model::psf::{GaussianPsf, Psf};
use stepsim_sim::model::render::{Accuracy, Method, Renderer, StageTimes};
fn main() {
    let plan = Plan::from_json("{}", Path::new("t"), &["run.seed=20060101"]).unwrap();
    let rows = stepsim_sim::model::population::sheared(
        &stepsim_sim::model::population::base_field(&plan.population(), 0).unwrap(),
        0.1,
        0.0,
    );
    let p = plan.pixel_scale_arcsec();
    let det = plan.detector();
    let coma = plan.psf(1).unwrap();
    let split_of_coma = Renderer::new(coma.clone(), p, plan.accuracy(), det.sky_sigma_e());
    let split = split_of_coma.split().expect("default method splits");
    println!(
        "split coma: σ_L {:.3}″, margin {} px, tile {} px",
        split.sigma_l_arcsec(),
        split.margin_px(),
        split.convolver(4096, 4096).tile()
    );
    for (name, psf) in [
        (
            "gauss (stamp)",
            Arc::new(GaussianPsf::round(0.9)) as Arc<dyn Psf>,
        ),
        ("coma (stamp)", coma),
        ("coma (split: L)", split.stamps().psf().clone()),
    ] {
        println!(
            "{name}: r(0.995) = {:.2}″, r(0.9999) = {:.2}″",
            psf.radius_enclosing(0.995),
            psf.radius_enclosing(0.9999)
        );
        let r = Renderer::new(
            psf,
            p,
            Accuracy {
                method: Method::Stamp,
                ..plan.accuracy()
            },
            det.sky_sigma_e(),
        );
        let mut sides: Vec<usize> = rows
            .iter()
            .filter(|r| !r.is_star())
            .map(|row| r.stamp_side(row).unwrap())
            .collect();
        sides.sort();
        let n = sides.len();
        let px2: f64 = sides.iter().map(|&s| (s * s) as f64).sum::<f64>() / n as f64;
        println!(
            "  galaxies {n}: side p10 {} p50 {} p90 {} p99 {} max {}; mean px² {:.0}",
            sides[n / 10],
            sides[n / 2],
            sides[9 * n / 10],
            sides[99 * n / 100],
            sides[n - 1],
            px2
        );
        // Serial cost per galaxy by stage (first 5 000 galaxies).
        let mut t = StageTimes::default();
        let mut k = 0;
        let clock = std::time::Instant::now();
        for row in rows.iter().filter(|r| !r.is_star()).take(5000) {
            t += r.draw_timed(row).unwrap().1;
            k += 1;
        }
        let wall = clock.elapsed().as_secs_f64();
        let per = |ns: u64| ns as f64 / 1e3 / k as f64;
        println!(
            "  µs per galaxy (1 thread): setup {:.1}, k-space {:.1}, FFT {:.1}; draw total {:.1}",
            per(t.setup_ns),
            per(t.kspace_ns),
            per(t.fft_ns),
            wall * 1e6 / k as f64
        );
    }
}
