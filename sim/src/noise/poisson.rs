//! Exact Poisson variates for pixel means, fast near one level (the sky).
//!
//! Three exact methods, each where it is fastest (`docs/noise.md`):
//!
//! - λ < [`INVERSION_MAX`]: inversion by sequential search, one uniform and
//!   about λ + 1 multiply-adds ([`poisson_inversion`]);
//! - λ ≥ [`INVERSION_MAX`]: Hörmann's transformed rejection with squeeze
//!   (PTRS, W. Hörmann 1993, *Insurance: Mathematics and Economics* 12, 39),
//!   two uniforms per try, about 1.1 tries, log-factorials only outside the
//!   squeeze ([`poisson_ptrs`]);
//! - a pixel whose mean λ is at least the base level λ₀ of a
//!   [`PoissonSampler`] (just under the sky) is drawn as Poisson(λ₀) +
//!   Poisson(λ − λ₀): the sum of independent Poisson variates is Poisson with
//!   the summed mean, so this is exact. Poisson(λ₀) comes from an alias
//!   table built once (one 64-bit uniform per draw), the small remainder by
//!   inversion. A pixel below λ₀ (ringing of a Fourier renderer) is drawn
//!   directly.
//!
//! No method is a normal approximation. The alias table holds the pmf from
//! its mode outwards by the ratio recurrence, normalised; its tails beyond
//! 10⁻²⁵ of the mode's probability (about ±10.7σ) are left out, a mass far
//! below the 2⁻⁵³ resolution of the uniforms. `rand_distr::Poisson` is the
//! slow, independent twin the tests compare with.

use crate::seed::SimRng;
use rand::{Rng, RngExt};

/// Below this mean, [`poisson_exact`] uses inversion; from it, PTRS.
pub const INVERSION_MAX: f64 = 10.0;

/// Means are clipped here (2⁵⁰ e⁻, far above any saturation level) so that
/// counts stay exact integers in an f64.
pub const MAX_LAMBDA: f64 = 1_125_899_906_842_624.0;

/// How far below the level the base λ₀ of a [`PoissonSampler`] sits, in
/// electrons: an empty pixel's remainder Poisson(λ − λ₀) has mean about this,
/// and slightly negative model values (Fourier ringing) still use the table.
pub const BASE_MARGIN_E: f64 = 1.0;

/// Smallest level for which a [`PoissonSampler`] builds its table.
pub const TABLE_MIN_LEVEL: f64 = 30.0;

/// An exact Poisson variate of mean `lambda` (≤ 0: 0; clipped at
/// [`MAX_LAMBDA`]): inversion below [`INVERSION_MAX`], PTRS from it.
pub fn poisson_exact(lambda: f64, rng: &mut SimRng) -> f64 {
    if lambda.is_nan() || lambda <= 0.0 {
        0.0
    } else if lambda < INVERSION_MAX {
        poisson_inversion(lambda, (-lambda).exp(), rng)
    } else {
        poisson_ptrs(lambda.min(MAX_LAMBDA), rng)
    }
}

/// Inversion by sequential search for 0 < λ < [`INVERSION_MAX`], given
/// `exp_neg = e^−λ`: the smallest k with U < P(X ≤ k).
pub fn poisson_inversion(lambda: f64, exp_neg: f64, rng: &mut SimRng) -> f64 {
    let u: f64 = rng.random();
    let (mut k, mut p) = (0u32, exp_neg);
    let mut cdf = p;
    // The cap is reached only if rounding leaves the summed cdf below u
    // (probability far under 2⁻⁵³ for λ < 10).
    while u >= cdf && k < 400 {
        k += 1;
        p *= lambda / f64::from(k);
        cdf += p;
    }
    f64::from(k)
}

