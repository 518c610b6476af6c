//! Galaxy sizes: luminosity–size relations (Stuff-style) and the second
//! moments of the two light profiles.
//!
//! **Bulges** (Binggeli, Sandage & Tarenghi 1984, Fig. 7, as used by Stuff):
//! the mean effective radius follows a broken power law in luminosity around
//! a knee at M_knee: r_e = r_knee · 10^(−0.3 ΔM) for ΔM = M − M_knee < 0
//! (bright: r_e ∝ L^0.75) and r_e = r_knee · 10^(−0.1 ΔM) for ΔM ≥ 0
//! (faint: r_e ∝ L^0.25); no scatter.
//!
//! **Disks** (de Jong & Lacey 2000, as used by Stuff): log-normal scale
//! length around a power law, h = h* (L/L*)^(−β) exp(σ_λ N(0, 1)), with
//! h* = r_e*/1.67835 (an exponential's half-light radius is 1.67835 h).
//!
//! Both evolve with redshift as (1+z)^ε (Trujillo et al. 2006-style
//! `*_evol`), and M is taken with the luminosity evolution of M* removed,
//! so that the size–luminosity relation does not brighten with z.
//!
//! **Second moments.** For a circular profile I(r) the second moment along
//! one axis is ⟨x²⟩ = ⟨r²⟩/2 with ⟨r²⟩ = ∫ r² I 2πr dr / ∫ I 2πr dr.
//! * Exponential I ∝ exp(−r/h): ⟨r²⟩ = Γ(4)/Γ(2) h² = 6 h².
//! * Sérsic I ∝ exp(−b_n (r/r_e)^(1/n)): ⟨r²⟩ = Γ(4n)/(Γ(2n) b_n^(2n)) r_e²
//!   (substitute t = b_n (r/r_e)^(1/n); e.g. Graham & Driver 2005, PASA 22,
//!   118, eq. 2–4), where b_n solves γ(2n, b_n) = Γ(2n)/2. For n = 4
//!   (de Vaucouleurs), b₄ = 7.669249 and ⟨r²⟩ = 21.6793 r_e².
//!
//! A component stretched to axis ratio β along its major axis then has
//! major-axis second moment σ² = ⟨r²⟩/2 and minor-axis β²σ²
//! (see [`crate::shear::Moments::of_ellipse`]).

use stepsim_numerics::quad::simpson;
use stepsim_numerics::roots::Bisection;

/// Exponential-disk half-light radius in units of the scale length.
pub const EXP_HALF_LIGHT_OVER_H: f64 = 1.678_346_990_016_661;

/// ⟨r²⟩ / h² of an untruncated exponential profile.
pub const EXP_R2_OVER_H2: f64 = 6.0;

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

/// ⟨r²⟩ / r_e² of the de Vaucouleurs (n = 4) profile.
pub fn devaucouleurs_r2_over_re2() -> f64 {
    sersic_r2_over_re2(4)
}

/// Slow reference for the profile moments: ⟨r²⟩ of a circular profile
/// `profile(r)` by direct Simpson integration of ∫ r³ I dr / ∫ r I dr on
/// [0, r_max] with `n` intervals.
pub fn r2_by_integration(profile: impl Fn(f64) -> f64, r_max: f64, n: usize) -> f64 {
    let num = simpson(|r| r * r * r * profile(r), 0.0, r_max, n);
    num / simpson(|r| r * profile(r), 0.0, r_max, n)
}

/// Mean bulge effective radius (kpc) of a bulge of absolute magnitude
/// `m_abs` (with M* evolution removed; real, not h-scaled), from the
/// Binggeli et al. (1984) broken power law around (`m_knee`, `re_knee_kpc`).
pub fn bulge_re_kpc(m_abs: f64, m_knee: f64, re_knee_kpc: f64) -> f64 {
    let dm = m_abs - m_knee;
    let slope = if dm < 0.0 { 0.3 } else { 0.1 };
    re_knee_kpc * 10f64.powf(-slope * dm)
}

