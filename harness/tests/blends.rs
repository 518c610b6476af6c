//! How much of the shear does a blended galaxy lose, noise-free? For every
//! galaxy of a run's base fields (I < 24), drawn through a 0.9″ Gaussian
//! PSF: adaptive moments in a 25-pixel window about its true position in
//! the whole image, against the same measurement of the galaxy drawn alone.
//! The response R = ∂χ1/∂g1 comes from g1 = ±0.05 and the 90° twins;
//! m_blend = ΣR_image / ΣR_alone − 1 per class (isolated or not: no object
//! with ≥ 10 % of the flux within 3″, `isolation.rs`), for unlensed and
//! lensed positions. It measures the scene, not any shear method. The
//! fields hold galaxies only (stars are not lensed, so with lensed
//! positions a star–galaxy overlap would change with the sign of g).
//! `STEPSIM_SLOW=1` runs 150 fields of 512² per case; `STEPSIM_BLEND_FIELDS`
//! sets the number (one count for both cases, or `UNLENSED,LENSED`; the
//! numbers in docs/scoring.md); otherwise 3 fields. The seed is fixed
//! (`run.seed`), so every run measures the same scene.

use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use stepsim_harness::{ISOLATION_FLUX_FRACTION, ISOLATION_RADIUS_ARCSEC, isolated};
use stepsim_sim::Plan;
use stepsim_sim::model::population::{base_field, lensed, rotated, sheared};
use stepsim_sim::model::render::{Accuracy, Renderer, Stamp, draw_image};

const W: usize = 512;
const HALF: i64 = 12;
const G: f64 = 0.05;

/// Master seed of the scene (fixed, so that runs reproduce and compare).
const SEED: u64 = 20061313;

fn plan(n_fields: u32) -> Plan {
    let o: Vec<String> = [
        format!("run.seed={SEED}"),
        format!("image.width_px={W}"),
        format!("image.height_px={W}"),
        format!("image.n_images={n_fields}"),
        "population.galaxies.mag_faint=24".into(),
        "population.lens_positions=true".into(),
        // No stars: they stay put while lensed galaxies move, which would
        // add star–galaxy overlaps that change with the sign of g.
        "population.stars.density_per_arcmin2=0".into(),
        "shears=[{\"g1\":-0.05},{\"g1\":0.05}]".into(),
        "psfs=[{\"name\":\"g\",\"model\":\"gaussian\",\"fwhm_arcsec\":0.9}]".into(),
    ]
    .into();
    let o: Vec<&str> = o.iter().map(String::as_str).collect();
    Plan::from_json("{}", Path::new("blends.json"), &o).unwrap()
}

/// χ1 of the adaptive moments in the window about (x, y) (FITS pixels) of
/// an image of side W whose pixel (i, j) (0-based column, row) is
/// `pixel(i, j)`; `None` off the image or without convergence.
fn chi1(x: f64, y: f64, pixel: impl Fn(usize, usize) -> f64) -> Option<f64> {
    let (ix, iy) = (x.round() as i64 - 1, y.round() as i64 - 1);
    if ix - HALF < 0 || iy - HALF < 0 || ix + HALF >= W as i64 || iy + HALF >= W as i64 {
        return None;
    }
    let n = (2 * HALF + 1) as usize;
    let mut win = Vec::with_capacity(n * n);
    for j in iy - HALF..=iy + HALF {
        for i in ix - HALF..=ix + HALF {
            win.push(pixel(i as usize, j as usize));
        }
    }
    // Started at the true position (window pixel HALF + 1 + sub-pixel).
    let start = (
        (HALF + 1) as f64 + x - x.round(),
        (HALF + 1) as f64 + y - y.round(),
    );
    let m = stepsim_sim::model::moments::adaptive_from(&win, n, n, start, 2.0).ok()?;
    Some(m.chi().0)
}

/// Pixel (i, j) of an image of side W holding only the stamp `s`.
fn stamp_pixel(s: &Stamp, i: usize, j: usize) -> f64 {
    let (u, v) = (i as i64 - s.x0, j as i64 - s.y0);
    if (0..s.nx as i64).contains(&u) && (0..s.ny as i64).contains(&v) {
        f64::from(s.data[v as usize * s.nx + u as usize])
    } else {
        0.0
    }
}

/// One field's sums per class [isolated, blended]: (ΣR_image, ΣR_alone,
/// galaxies, Σ(R_image − R_alone)²).
type Sums = [(f64, f64, usize, f64); 2];

