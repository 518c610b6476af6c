//! ΛCDM distances and volumes (Hogg 1999, astro-ph/9905116).
//!
//! E(z) = sqrt(Ωm (1+z)³ + Ωk (1+z)² + ΩΛ), Ωk = 1 − Ωm − ΩΛ;
//! line-of-sight comoving distance D_C = D_H ∫₀^z dz'/E(z'), D_H = c/H0;
//! transverse comoving distance D_M (= D_C when flat; sinh/sin forms
//! otherwise); angular-diameter distance D_A = D_M/(1+z); luminosity distance
//! D_L = (1+z) D_M; distance modulus 5 log10(D_L / 10 pc); comoving volume
//! element dV/dz/dΩ = D_H D_M² / E(z). Distances in Mpc.

use super::Cosmology;
use stepsim_numerics::quad::simpson;

/// Speed of light, km/s.
pub const C_KM_S: f64 = 299_792.458;

/// A ΛCDM cosmology, ready for distance computations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lcdm {
    /// Hubble constant, km s⁻¹ Mpc⁻¹.
    pub h0: f64,
    /// Ωm.
    pub omega_m: f64,
    /// ΩΛ.
    pub omega_lambda: f64,
}

impl Lcdm {
    /// From the config section.
    pub fn new(c: &Cosmology) -> Self {
        Self {
            h0: c.h0,
            omega_m: c.omega_m,
            omega_lambda: c.omega_lambda,
        }
    }

    /// h = H0 / (100 km s⁻¹ Mpc⁻¹).
    pub fn h(&self) -> f64 {
        self.h0 / 100.0
    }

    /// Curvature density Ωk = 1 − Ωm − ΩΛ.
    pub fn omega_k(&self) -> f64 {
        1.0 - self.omega_m - self.omega_lambda
    }

    /// Hubble distance c/H0 in Mpc.
    pub fn hubble_distance_mpc(&self) -> f64 {
        C_KM_S / self.h0
    }

    /// E(z) = H(z)/H0.
    pub fn e(&self, z: f64) -> f64 {
        let a = 1.0 + z;
        (self.omega_m * a * a * a + self.omega_k() * a * a + self.omega_lambda).sqrt()
    }

    /// Line-of-sight comoving distance D_C (Mpc): composite Simpson rule
    /// with 256 intervals in u = ln(1+z), D_C = D_H ∫ (1+z)/E(z) du, which
    /// keeps the integrand smooth at high z (relative error < 1e-9 for
    /// z ≤ 10; tested against the Einstein–de Sitter closed form).
    pub fn comoving_distance_mpc(&self, z: f64) -> f64 {
        if z <= 0.0 {
            return 0.0;
        }
        let f = |u: f64| {
            let a = u.exp();
            a / self.e(a - 1.0)
        };
        self.hubble_distance_mpc() * simpson(f, 0.0, z.ln_1p(), 256)
    }

    /// Transverse comoving distance D_M (Mpc).
    pub fn transverse_distance_mpc(&self, z: f64) -> f64 {
        self.transverse_from_comoving(self.comoving_distance_mpc(z))
    }

    /// D_M from D_C (the curvature transform).
    pub fn transverse_from_comoving(&self, dc: f64) -> f64 {
        let ok = self.omega_k();
        let dh = self.hubble_distance_mpc();
        if ok.abs() < 1e-12 {
            dc
        } else if ok > 0.0 {
            let s = ok.sqrt();
            dh / s * (s * dc / dh).sinh()
        } else {
            let s = (-ok).sqrt();
            dh / s * (s * dc / dh).sin()
        }
    }

    /// Angular-diameter distance D_A (Mpc).
    pub fn angular_distance_mpc(&self, z: f64) -> f64 {
        self.transverse_distance_mpc(z) / (1.0 + z)
    }

    /// Luminosity distance D_L (Mpc).
    pub fn luminosity_distance_mpc(&self, z: f64) -> f64 {
        self.transverse_distance_mpc(z) * (1.0 + z)
    }

    /// Distance modulus 5 log10(D_L / 10 pc).
    pub fn distance_modulus(&self, z: f64) -> f64 {
        5.0 * (self.luminosity_distance_mpc(z) * 1e5).log10()
    }

    /// Comoving volume per unit redshift and steradian, Mpc³ sr⁻¹.
    pub fn dv_dz_dsr_mpc3(&self, z: f64) -> f64 {
        let dm = self.transverse_distance_mpc(z);
        self.hubble_distance_mpc() * dm * dm / self.e(z)
    }
}

/// Comoving distances tabulated on a uniform z grid and interpolated by
/// cubic Hermite polynomials using the exact slope dD_C/dz = D_H/E(z) (the
/// fast twin of [`Lcdm::comoving_distance_mpc`]; relative
/// error < 1e-9 for z ≥ 0.01 with the default 4096 cells, tested).
#[derive(Debug, Clone)]
pub struct DistanceTable {
    cosmo: Lcdm,
    dz: f64,
    dc: Vec<f64>,
}

impl DistanceTable {
    /// Tabulates D_C on [0, `z_max`] with `cells` cells.
    pub fn new(cosmo: Lcdm, z_max: f64, cells: usize) -> Self {
        let dz = z_max / cells as f64;
        let dc = (0..=cells)
            .map(|i| cosmo.comoving_distance_mpc(i as f64 * dz))
            .collect();
        Self { cosmo, dz, dc }
    }