/// Disk scale length (kpc) for a disk `dm_star` = M_disk − M*(z)
/// magnitudes from L*: h* (L/L*)^(−β) e^(σ n) with `n` a standard normal
/// deviate, h* = `re_star_kpc` / 1.67835.
pub fn disk_h_kpc(dm_star: f64, re_star_kpc: f64, beta: f64, sigma_ln: f64, n: f64) -> f64 {
    // (L/L*)^(−β) = 10^(0.4 β (M − M*)).
    re_star_kpc / EXP_HALF_LIGHT_OVER_H
        * (0.4 * std::f64::consts::LN_10 * beta * dm_star + sigma_ln * n).exp()
}

/// Angular size in arcsec of a physical size in kpc at angular-diameter
/// distance `d_a_mpc`.
pub fn kpc_to_arcsec(size_kpc: f64, d_a_mpc: f64) -> f64 {
    size_kpc / (d_a_mpc * 1e3) * (180.0 / std::f64::consts::PI * 3600.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sersic_constants() {
        // Exponential (n = 1): b₁ = 1.678347 = r_e / h.
        assert!((sersic_b(1) - EXP_HALF_LIGHT_OVER_H).abs() < 1e-12);
        assert!((sersic_r2_over_re2(1) * EXP_HALF_LIGHT_OVER_H.powi(2) - 6.0).abs() < 1e-12);
        // de Vaucouleurs: b₄ = 7.669249 (Ciotti & Bertin 1999 asymptotic
        // 2n − 1/3 + 4/(405 n) + … = 7.66925).
        assert!((sersic_b(4) - 7.669_249).abs() < 1e-6, "{}", sersic_b(4));
        assert!((devaucouleurs_r2_over_re2() - 21.6793).abs() < 1e-3);
    }

    #[test]
    fn moments_match_direct_integration() {
        // Exponential with h = 1: integrate to 60 h.
        let slow = r2_by_integration(|r| (-r).exp(), 60.0, 60_000);
        assert!((slow - EXP_R2_OVER_H2).abs() < 1e-8, "{slow}");
        // de Vaucouleurs with r_e = 1: the r^(1/4) law has wide wings;
        // integrate in t = r^(1/4) to 60 (r = 1.3e7 r_e) by substitution
        // r = t⁴, dr = 4t³ dt: ⟨r²⟩ = ∫ t^15 e^(−bt) dt / ∫ t^7 e^(−bt) dt.
        let b = sersic_b(4);
        let n = 200_000;
        let num = simpson(|t| t.powi(15) * (-b * t).exp(), 0.0, 60.0, n);
        let slow = num / simpson(|t| t.powi(7) * (-b * t).exp(), 0.0, 60.0, n);
        let fast = devaucouleurs_r2_over_re2();
        assert!((slow / fast - 1.0).abs() < 1e-9, "{slow} vs {fast}");
    }

    #[test]
    fn size_relations() {
        // At the knee the radius is the knee radius; 1 mag brighter ×10^0.3,
        // 1 mag fainter ×10^−0.1.
        assert!((bulge_re_kpc(-20.0, -20.0, 2.0) - 2.0).abs() < 1e-12);
        assert!((bulge_re_kpc(-21.0, -20.0, 2.0) - 2.0 * 10f64.powf(0.3)).abs() < 1e-12);
        assert!((bulge_re_kpc(-19.0, -20.0, 2.0) - 2.0 * 10f64.powf(-0.1)).abs() < 1e-12);
        // Disk at L* without scatter: h* = r_e*/1.678.
        assert!((disk_h_kpc(0.0, 5.5, -0.214, 0.36, 0.0) - 5.5 / 1.678_347).abs() < 1e-5);
        // 2.5 mag brighter = 10 L*: ×10^0.214.
        let r = disk_h_kpc(-2.5, 1.0, -0.214, 0.0, 0.0) / disk_h_kpc(0.0, 1.0, -0.214, 0.0, 0.0);
        assert!((r - 10f64.powf(0.214)).abs() < 1e-12);
        // 1 kpc at 206.265 Mpc is 1″.
        assert!((kpc_to_arcsec(1.0, 206.264_806_247) - 1.0).abs() < 1e-9);
    }
}