fn measure(plan: &Plan, renderer: &Renderer, field: u32, lens: bool) -> Sums {
    let population = plan.population();
    let base = base_field(&population, field).unwrap();
    let r_px = ISOLATION_RADIUS_ARCSEC / plan.geometry().pixel_scale_arcsec;
    let iso = isolated(&base, r_px, ISOLATION_FLUX_FRACTION);
    let twin = rotated(&base);
    // Per galaxy id: (view, χ1 in the image, χ1 alone); view = 2·twin + (g > 0).
    let mut per: std::collections::BTreeMap<i64, Vec<(usize, f64, f64)>> = Default::default();
    for (k, rows) in [&base, &twin].into_iter().enumerate() {
        for (up, sign) in [(0, -1.0), (1, 1.0)] {
            let mut view = sheared(rows, sign * G, 0.0);
            if lens {
                view = lensed(&population, field, &view, sign * G, 0.0);
            }
            let img: Vec<f64> = draw_image(renderer, &view, W as u32, W as u32)
                .into_iter()
                .map(f64::from)
                .collect();
            for r in view.iter().filter(|r| !r.is_star() && r.mag < 24.0) {
                let Some(c) = chi1(r.x, r.y, |i, j| img[j * W + i]) else {
                    continue;
                };
                let s = renderer.draw(r);
                let Some(a) = chi1(r.x, r.y, |i, j| stamp_pixel(&s, i, j)) else {
                    continue;
                };
                per.entry(r.id).or_default().push((2 * k + up, c, a));
            }
        }
    }
    let mut sums: Sums = [(0.0, 0.0, 0, 0.0); 2];
    for (id, v) in per {
        if v.len() != 4 {
            continue;
        }
        let get = |view: usize| v.iter().find(|p| p.0 == view).map(|p| (p.1, p.2)).unwrap();
        let idx = base.iter().position(|b| b.id == id).unwrap();
        let class = usize::from(!iso[idx]);
        let img = ((get(1).0 - get(0).0) + (get(3).0 - get(2).0)) / (4.0 * G);
        let alone = ((get(1).1 - get(0).1) + (get(3).1 - get(2).1)) / (4.0 * G);
        let a = &mut sums[class];
        a.0 += img;
        a.1 += alone;
        a.2 += 1;
        a.3 += (img - alone).powi(2);
    }
    sums
}

/// The sums of one case over the fields so far: per class the totals and
/// each field's (ΣR_image, ΣR_alone), for the error over fields.
#[derive(Default)]
struct Acc {
    total: [(f64, f64, usize, f64); 2],
    per_field: [Vec<(f64, f64)>; 2],
}

impl Acc {
    fn add(&mut self, s: &Sums) {
        for ((t, field), sc) in self.total.iter_mut().zip(&mut self.per_field).zip(s) {
            t.0 += sc.0;
            t.1 += sc.1;
            t.2 += sc.2;
            t.3 += sc.3;
            field.push((sc.0, sc.1));
        }
    }
}

/// Error of the ratio r = ΣA_f / ΣB_f over independent fields f (the
/// delta method for a ratio of cluster sums): with z_f = A_f − r B_f,
/// σ_r² = F/(F − 1) Σ z_f² / (ΣB_f)². Galaxies of one field (the members
/// of a blend above all) are not independent; fields are.
fn ratio_error_over_fields(per_field: &[(f64, f64)]) -> f64 {
    let f = per_field.len() as f64;
    let (sa, sb) = per_field
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
    let r = sa / sb;
    let z2: f64 = per_field.iter().map(|p| (p.0 - r * p.1).powi(2)).sum();
    (f / (f - 1.0) * z2).sqrt() / sb.abs()
}

/// [isolated, blended] (m_blend, error, galaxies) for unlensed and lensed
/// positions over `n_fields[0]` fields (unlensed) and `n_fields[1]`
/// fields (lensed), the same first fields of one scene. The error is the
/// larger of the two estimates `summary` prints.
fn run(n_fields: [u32; 2]) -> [[(f64, f64, usize); 2]; 2] {
    let plan = plan(n_fields[0].max(n_fields[1]));
    let psf = Arc::new(stepsim_sim::model::psf::GaussianPsf::round(0.9));
    let renderer = Renderer::new(
        psf,
        plan.geometry().pixel_scale_arcsec,
        Accuracy::default(),
        283.0,
    );
    let mut out = [[(0.0, 0.0, 0); 2]; 2];
    let mut acc: [Acc; 2] = Default::default();
    // Blocks of 25 fields, measured in parallel and added in field order
    // (the same sums at any thread count), so that a long run reports
    // both cases as it goes.
    let n = n_fields[0].max(n_fields[1]);
    for start in (0..n).step_by(25) {
        let block: Vec<(u32, usize)> = (start..(start + 25).min(n))
            .flat_map(|f| (0..2).map(move |l| (f, l)))
            .filter(|&(f, l)| f < n_fields[l])
            .collect();
        let sums: Vec<Sums> = block
            .par_iter()
            .map(|&(f, l)| measure(&plan, &renderer, f, l == 1))
            .collect();
        for (&(f, l), s) in block.iter().zip(&sums) {
            acc[l].add(s);
            if (f + 1) % 25 == 0 || f + 1 == n_fields[l] {
                out[l] = summary(&acc[l], l == 1, f + 1);
            }
        }
    }
    out
}

