//! Linear least squares with κσ clipping: the one clipping rule of the
//! workspace (the KSB+ PSF polynomials across the field and the P^γ(r_g)
//! fit both use it).
//!
//! A model is Σₖ cₖ bₖ(point) with the first `m` basis functions of a
//! family whose lower orders come first (so fewer terms = a lower order).
//! **The rule.** Start with every point kept. Each pass:
//! 1. refuse (`None`) when fewer than `min_points` (at least 1) are kept;
//! 2. choose m = `terms_for(kept)` and fit every quantity to the kept points
//!    by its normal equations ([`crate::linalg::solve_spd`]; `None` when
//!    singular);
//! 3. per quantity, σ = max(MAD-σ of the kept points' residuals,
//!    1e-12 × (1 + max |value|)) ([`crate::robust::mad_sigma`] about zero;
//!    the floor stops an exact fit from clipping on rounding);
//! 4. drop every kept point whose residual exceeds κσ in *any* quantity.
//!    A dropped point stays dropped (no re-admission).
//!
//! Passes stop when a pass drops nothing, or after `max_passes`; the
//! coefficients are those of the last pass and the mask is the final one
//! (after `max_passes` it may have dropped points the last fit still used).

use crate::linalg::solve_spd;
use crate::robust::{mad_sigma, mad_sigma_slow};

/// The clipping parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clip {
    /// Residuals beyond `kappa` σ are clipped.
    pub kappa: f64,
    /// At most this many fits.
    pub max_passes: usize,
    /// Fewer kept points than this refuse the fit.
    pub min_points: usize,
}

/// A clipped fit of one or more quantities at the same points.
#[derive(Debug, Clone, PartialEq)]
pub struct ClippedFit {
    /// Coefficients per quantity (each of length [`Self::terms`]).
    pub coef: Vec<Vec<f64>>,
    /// Number of basis functions of the last fit.
    pub terms: usize,
    /// Which points are kept.
    pub keep: Vec<bool>,
}

