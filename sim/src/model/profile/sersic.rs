//! Sérsic constants for integer index n: b_n and the second moment.
//!
//! For a circular profile I(r) the second moment along one axis is
//! ⟨x²⟩ = ⟨r²⟩/2 with ⟨r²⟩ = ∫ r² I 2πr dr / ∫ I 2πr dr.
//! * Exponential I ∝ exp(−r/h) (n = 1): ⟨r²⟩ = Γ(4)/Γ(2) h² = 6 h²
//!   ([`super::Exponential::MEAN_R2`]); r½ = b₁ h
//!   ([`super::Exponential::HALF_LIGHT_RADIUS`]).
//! * Sérsic I ∝ exp(−b_n (r/r_e)^(1/n)): ⟨r²⟩ = Γ(4n)/(Γ(2n) b_n^(2n)) r_e²
//!   (substitute t = b_n (r/r_e)^(1/n); e.g. Graham & Driver 2005, PASA 22,
//!   118, eq. 2–4), where b_n solves γ(2n, b_n) = Γ(2n)/2. For n = 4
//!   (de Vaucouleurs), b₄ = 7.669249 ([`super::DeVaucouleurs::B`]) and
//!   ⟨r²⟩ = 21.6793 r_e² ([`devaucouleurs_r2_over_re2`]).
//!
//! A component stretched to axis ratio β along its major axis then has
//! major-axis second moment σ² = ⟨r²⟩/2 and minor-axis β²σ²
//! (see [`stepsim_contract::shear::Moments::of_ellipse`]). The truth tables' combined
//! ellipticities use these moments (`population`).

use stepsim_numerics::quad::simpson;
use stepsim_numerics::roots::Bisection;

/// Regularised lower incomplete gamma P(k, x) for integer k ≥ 1:
/// 1 − e^(−x) Σ_{j<k} x^j / j!.
pub fn gamma_p_integer(k: u32, x: f64) -> f64 {
    let mut term = 1.0;
    let mut sum = 1.0;
    for j in 1..k {
        term *= x / j as f64;
        sum += term;
    }
    1.0 - (-x).exp() * sum
}

/// b_n of a Sérsic profile with integer n: the root of P(2n, b) = 1/2,
/// found by bisection to machine precision.
pub fn sersic_b(n: u32) -> f64 {
    let (lo, hi) = Bisection::halvings(200).run(0.0, 4.0 * f64::from(n) + 10.0, |b| {
        gamma_p_integer(2 * n, b) >= 0.5
    });
    0.5 * (lo + hi)
}

/// ⟨r²⟩ / r_e² of an untruncated Sérsic profile with integer index n:
/// Γ(4n) / (Γ(2n) b_n^(2n)).
pub fn sersic_r2_over_re2(n: u32) -> f64 {
    let b = sersic_b(n);
    // Γ(4n)/Γ(2n) = (4n−1)!/(2n−1)! = Π_{j=2n}^{4n−1} j; divide by b^(2n)
    // one factor at a time to stay in range.
    (2 * n..4 * n).map(|j| f64::from(j) / b).product()
}

/// ⟨r²⟩ / r_e² of the de Vaucouleurs (n = 4) profile: solved once per
/// process (the truth tables need it for every galaxy of every dataset).
pub fn devaucouleurs_r2_over_re2() -> f64 {
    static R2: std::sync::LazyLock<f64> = std::sync::LazyLock::new(|| sersic_r2_over_re2(4));
    *R2
}

/// Slow reference for the profile moments: ⟨r²⟩ of a circular profile
/// `profile(r)` by direct Simpson integration of ∫ r³ I dr / ∫ r I dr on
/// [0, r_max] with `n` intervals.
pub fn r2_slow(profile: impl Fn(f64) -> f64, r_max: f64, n: usize) -> f64 {
    let num = simpson(|r| r * r * r * profile(r), 0.0, r_max, n);
    num / simpson(|r| r * profile(r), 0.0, r_max, n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::profile::{DeVaucouleurs, Exponential};

    #[test]
    fn sersic_constants() {
        // Exponential (n = 1): b₁ = 1.678347 = r_e / h.
        assert!((sersic_b(1) - Exponential::HALF_LIGHT_RADIUS).abs() < 1e-12);
        assert!(
            (sersic_r2_over_re2(1) * Exponential::HALF_LIGHT_RADIUS.powi(2) - 6.0).abs() < 1e-12
        );
        // de Vaucouleurs: b₄ = 7.669249 (Ciotti & Bertin 1999 asymptotic
        // 2n − 1/3 + 4/(405 n) + … = 7.66925).
        assert!((sersic_b(4) - 7.669_249).abs() < 1e-6, "{}", sersic_b(4));
        assert!((devaucouleurs_r2_over_re2() - 21.6793).abs() < 1e-3);
    }

    #[test]
    fn moments_match_direct_integration() {
        // Exponential with h = 1: integrate to 60 h.
        let slow = r2_slow(|r| (-r).exp(), 60.0, 60_000);
        assert!((slow - Exponential::MEAN_R2).abs() < 1e-8, "{slow}");
        // de Vaucouleurs with r_e = 1: the r^(1/4) law has wide wings;
        // integrate in t = r^(1/4) to 60 (r = 1.3e7 r_e) by substitution
        // r = t⁴, dr = 4t³ dt: ⟨r²⟩ = ∫ t^15 e^(−bt) dt / ∫ t^7 e^(−bt) dt.
        let b = sersic_b(4);
        let n = 200_000;
        let h = 60.0 / n as f64;
        let (mut num, mut den) = (0.0, 0.0);
        for i in 0..=n {
            let t = i as f64 * h;
            let w = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let f = (-b * t).exp();
            num += w * t.powi(15) * f;
            den += w * t.powi(7) * f;
        }
        let slow = num / den;
        let fast = devaucouleurs_r2_over_re2();
        assert!((slow / fast - 1.0).abs() < 1e-9, "{slow} vs {fast}");
    }

    #[test]
    fn the_de_vaucouleurs_constant_is_the_root() {
        assert!((sersic_b(4) - DeVaucouleurs::B).abs() < 1e-12);
        assert_eq!(DeVaucouleurs::b_slow(), sersic_b(4));
        // The value kept for the process is the one solved afresh.
        assert_eq!(
            devaucouleurs_r2_over_re2().to_bits(),
            sersic_r2_over_re2(4).to_bits()
        );
    }
}
