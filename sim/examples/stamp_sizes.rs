use std::path::Path;
use std::sync::Arc;
use stepsim_sim::config::{Plan, RawConfig};
use stepsim_sim::psf::{GaussianPsf, Psf};
use stepsim_sim::render::{Accuracy, Renderer};
fn main() {
    let raw = RawConfig::parse("{}", Path::new("t"), &[]).unwrap();
    let plan = Plan::new(raw, Path::new("t")).unwrap();
    let rows = stepsim_sim::population::sheared(
        &stepsim_sim::population::base_field(&plan, 0).unwrap(),
        0.1,
        0.0,
    );
    let p = 0.206;
    let det = stepsim_sim::noise::Detector::new(&plan.raw.instrument, p);
    let coma = stepsim_sim::psf::build(&plan.raw.psfs[1], &plan.raw.telescope, p).unwrap();
    for (name, psf) in [
        ("gauss", Arc::new(GaussianPsf::round(0.9)) as Arc<dyn Psf>),
        ("coma", coma),
    ] {
        println!(
            "{name}: r(0.995) = {:.2}″, r(0.9999) = {:.2}″",
            psf.radius_enclosing(0.995),
            psf.radius_enclosing(0.9999)
        );
        let r = Renderer::new(
            psf,
            p,
            Accuracy::from_config(&plan.raw.render),
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
    }
}
