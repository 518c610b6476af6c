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
//! The profiles' constants (r½/h of the exponential, ⟨r²⟩ of both laws,
//! the de Vaucouleurs b) live with the profiles: [`crate::model::profile::sersic`].

use crate::model::profile::Exponential;

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
    re_star_kpc / Exponential::HALF_LIGHT_RADIUS
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
