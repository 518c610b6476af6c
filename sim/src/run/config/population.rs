//! `population` section: galaxies, stars and the cosmology behind them.
//!
//! The Stuff-style model parameters (luminosity functions, sizes, B/T,
//! K-corrections) are documented in `docs/population.md`.

use super::{Invalid, check_positive, check_range};
use crate::model::population::{Cosmology, GalaxySpec, StarSpec};
use serde::{Deserialize, Serialize};

/// `population`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawPopulation {
    /// Where the base fields come from.
    pub source: Source,
    /// Galaxy model.
    pub galaxies: GalaxySpec,
    /// Star model.
    pub stars: StarSpec,
    /// Cosmology for volumes and distances.
    pub cosmology: Cosmology,
    /// Beyond STEP1: every base field also exists with each galaxy's position
    /// angle turned by 90° (STEP2/GREAT3 shape-noise cancellation). Doubles
    /// the number of images per dataset.
    pub rotated_pairs: bool,
    /// Beyond STEP1: lens the galaxies' positions with the dataset's shear
    /// too (x = A⁻¹ x_s about the image centre, the mapping that goes with
    /// the shear matrix A of the profiles; stars stay put). Off by default
    /// and in the STEP1 presets: STEP1 sheared shapes only (κ = 0).
    pub lens_positions: bool,
    /// Beyond STEP2/GREAT3: with `rotated_pairs`, the twin is the whole
    /// field turned by 90° about the image centre, the positions of galaxies
    /// and stars as well as the galaxies' position angles, so that every
    /// spin-2 quantity of the field (shapes, and the directions from a galaxy
    /// to its neighbours) changes sign in the twin. Needs a square image.
    /// Left out of the resolved config when off, so that configs without it
    /// keep their bytes.
    #[serde(skip_serializing_if = "is_false")]
    pub rotate_positions: bool,
}

/// For `skip_serializing_if`: an option that is off is not written.
fn is_false(b: &bool) -> bool {
    !*b
}

/// Where the objects of the base fields come from.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
pub enum Source {
    /// Drawn from the Stuff-style model below.
    #[default]
    Stuff,
    /// Read from SkyMaker/Stuff list files, one per base field: the path may
    /// contain `{field}`, replaced by the 0-based field number.
    SkymakerList {
        /// Path pattern.
        path: String,
    },
}

