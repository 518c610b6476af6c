//! `population` section: galaxies, stars and the cosmology behind them.
//!
//! The Stuff-style model parameters (luminosity functions, sizes, B/T,
//! K-corrections) are documented in `docs/population.md`.

use super::{Invalid, check_positive, check_range};
use serde::{Deserialize, Serialize};

/// `population`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawPopulation {
    /// Where the base fields come from.
    pub source: Source,
    /// Galaxy model.
    pub galaxies: RawGalaxies,
    /// Star model.
    pub stars: RawStars,
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

/// Intrinsic bulge flattening law: normal, truncated by resampling.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Flattening {
    /// Mean (paper: 0.65).
    pub mean: f64,
    /// Standard deviation (paper: 0.18).
    pub sigma: f64,
    /// Lower truncation (paper: 0.3).
    pub min: f64,
    /// Upper truncation (paper: 1).
    pub max: f64,
}

impl Default for Flattening {
    fn default() -> Self {
        Self {
            mean: 0.65,
            sigma: 0.18,
            min: 0.3,
            max: 1.0,
        }
    }
}

/// Inclination law of the disks.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum InclinationLaw {
    /// Uniform in angle on [0, max_inclination_deg] (Stuff; STEP1 default).
    Flat,
    /// Isotropic orientations: cos i uniform on [cos max, 1].
    Isotropic,
}

/// `population.galaxies`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawGalaxies {
    /// Bright limit of the apparent I (Vega) magnitude.
    pub mag_bright: f64,
    /// Faint limit of the apparent I (Vega) magnitude.
    pub mag_faint: f64,
    /// Bulge intrinsic flattening.
    pub flattening: Flattening,
    /// Inclination law.
    pub inclination: InclinationLaw,
    /// Largest inclination (Stuff: 85°).
    pub max_inclination_deg: f64,
    /// The Hubble types E, S0, Sab, Sbc, Scd, Irr (exactly six, in this
    /// order): luminosity functions, B/T and colours.
    pub types: Vec<GalaxyType>,
    /// Every type's φ* is multiplied by this: the calibration of the model's
    /// I-band counts to the CFDF/Hawaii deep-field counts (see
    /// `docs/population.md`; Stuff's own defaults give ≈ 0.6× the observed
    /// counts at I ≈ 20 with this project's K-corrections).
    pub phi_star_scale: f64,
    /// Luminosity–size relations.
    pub sizes: Sizes,
    /// Bounds of every luminosity function, absolute B_J magnitude − 5 log10 h
    /// (Stuff `LF_MAGLIMITS`: −27, −13).
    pub abs_mag_limits: [f64; 2],
    /// Galaxies are placed at redshifts in (0, z_max] (the model has no
    /// Lyman break: keep z_max ≤ 5 so that I stays redward of Lyman α).
    pub z_max: f64,
}

/// One Hubble type of the Stuff-style model. Absolute magnitudes are in the
/// reference band B_J (Vega) and written as M − 5 log10 h; densities in
/// h³ Mpc⁻³ (Stuff's conventions). Sources in `docs/population.md`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GalaxyType {
    /// Name (E, S0, Sab, Sbc, Scd, Irr).
    pub name: String,
    /// de Vaucouleurs T, written in SkyMaker lists (Stuff `HUBBLE_TYPE`).
    pub t_type: f64,
    /// Bulge-to-total flux ratio (Stuff `BULGE_FRACTION`).
    pub bt: f64,
    /// Schechter φ* at z = 0, h³ Mpc⁻³ (Stuff `LF_PHISTAR`).
    pub phi_star_h3_mpc3: f64,
    /// Schechter M* − 5 log10 h at z = 0, B_J Vega (Stuff `LF_MSTAR`).
    pub m_star: f64,
    /// Schechter faint-end slope α (Stuff `LF_ALPHA`).
    pub alpha: f64,
    /// d ln φ* / d ln(1+z) (Stuff `LF_PHISTAREVOL`).
    pub phi_star_evol: f64,
    /// d M* / d ln(1+z) (Stuff `LF_MSTAREVOL`).
    pub m_star_evol: f64,
    /// Rest-frame colour B − I (Vega) of the type; sets the optical slope of
    /// the power-law SED used for the K-correction.
    pub b_minus_i: f64,
    /// Slope s of the SED f_ν ∝ λ^s blueward of 4000 Å (the break).
    pub uv_slope: f64,
    /// Internal extinction of the disk, de Vaucouleurs' α: A_B(i) =
    /// α log10(sec i) (Stuff `DISK_EXTINCT`).
    pub disk_extinction: f64,
}