    /// The cosmology.
    pub fn cosmology(&self) -> &Lcdm {
        &self.cosmo
    }

    /// Interpolated D_C (Mpc); beyond the table, the direct integral.
    pub fn comoving_distance_mpc(&self, z: f64) -> f64 {
        let t = z / self.dz;
        let i = t.floor();
        if !(0.0..(self.dc.len() - 1) as f64).contains(&i) {
            return self.cosmo.comoving_distance_mpc(z);
        }
        let k = i as usize;
        let f = t - i;
        let dh = self.cosmo.hubble_distance_mpc();
        let (z0, z1) = (k as f64 * self.dz, (k + 1) as f64 * self.dz);
        let (m0, m1) = (
            dh / self.cosmo.e(z0) * self.dz,
            dh / self.cosmo.e(z1) * self.dz,
        );
        let (f2, f3) = (f * f, f * f * f);
        self.dc[k] * (2.0 * f3 - 3.0 * f2 + 1.0)
            + m0 * (f3 - 2.0 * f2 + f)
            + self.dc[k + 1] * (-2.0 * f3 + 3.0 * f2)
            + m1 * (f3 - f2)
    }

    /// Transverse comoving distance D_M (Mpc).
    pub fn transverse_distance_mpc(&self, z: f64) -> f64 {
        self.cosmo
            .transverse_from_comoving(self.comoving_distance_mpc(z))
    }

    /// Angular-diameter distance (Mpc).
    pub fn angular_distance_mpc(&self, z: f64) -> f64 {
        self.transverse_distance_mpc(z) / (1.0 + z)
    }

    /// Distance modulus.
    pub fn distance_modulus(&self, z: f64) -> f64 {
        5.0 * (self.transverse_distance_mpc(z) * (1.0 + z) * 1e5).log10()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat() -> Lcdm {
        Lcdm::new(&Cosmology::default())
    }

    #[test]
    fn einstein_de_sitter_closed_form() {
        // Ωm = 1: D_C = 2 D_H (1 − 1/sqrt(1+z)).
        let c = Lcdm {
            h0: 70.0,
            omega_m: 1.0,
            omega_lambda: 0.0,
        };
        for z in [0.1, 0.5, 1.0, 3.0, 8.0] {
            let want = 2.0 * c.hubble_distance_mpc() * (1.0 - 1.0 / (1.0f64 + z).sqrt());
            let got = c.comoving_distance_mpc(z);
            assert!((got / want - 1.0).abs() < 1e-9, "z={z}: {got} vs {want}");
        }
    }

    #[test]
    fn flat_lcdm_reference_values() {
        // H0 = 70, Ωm = 0.3, ΩΛ = 0.7, z = 1: D_C = 3303.83 Mpc,
        // D_A = 1651.9 Mpc, distance modulus 44.10 (Wright 2006's
        // cosmology calculator gives these to the digits quoted).
        let c = flat();
        assert!((c.comoving_distance_mpc(1.0) - 3303.83).abs() < 0.5);
        assert!((c.angular_distance_mpc(1.0) - 1651.9).abs() < 0.3);
        assert!((c.distance_modulus(1.0) - 44.10).abs() < 0.01);
        // Low z: D_L → c z / H0.
        let z = 1e-4;
        assert!((c.luminosity_distance_mpc(z) / (C_KM_S * z / 70.0) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn volume_element_integrates_to_the_comoving_volume() {
        // Flat: V_C(z) = 4π/3 D_M³; integrate dV/dz/dΩ over 4π sr.
        let c = flat();
        let z = 2.0;
        let v = 4.0 * std::f64::consts::PI * simpson(|z| c.dv_dz_dsr_mpc3(z), 0.0, z, 400);
        let want = 4.0 / 3.0 * std::f64::consts::PI * c.transverse_distance_mpc(z).powi(3);
        assert!((v / want - 1.0).abs() < 1e-8, "{v} vs {want}");
    }

    #[test]
    fn distance_table_matches_the_integral() {
        let c = flat();
        let t = DistanceTable::new(c, 5.0, 4096);
        let mut worst = 0.0f64;
        for i in 1..=500 {
            let z = 0.01 * i as f64;
            let r = t.angular_distance_mpc(z) / c.angular_distance_mpc(z) - 1.0;
            worst = worst.max(r.abs());
            assert!((t.distance_modulus(z) - c.distance_modulus(z)).abs() < 1e-8);
        }
        assert!(worst < 1e-9, "{worst:e}");
        // Beyond the table it falls back to the integral.
        assert_eq!(t.comoving_distance_mpc(6.0), c.comoving_distance_mpc(6.0));
    }

    #[test]
    fn open_universe_uses_sinh() {
        let c = Lcdm {
            h0: 70.0,
            omega_m: 0.3,
            omega_lambda: 0.0,
        };
        assert!(c.transverse_distance_mpc(2.0) > c.comoving_distance_mpc(2.0));
        let closed = Lcdm {
            h0: 70.0,
            omega_m: 1.5,
            omega_lambda: 0.0,
        };
        assert!(closed.transverse_distance_mpc(2.0) < closed.comoving_distance_mpc(2.0));
    }
}