/// [isolated, blended] (m_blend, error, galaxies) of the sums `acc` over
/// `n_fields` fields, also printed with both errors: from the scatter over
/// galaxies (taken as independent) and over fields.
fn summary(acc: &Acc, lens: bool, n_fields: u32) -> [(f64, f64, usize); 2] {
    let mut out = [(0.0, 0.0, 0); 2];
    for (c, a) in acc.total.iter().enumerate() {
        let n = a.2 as f64;
        let m = a.0 / a.1 - 1.0;
        // Error from the scatter of R_image − R_alone over galaxies.
        let mean_d = (a.0 - a.1) / n;
        let var = (a.3 / n - mean_d * mean_d).max(0.0) * n / (n - 1.0);
        let err_gal = (var / n).sqrt() / (a.1 / n);
        let err_field = ratio_error_over_fields(&acc.per_field[c]);
        let err = err_gal.max(err_field);
        out[c] = (m, err, a.2);
        eprintln!(
            "{} positions, {} galaxies: m_blend = {m:+.4} ± {err_field:.4} over fields \
             (± {err_gal:.4} over galaxies; {} galaxies, {n_fields} fields)",
            if lens { "lensed" } else { "unlensed" },
            if c == 0 { "isolated" } else { "blended" },
            a.2
        );
    }
    out
}

/// Field counts [unlensed, lensed] from `STEPSIM_BLEND_FIELDS` ("N" for
/// both or "U,L"), else 150 each with `slow`, else 3 each.
fn field_counts(var: Option<&str>, slow: bool) -> Result<[u32; 2], String> {
    let Some(v) = var else {
        return Ok(if slow { [150, 150] } else { [3, 3] });
    };
    let bad = || format!("STEPSIM_BLEND_FIELDS={v:?}: expected N or UNLENSED,LENSED (counts ≥ 1)");
    let n: Vec<u32> = v
        .split(',')
        .map(|p| p.trim().parse::<u32>().ok().filter(|&n| n > 0))
        .collect::<Option<_>>()
        .ok_or_else(bad)?;
    match n[..] {
        [a] => Ok([a, a]),
        [a, b] => Ok([a, b]),
        _ => Err(bad()),
    }
}

#[test]
fn field_counts_come_from_the_environment() {
    assert_eq!(field_counts(None, false), Ok([3, 3]));
    assert_eq!(field_counts(None, true), Ok([150, 150]));
    assert_eq!(field_counts(Some("40"), false), Ok([40, 40]));
    assert_eq!(field_counts(Some("500, 2000"), false), Ok([500, 2000]));
    for bad in ["", "0", "x", "1,2,3", "-4"] {
        assert!(field_counts(Some(bad), false).is_err(), "{bad}");
    }
}

#[test]
fn the_ratio_error_is_the_scatter_over_fields() {
    // A_f = 2 B_f on every field: the ratio is known exactly.
    assert_eq!(
        ratio_error_over_fields(&[(2.0, 1.0), (6.0, 3.0), (4.0, 2.0)]),
        0.0
    );
    // r = 6/6 = 1, z = (1, −1, 0), σ² = 3/2 · 2 / 6² → σ = √3 / 6.
    let e = ratio_error_over_fields(&[(3.0, 2.0), (1.0, 2.0), (2.0, 2.0)]);
    assert!((e - 3f64.sqrt() / 6.0).abs() < 1e-15, "{e}");
}

#[test]
fn the_scene_is_fixed_by_its_seed() {
    let (a, b) = (plan(3), plan(3));
    assert_eq!(a.seed(), SEED);
    let (fa, fb) = (
        base_field(&a.population(), 2).unwrap(),
        base_field(&b.population(), 2).unwrap(),
    );
    assert!(!fa.is_empty());
    assert_eq!(fa, fb);
}

#[test]
fn blends_respond_less_than_isolated_galaxies() {
    let slow = std::env::var_os("STEPSIM_SLOW").is_some();
    let var = std::env::var("STEPSIM_BLEND_FIELDS").ok();
    let counts = field_counts(var.as_deref(), slow).unwrap();
    let slow = slow || counts[0] >= 100;
    let r = run(counts);
    // Isolated galaxies lose (almost) nothing, lensed or not.
    for per_lens in &r {
        let (m, e, n) = per_lens[0];
        assert!(n > 50, "{n}");
        assert!(m.abs() < 0.01 + 3.0 * e, "isolated m_blend {m} ± {e}");
    }
    if slow {
        // Unlensed blends lose shear. (With lensed positions this
        // measurement is too noisy to say more: see docs/scoring.md.)
        let (mb, eb, _) = r[0][1];
        assert!(mb < -3.0 * eb, "unlensed blended {mb} ± {eb}");
    }
}