/// Hörmann's PTRS for λ ≥ [`INVERSION_MAX`]: a candidate k from a
/// transformed uniform, accepted at once inside the squeeze, else by the
/// exact ratio of the pmf to the hat (log-factorial from `libm::lgamma`).
pub fn poisson_ptrs(lambda: f64, rng: &mut SimRng) -> f64 {
    let slam = lambda.sqrt();
    let ln_lam = lambda.ln();
    let b = 0.931 + 2.53 * slam;
    let a = -0.059 + 0.02483 * b;
    let inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
    let v_r = 0.9277 - 3.6224 / (b - 2.0);
    loop {
        let u = rng.random::<f64>() - 0.5;
        let v: f64 = rng.random();
        let us = 0.5 - u.abs();
        let k = ((2.0 * a / us + b) * u + lambda + 0.43).floor();
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if k < 0.0 || (us < 0.013 && v > us) {
            continue;
        }
        let lhs = v.ln() + inv_alpha.ln() - (a / (us * us) + b).ln();
        let rhs = -lambda + k * ln_lam - libm::lgamma(k + 1.0);
        if lhs <= rhs {
            return k;
        }
    }
}

/// Walker's alias table of a finite distribution on `lo, lo + 1, …`.
#[derive(Debug, Clone)]
struct AliasTable {
    lo: f64,
    /// Probability of keeping the column's own value.
    keep: Vec<f64>,
    /// The other value of each column (index).
    alias: Vec<u32>,
}