/// Fits `values` (one slice per quantity, each with one value per point)
/// under the module's clipping rule. `basis(i, m, out)` writes the first
/// `m` basis functions at point `i` into `out` (cleared by the callee);
/// `terms_for(kept)` is the number of terms to fit with `kept` points.
pub fn fit_clipped(
    values: &[&[f64]],
    basis: impl Fn(usize, usize, &mut Vec<f64>),
    terms_for: impl Fn(usize) -> usize,
    clip: Clip,
) -> Option<ClippedFit> {
    let n = values.first().map_or(0, |v| v.len());
    let mut keep = vec![true; n];
    let mut coef: Vec<Vec<f64>> = Vec::new();
    let mut terms = 0;
    let mut b = Vec::new();
    for _ in 0..clip.max_passes {
        let kept = keep.iter().filter(|k| **k).count();
        if kept < clip.min_points.max(1) {
            return None;
        }
        terms = terms_for(kept);
        coef.clear();
        for vals in values {
            coef.push(least_squares(vals, &keep, terms, &basis)?);
        }
        let mut changed = false;
        let mut new_keep = keep.clone();
        for (c, vals) in coef.iter().zip(values) {
            let res: Vec<f64> = (0..n)
                .map(|i| {
                    basis(i, terms, &mut b);
                    vals[i] - b.iter().zip(c).map(|(a, c)| a * c).sum::<f64>()
                })
                .collect();
            let mad = mad_sigma(res.iter().zip(&keep).filter(|(_, k)| **k).map(|(r, _)| *r));
            let scale = vals.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let sigma = mad.unwrap_or(0.0).max(1e-12 * (1.0 + scale));
            for (i, r) in res.iter().enumerate() {
                if keep[i] && r.abs() > clip.kappa * sigma {
                    new_keep[i] = false;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
        keep = new_keep;
    }
    Some(ClippedFit { coef, terms, keep })
}

/// Unweighted least squares of the kept points by the normal equations.
fn least_squares(
    vals: &[f64],
    keep: &[bool],
    m: usize,
    basis: &impl Fn(usize, usize, &mut Vec<f64>),
) -> Option<Vec<f64>> {
    let mut ata = vec![0.0; m * m];
    let mut atb = vec![0.0; m];
    let mut b = Vec::with_capacity(m);
    for (p, (v, k)) in vals.iter().zip(keep).enumerate() {
        if !*k {
            continue;
        }
        basis(p, m, &mut b);
        for i in 0..m {
            atb[i] += b[i] * v;
            for j in 0..m {
                ata[i * m + j] += b[i] * b[j];
            }
        }
    }
    solve_spd(&ata, &atb)
}

/// Slow reference for [`fit_clipped`]: the same rule written plainly, one
/// quantity at a time for the σs, with the design matrix built in full,
/// Cramer's rule ([`crate::linalg::solve_spd_slow`]) and the counting
/// MAD-σ.
pub fn fit_clipped_slow(
    values: &[&[f64]],
    basis: impl Fn(usize, usize, &mut Vec<f64>),
    terms_for: impl Fn(usize) -> usize,
    clip: Clip,
) -> Option<ClippedFit> {
    let n = values.first().map_or(0, |v| v.len());
    let mut keep = vec![true; n];
    let mut last = None;
    for _ in 0..clip.max_passes {
        let kept: Vec<usize> = (0..n).filter(|&i| keep[i]).collect();
        if kept.len() < clip.min_points.max(1) {
            return None;
        }
        let m = terms_for(kept.len());
        let design: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                let mut row = Vec::new();
                basis(i, m, &mut row);
                row
            })
            .collect();
        let mut coef = Vec::new();
        for vals in values {
            let ata: Vec<f64> = (0..m * m)
                .map(|ij| {
                    kept.iter()
                        .map(|&p| design[p][ij / m] * design[p][ij % m])
                        .sum()
                })
                .collect();
            let atb: Vec<f64> = (0..m)
                .map(|j| kept.iter().map(|&p| design[p][j] * vals[p]).sum())
                .collect();
            coef.push(crate::linalg::solve_spd_slow(&ata, &atb)?);
        }
        let mut drop = vec![false; n];
        for (c, vals) in coef.iter().zip(values) {
            let res = |p: usize| vals[p] - (0..m).map(|j| design[p][j] * c[j]).sum::<f64>();
            let kept_res: Vec<f64> = kept.iter().map(|&p| res(p)).collect();
            let floor = 1e-12 * (1.0 + vals.iter().map(|v| v.abs()).fold(0.0, f64::max));
            let sigma = mad_sigma_slow(&kept_res).unwrap_or(0.0).max(floor);
            for &p in &kept {
                drop[p] |= res(p).abs() > clip.kappa * sigma;
            }
        }
        last = Some((coef, m));
        if !drop.iter().any(|d| *d) {
            break;
        }
        (0..n).for_each(|p| keep[p] &= !drop[p]);
    }
    let (coef, terms) = last?;
    Some(ClippedFit { coef, terms, keep })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng;
    use rand::RngExt;

    const CLIP: Clip = Clip {
        kappa: 3.0,
        max_passes: 10,
        min_points: 3,
    };

    /// Powers of x: 1, x, x², …
    fn powers(x: &[f64]) -> impl Fn(usize, usize, &mut Vec<f64>) + '_ {
        move |i, m, out| {
            out.clear();
            out.extend((0..m).map(|k| x[i].powi(k as i32)));
        }
    }

    #[test]
    fn clipped_fit_matches_its_plain_twin() {
        let mut rng = test_rng(2);
        for case in 0..40 {
            let n = rng.random_range(8..80);
            let x: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * 2.0 - 1.0).collect();
            let y: Vec<f64> = x
                .iter()
                .map(|&x| {
                    let outlier = if rng.random::<f64>() < 0.15 { 5.0 } else { 0.0 };
                    1.0 + 0.5 * x - 0.3 * x * x + 0.05 * (rng.random::<f64>() - 0.5) + outlier
                })
                .collect();
            let z: Vec<f64> = y.iter().map(|v| 2.0 - v).collect();
            let terms = |kept: usize| if kept >= 20 { 3 } else { 2 };
            let fast = fit_clipped(&[&y, &z], powers(&x), terms, CLIP);
            let slow = fit_clipped_slow(&[&y, &z], powers(&x), terms, CLIP);
            let (fast, slow) = (fast.unwrap(), slow.unwrap());
            assert_eq!(fast.keep, slow.keep, "case {case}");
            assert_eq!(fast.terms, slow.terms, "case {case}");
            for (f, s) in fast.coef.iter().flatten().zip(slow.coef.iter().flatten()) {
                assert!((f - s).abs() < 1e-9, "case {case}: {f} {s}");
            }
        }
    }

    #[test]
    fn the_rule_drops_outliers_for_good_and_refuses_too_few_points() {
        // A line with two gross outliers and ±0.01 alternating noise.
        let x: Vec<f64> = (0..30).map(f64::from).collect();
        let mut y: Vec<f64> = x
            .iter()
            .map(|x| 2.0 + 0.1 * x + if *x as i32 % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        y[4] += 3.0;
        y[17] -= 2.0;
        let f = fit_clipped(&[&y], powers(&x), |_| 2, CLIP).unwrap();
        let dropped: Vec<usize> = (0..30).filter(|&i| !f.keep[i]).collect();
        assert_eq!(dropped, [4, 17]);
        assert!((f.coef[0][0] - 2.0).abs() < 0.01 && (f.coef[0][1] - 0.1).abs() < 1e-3);
        // κ = 1 clips some of the good points too (the same ones as the twin).
        let tight = Clip { kappa: 1.0, ..CLIP };
        let f = fit_clipped(&[&y], powers(&x), |_| 2, tight).unwrap();
        let slow = fit_clipped_slow(&[&y], powers(&x), |_| 2, tight).unwrap();
        assert_eq!(f.keep, slow.keep);
        let kept = f.keep.iter().filter(|k| **k).count();
        assert_eq!(kept, 22);
        // Too few points, and a singular design, are refused.
        assert!(fit_clipped(&[&y[..2]], powers(&x), |_| 2, CLIP).is_none());
        let same = vec![1.0; 10];
        assert!(fit_clipped(&[&y[..10]], powers(&same), |_| 2, CLIP).is_none());
        // An exact fit clips nothing (the σ floor).
        let exact: Vec<f64> = x.iter().map(|x| 1.0 - x).collect();
        let f = fit_clipped(&[&exact], powers(&x), |_| 2, CLIP).unwrap();
        assert!(f.keep.iter().all(|k| *k));
    }
}