impl GalaxyType {
    #[allow(clippy::too_many_arguments)]
    fn new(
        name: &str,
        t_type: f64,
        bt: f64,
        phi_star_h3_mpc3: f64,
        m_star: f64,
        alpha: f64,
        phi_star_evol: f64,
        m_star_evol: f64,
        b_minus_i: f64,
        uv_slope: f64,
        disk_extinction: f64,
    ) -> Self {
        Self {
            name: name.into(),
            t_type,
            bt,
            phi_star_h3_mpc3,
            m_star,
            alpha,
            phi_star_evol,
            m_star_evol,
            b_minus_i,
            uv_slope,
            disk_extinction,
        }
    }

    /// The six types with Stuff's default parameters (B/T, LFs and their
    /// evolution) and this project's colours (see `docs/population.md`).
    pub fn stuff_defaults() -> Vec<Self> {
        vec![
            Self::new(
                "E", -6.0, 1.0, 4.95e-3, -19.58, -0.54, -1.7, -1.0, 2.27, 4.0, 0.0,
            ),
            Self::new(
                "S0", -2.0, 0.57, 4.95e-3, -19.58, -0.54, -1.7, -1.0, 2.15, 3.5, 0.75,
            ),
            Self::new(
                "Sab", 2.0, 0.32, 7.2e-3, -19.53, -0.99, -1.2, -1.0, 2.0, 2.5, 1.23,
            ),
            Self::new(
                "Sbc", 4.0, 0.16, 5.0e-3, -19.17, -1.24, -1.2, -1.0, 1.75, 1.5, 1.47,
            ),
            Self::new(
                "Scd", 6.0, 0.049, 1.2e-3, -19.15, -1.50, -1.2, -1.0, 1.45, 2.0, 1.47,
            ),
            Self::new(
                "Irr", 10.0, 0.0, 1.2e-3, -19.15, -1.50, 1.9, -1.5, 1.05, 2.5, 1.23,
            ),
        ]
    }
}

/// Luminosity–size relations (Stuff defaults; sources in `docs/population.md`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Sizes {
    /// Disk effective radius at L*, h⁻¹ kpc (de Jong & Lacey 2000; Stuff
    /// `DISK_RSTAR` 3.85). The scale length is this / 1.67835.
    pub disk_re_star_kpc_h: f64,
    /// Disk size–luminosity exponent β: h ∝ (L/L*)^(−β) (Stuff `DISK_BETA`).
    pub disk_beta: f64,
    /// Log-normal scatter σ of ln h (Stuff `DISK_SIGMAL`).
    pub disk_sigma_ln: f64,
    /// d ln h / d ln(1+z) (Stuff `DISK_REVOL`).
    pub disk_evol: f64,
    /// Absolute magnitude of the knee, M − 5 log10 h (Stuff `SPHEROID_MKNEE`).
    pub bulge_m_knee: f64,
    /// Bulge effective radius at the knee, h⁻¹ kpc (Stuff `SPHEROID_RKNEE`).
    pub bulge_re_knee_kpc_h: f64,
    /// d ln r_e / d ln(1+z) (Stuff `SPHEROID_REVOL`).
    pub bulge_evol: f64,
}

impl Default for Sizes {
    fn default() -> Self {
        Self {
            disk_re_star_kpc_h: 3.85,
            disk_beta: -0.214,
            disk_sigma_ln: 0.36,
            disk_evol: -0.4,
            bulge_m_knee: -20.0,
            bulge_re_knee_kpc_h: 1.58,
            bulge_evol: -0.5,
        }
    }
}

impl Default for RawGalaxies {
    fn default() -> Self {
        Self {
            mag_bright: 17.0,
            mag_faint: 26.0,
            flattening: Flattening::default(),
            inclination: InclinationLaw::Flat,
            max_inclination_deg: 85.0,
            types: GalaxyType::stuff_defaults(),
            phi_star_scale: 1.5,
            sizes: Sizes::default(),
            abs_mag_limits: [-27.0, -13.0],
            z_max: 5.0,
        }
    }
}

/// `population.stars`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawStars {
    /// Stars per arcmin² between the bright and the faint limit.
    pub density_per_arcmin2: f64,
    /// d log10 N / dm of the differential counts (paper: 0.3).
    pub slope: f64,
    /// Bright limit (I, Vega).
    pub mag_bright: f64,
    /// Faint limit (paper: 25).
    pub mag_faint: f64,
}

impl Default for RawStars {
    fn default() -> Self {
        Self {
            density_per_arcmin2: 10.0,
            slope: 0.3,
            mag_bright: 17.0,
            mag_faint: 25.0,
        }
    }
}

/// `population.cosmology`: flat or curved ΛCDM.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Cosmology {
    /// Hubble constant, km s⁻¹ Mpc⁻¹.
    pub h0: f64,
    /// Matter density.
    pub omega_m: f64,
    /// Dark energy density.
    pub omega_lambda: f64,
}

impl Default for Cosmology {
    fn default() -> Self {
        Self {
            h0: 70.0,
            omega_m: 0.3,
            omega_lambda: 0.7,
        }
    }
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
        let cdf = crate::stats::normal_cdf;
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