impl AliasTable {
    /// Vose's construction from probabilities summing to 1.
    fn new(lo: f64, p: &[f64]) -> Self {
        let n = p.len();
        let mut scaled: Vec<f64> = p.iter().map(|&q| q * n as f64).collect();
        let mut keep = vec![1.0; n];
        let mut alias: Vec<u32> = (0..n as u32).collect();
        let (mut small, mut large): (Vec<usize>, Vec<usize>) =
            (0..n).partition(|&i| scaled[i] < 1.0);
        while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
            keep[s] = scaled[s];
            alias[s] = l as u32;
            scaled[l] -= 1.0 - scaled[s];
            if scaled[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // What is left has probability 1 up to rounding.
        Self { lo, keep, alias }
    }

    /// One draw from one 64-bit uniform: u·n = column · 2⁶⁴ + fraction.
    fn sample(&self, rng: &mut SimRng) -> f64 {
        let n = self.keep.len() as u128;
        let prod = u128::from(rng.next_u64()) * n;
        let column = (prod >> 64) as usize;
        let frac = ((prod as u64) >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        let i = if frac < self.keep[column] {
            column
        } else {
            self.alias[column] as usize
        };
        self.lo + i as f64
    }
}

/// The Poisson pmf of mean `mu` on `lo..lo + len` where it exceeds 10⁻²⁵
/// of the mode's, normalised: (lo, probabilities).
fn truncated_pmf(mu: f64) -> (f64, Vec<f64>) {
    const CUT: f64 = 1e-25;
    let mode = mu.floor();
    // Relative values by p(k+1)/p(k) = μ/(k+1), from the mode outwards.
    let mut up = vec![1.0];
    let mut k = mode;
    loop {
        let next = up.last().copied().unwrap_or(1.0) * mu / (k + 1.0);
        if next < CUT {
            break;
        }
        up.push(next);
        k += 1.0;
    }
    let mut down = Vec::new();
    let (mut k, mut p) = (mode, 1.0);
    while k > 0.0 {
        p *= k / mu;
        if p < CUT {
            break;
        }
        down.push(p);
        k -= 1.0;
    }
    let lo = mode - down.len() as f64;
    let mut pmf: Vec<f64> = down.into_iter().rev().chain(up).collect();
    let sum: f64 = pmf.iter().sum();
    for p in &mut pmf {
        *p /= sum;
    }
    (lo, pmf)
}

/// Exact Poisson variates for means near one `level` (the sky of an image).
/// Built once per run; sampling is read-only, so threads share it.
#[derive(Debug, Clone)]
pub struct PoissonSampler {
    /// λ₀: means at or above it are drawn as Poisson(λ₀) + Poisson(λ − λ₀).
    base: f64,
    /// Alias table of Poisson(λ₀) (none for a level below [`TABLE_MIN_LEVEL`]).
    table: Option<AliasTable>,
}

impl PoissonSampler {
    /// A sampler for pixel means near `level` electrons: base λ₀ = level −
    /// [`BASE_MARGIN_E`], with its alias table when `level` ≥
    /// [`TABLE_MIN_LEVEL`].
    pub fn new(level: f64) -> Self {
        if level.is_finite() && level >= TABLE_MIN_LEVEL {
            let base = level - BASE_MARGIN_E;
            let (lo, pmf) = truncated_pmf(base);
            Self {
                base,
                table: Some(AliasTable::new(lo, &pmf)),
            }
        } else {
            Self {
                base: f64::INFINITY,
                table: None,
            }
        }
    }

    /// λ₀, the mean drawn from the table (infinite without one).
    pub fn base(&self) -> f64 {
        self.base
    }

    /// Entries of the alias table (0 without one).
    pub fn table_len(&self) -> usize {
        self.table.as_ref().map_or(0, |t| t.keep.len())
    }

    /// An exact Poisson variate of mean `lambda` (≤ 0 or NaN: 0).
    pub fn sample(&self, lambda: f64, rng: &mut SimRng) -> f64 {
        match &self.table {
            Some(t) if lambda >= self.base => {
                let rest = lambda - self.base;
                t.sample(rng) + poisson_exact(rest, rng)
            }
            _ => poisson_exact(lambda, rng),
        }
    }

    /// As [`PoissonSampler::sample`], with `e^−(λ − λ₀)` of the last
    /// remainder cached in `last` (empty sky pixels repeat it).
    pub fn sample_cached(&self, lambda: f64, last: &mut (f64, f64), rng: &mut SimRng) -> f64 {
        match &self.table {
            Some(t) if lambda >= self.base => {
                let rest = lambda - self.base;
                let from_table = t.sample(rng);
                let extra = if rest <= 0.0 {
                    0.0
                } else if rest < INVERSION_MAX {
                    if last.0 != rest {
                        *last = (rest, (-rest).exp());
                    }
                    poisson_inversion(rest, last.1, rng)
                } else {
                    poisson_ptrs(rest.min(MAX_LAMBDA), rng)
                };
                from_table + extra
            }
            _ => poisson_exact(lambda, rng),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seed::{SeedKey, Stream};
    use rand_distr::{Distribution, Poisson};

    fn rng(i: u64) -> SimRng {
        SeedKey::image(11, 0, 0, Stream::Test).with_index(i).rng()
    }

    /// ln P(X = k) for Poisson(λ), from lgamma (independent of the code
    /// under test's recurrences).
    fn ln_pmf(lambda: f64, k: f64) -> f64 {
        -lambda + k * lambda.ln() - libm::lgamma(k + 1.0)
    }

    /// Pearson's χ² of integer samples against the exact Poisson pmf, bins
    /// merged so that each expects ≥ 20 (tails into the end bins); returns
    /// (χ², degrees of freedom).
    fn chi_square(samples: &[f64], lambda: f64) -> (f64, usize) {
        let n = samples.len() as f64;
        let lo = (lambda - 12.0 * lambda.sqrt() - 5.0).floor().max(0.0) as i64;
        let hi = (lambda + 12.0 * lambda.sqrt() + 30.0).ceil() as i64;
        let mut counts = vec![0f64; (hi - lo + 1) as usize];
        for &s in samples {
            assert!(s >= 0.0 && s.fract() == 0.0, "{s}");
            let i = (s as i64).clamp(lo, hi) - lo;
            counts[i as usize] += 1.0;
        }
        let mut probs: Vec<f64> = (lo..=hi).map(|k| ln_pmf(lambda, k as f64).exp()).collect();
        // End bins hold the tails.
        let below: f64 = (0..lo).map(|k| ln_pmf(lambda, k as f64).exp()).sum();
        probs[0] += below;
        let above = 1.0 - probs.iter().sum::<f64>();
        *probs.last_mut().unwrap() += above.max(0.0);
        // Merge adjacent bins until each expects ≥ 20.
        let (mut chi2, mut bins) = (0.0, 0usize);
        let (mut o, mut e) = (0.0, 0.0);
        for (c, p) in counts.iter().zip(&probs) {
            o += c;
            e += p * n;
            if e >= 20.0 {
                chi2 += (o - e) * (o - e) / e;
                bins += 1;
                (o, e) = (0.0, 0.0);
            }
        }
        if e > 0.0 {
            chi2 += (o - e) * (o - e) / e.max(1e-300);
            bins += 1;
        }
        (chi2, bins - 1)
    }

    /// Wilson–Hilferty: the χ² statistic as a standard normal deviate.
    fn chi2_z(chi2: f64, df: usize) -> f64 {
        let d = df as f64;
        ((chi2 / d).cbrt() - (1.0 - 2.0 / (9.0 * d))) / (2.0 / (9.0 * d)).sqrt()
    }

    fn mean_var(x: &[f64]) -> (f64, f64) {
        let n = x.len() as f64;
        let m = x.iter().sum::<f64>() / n;
        (
            m,
            x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0),
        )
    }

    fn check(name: &str, lambda: f64, samples: &[f64]) {
        let n = samples.len() as f64;
        let (chi2, df) = chi_square(samples, lambda);
        let z = chi2_z(chi2, df);
        let (m, v) = mean_var(samples);
        // Standard errors: mean sqrt(λ/n), variance ≈ λ sqrt(2/n) (+ the
        // fourth cumulant λ/n, negligible here).
        let zm = (m - lambda) / (lambda / n).sqrt();
        let zv = (v - lambda) / (lambda * (2.0 / n + 1.0 / (lambda * n)).sqrt());
        eprintln!(
            "{name} λ = {lambda}: χ² = {chi2:.1} on {df} df (z {z:+.2}), mean z {zm:+.2}, variance z {zv:+.2}"
        );
        assert!(z < 4.5, "{name} λ = {lambda}: χ² {chi2} on {df} df");
        assert!(
            zm.abs() < 4.5 && zv.abs() < 4.5,
            "{name} λ = {lambda}: mean {m}, var {v}"
        );
    }

    const N: usize = 400_000;

    #[test]
    fn every_method_matches_the_exact_pmf_at_small_and_large_means() {
        for (i, lambda) in [0.05, 0.7, 2.0, 9.99, 10.0, 33.3, 1000.0, 80_174.6]
            .into_iter()
            .enumerate()
        {
            let mut r = rng(i as u64);
            let s: Vec<f64> = (0..N).map(|_| poisson_exact(lambda, &mut r)).collect();
            check("poisson_exact", lambda, &s);
        }
    }

    #[test]
    fn the_sky_table_plus_remainder_matches_the_exact_pmf() {
        // Level 80 174.6 (STEP1 sky): means at the level, a little below it
        // (remainder < 1), far below (no table), above by a faint and a
        // bright object; and a small level (table of a few dozen entries).
        let sky = PoissonSampler::new(80_174.6);
        assert!(sky.table_len() > 5000 && sky.base() == 80_173.6);
        let faint = PoissonSampler::new(40.0);
        for (i, (sampler, lambda)) in [
            (&sky, 80_174.6),
            (&sky, 80_173.9),
            (&sky, 80_100.0),
            (&sky, 80_181.0),
            (&sky, 95_000.5),
            (&faint, 40.0),
            (&faint, 38.5),
            (&faint, 44.25),
        ]
        .into_iter()
        .enumerate()
        {
            let mut r = rng(100 + i as u64);
            let mut last = (f64::NAN, 0.0);
            let cached: Vec<f64> = (0..N)
                .map(|_| sampler.sample_cached(lambda, &mut last, &mut r))
                .collect();
            check("sample_cached", lambda, &cached);
            // The cached and uncached paths draw the same numbers.
            let mut r = rng(100 + i as u64);
            let plain: Vec<f64> = (0..1000).map(|_| sampler.sample(lambda, &mut r)).collect();
            assert_eq!(plain[..], cached[..1000]);
        }
    }

    #[test]
    fn agrees_with_the_independent_slow_twin() {
        // Two-sample χ² against rand_distr's Poisson (another exact method)
        // at the STEP1 sky: a wrong table or remainder shows here too.
        let lambda = 80_180.25;
        let sky = PoissonSampler::new(80_174.6);
        let twin = Poisson::new(lambda).unwrap();
        let (mut ra, mut rb) = (rng(200), rng(201));
        let a: Vec<f64> = (0..N).map(|_| sky.sample(lambda, &mut ra)).collect();
        let b: Vec<f64> = (0..N).map(|_| twin.sample(&mut rb)).collect();
        // Bins of width σ/4 over ±4σ, tails merged.
        let s = lambda.sqrt() / 4.0;
        let bin = |x: f64| (((x - lambda) / s).floor().clamp(-17.0, 16.0) + 17.0) as usize;
        let (mut ca, mut cb) = (vec![0f64; 34], vec![0f64; 34]);
        a.iter().for_each(|&x| ca[bin(x)] += 1.0);
        b.iter().for_each(|&x| cb[bin(x)] += 1.0);
        let chi2: f64 = ca
            .iter()
            .zip(&cb)
            .filter(|(x, y)| *x + *y > 0.0)
            .map(|(x, y)| (x - y) * (x - y) / (x + y))
            .sum();
        let z = chi2_z(chi2, 33);
        eprintln!("two-sample χ² = {chi2:.1} on 33 df (z {z:+.2})");
        assert!(z < 4.5, "{chi2}");
        let (ma, va) = mean_var(&a);
        let (mb, vb) = mean_var(&b);
        assert!((ma - mb).abs() < 4.5 * (2.0 * lambda / N as f64).sqrt());
        assert!((va / vb - 1.0).abs() < 4.5 * (4.0 / N as f64).sqrt());
    }

    #[test]
    fn the_table_holds_the_pmf_and_edge_means_give_zero() {
        let (lo, pmf) = truncated_pmf(80_173.6);
        assert!((pmf.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        // Against lgamma's pmf at the mode and ±5σ.
        for k in [80_173.0, 80_173.0 - 1416.0, 80_173.0 + 1416.0] {
            let got = pmf[(k - lo) as usize];
            let want = ln_pmf(80_173.6, k).exp();
            assert!((got / want - 1.0).abs() < 1e-8, "k {k}: {got} vs {want}");
        }
        // Every column of the alias table splits its 1/n between two values
        // so that the marginal equals the pmf.
        let t = AliasTable::new(lo, &pmf);
        let n = pmf.len() as f64;
        let mut marginal: Vec<f64> = t.keep.iter().map(|k| k / n).collect();
        for (i, &a) in t.alias.iter().enumerate() {
            marginal[a as usize] += (1.0 - t.keep[i]) / n;
        }
        for (m, p) in marginal.iter().zip(&pmf) {
            assert!((m - p).abs() < 1e-15, "{m} vs {p}");
        }
        let mut r = rng(300);
        assert_eq!(poisson_exact(0.0, &mut r), 0.0);
        assert_eq!(poisson_exact(-3.0, &mut r), 0.0);
        assert_eq!(poisson_exact(f64::NAN, &mut r), 0.0);
        let huge = poisson_exact(1e300, &mut r);
        assert!(huge.is_finite() && (huge / MAX_LAMBDA - 1.0).abs() < 1e-5);
        assert_eq!(PoissonSampler::new(5.0).table_len(), 0);
    }
}