impl RawPopulation {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        let f = &self.galaxies.flattening;
        check_range("population.galaxies.flattening.min", f.min, 0.0, 1.0)?;
        check_range("population.galaxies.flattening.max", f.max, 0.0, 1.0)?;
        if f.min >= f.max {
            return Err(Invalid::new(
                "population.galaxies.flattening".into(),
                format!("empty range: min {} ≥ max {}", f.min, f.max),
            ));
        }
        check_positive("population.galaxies.flattening.sigma", f.sigma)?;
        check_range("population.galaxies.flattening.mean", f.mean, -10.0, 10.0)?;
        // Resampling must terminate quickly: demand a 0.1 % acceptance rate.
        let cdf = stepsim_numerics::stats::normal_cdf;
        let accept = cdf((f.max - f.mean) / f.sigma) - cdf((f.min - f.mean) / f.sigma);
        if accept < 1e-3 {
            return Err(Invalid::new(
                "population.galaxies.flattening".into(),
                format!(
                    "only a fraction {accept:.2e} of N({}, {}) lies in [{}, {}] (need ≥ 1e-3)",
                    f.mean, f.sigma, f.min, f.max
                ),
            ));
        }
        check_range(
            "population.galaxies.max_inclination_deg",
            self.galaxies.max_inclination_deg,
            0.0,
            90.0,
        )?;
        let g = &self.galaxies;
        // I = 10 to 32: no galaxy of the model is brighter; beyond 32 the
        // counts only add memory (millions per arcmin²), no visible light.
        check_range("population.galaxies.mag_bright", g.mag_bright, 10.0, 32.0)?;
        check_range(
            "population.galaxies.mag_faint",
            g.mag_faint,
            g.mag_bright,
            32.0,
        )?;
        check_range("population.galaxies.z_max", g.z_max, 0.01, 5.5)?;
        check_range(
            "population.galaxies.phi_star_scale",
            g.phi_star_scale,
            0.0,
            100.0,
        )?;
        let [lo, hi] = g.abs_mag_limits;
        check_range("population.galaxies.abs_mag_limits.0", lo, -40.0, 0.0)?;
        check_range("population.galaxies.abs_mag_limits.1", hi, lo, 0.0)?;
        if g.types.len() != 6 {
            return Err(Invalid::new(
                "population.galaxies.types".into(),
                format!(
                    "exactly six types (E, S0, Sab, Sbc, Scd, Irr) are needed, got {}",
                    g.types.len()
                ),
            ));
        }
        for (i, t) in g.types.iter().enumerate() {
            let k = |f: &str| format!("population.galaxies.types.{i}.{f}");
            check_range(&k("bt"), t.bt, 0.0, 1.0)?;
            check_range(&k("phi_star_h3_mpc3"), t.phi_star_h3_mpc3, 0.0, 1.0)?;
            check_range(&k("m_star"), t.m_star, -30.0, -10.0)?;
            check_range(&k("alpha"), t.alpha, -3.0, 3.0)?;
            check_range(&k("phi_star_evol"), t.phi_star_evol, -10.0, 10.0)?;
            check_range(&k("m_star_evol"), t.m_star_evol, -10.0, 10.0)?;
            check_range(&k("b_minus_i"), t.b_minus_i, -2.0, 6.0)?;
            check_range(&k("uv_slope"), t.uv_slope, -5.0, 10.0)?;
            check_range(&k("t_type"), t.t_type, -10.0, 20.0)?;
            check_range(&k("disk_extinction"), t.disk_extinction, 0.0, 5.0)?;
        }
        let z = &g.sizes;
        let k = |f: &str| format!("population.galaxies.sizes.{f}");
        check_positive(&k("disk_re_star_kpc_h"), z.disk_re_star_kpc_h)?;
        check_range(&k("disk_beta"), z.disk_beta, -5.0, 5.0)?;
        check_range(&k("disk_sigma_ln"), z.disk_sigma_ln, 0.0, 3.0)?;
        check_range(&k("disk_evol"), z.disk_evol, -5.0, 5.0)?;
        check_range(&k("bulge_m_knee"), z.bulge_m_knee, -30.0, -10.0)?;
        check_positive(&k("bulge_re_knee_kpc_h"), z.bulge_re_knee_kpc_h)?;
        check_range(&k("bulge_evol"), z.bulge_evol, -5.0, 5.0)?;
        let s = &self.stars;
        // Up to 1e4 per arcmin² (about 3 per arcsec²: a stellar cluster core).
        check_range(
            "population.stars.density_per_arcmin2",
            s.density_per_arcmin2,
            0.0,
            1e4,
        )?;
        check_range("population.stars.slope", s.slope, -2.0, 2.0)?;
        check_range("population.stars.mag_bright", s.mag_bright, 5.0, 32.0)?;
        check_range(
            "population.stars.mag_faint",
            s.mag_faint,
            s.mag_bright,
            32.0,
        )?;
        let c = &self.cosmology;
        check_positive("population.cosmology.h0", c.h0)?;
        check_range("population.cosmology.omega_m", c.omega_m, 0.0, 5.0)?;
        check_range(
            "population.cosmology.omega_lambda",
            c.omega_lambda,
            -5.0,
            5.0,
        )?;
        if let Source::SkymakerList { path } = &self.source {
            if path.is_empty() {
                return Err(Invalid::new(
                    "population.source.skymaker_list.path".into(),
                    "empty path".into(),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::population::Flattening;

    #[test]
    fn defaults_validate_and_bad_values_name_their_key() {
        assert!(RawPopulation::default().validate().is_ok());
        let mut p = RawPopulation::default();
        p.galaxies.flattening = Flattening {
            mean: 5.0,
            sigma: 0.1,
            min: 0.3,
            max: 1.0,
        };
        let Invalid { key: k, message: m } = p.validate().unwrap_err();
        assert_eq!(k, "population.galaxies.flattening");
        assert!(m.contains("fraction"), "{m}");
        let mut p = RawPopulation::default();
        p.galaxies.types[3].bt = 1.5;
        assert_eq!(
            p.validate().unwrap_err().key,
            "population.galaxies.types.3.bt"
        );
        let mut p = RawPopulation::default();
        p.galaxies.types.pop();
        assert_eq!(p.validate().unwrap_err().key, "population.galaxies.types");
        let mut p = RawPopulation::default();
        p.galaxies.sizes.disk_re_star_kpc_h = -1.0;
        assert_eq!(
            p.validate().unwrap_err().key,
            "population.galaxies.sizes.disk_re_star_kpc_h"
        );
        let mut p = RawPopulation::default();
        p.galaxies.z_max = 8.0;
        assert_eq!(p.validate().unwrap_err().key, "population.galaxies.z_max");
    }
}
