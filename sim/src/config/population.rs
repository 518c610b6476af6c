//! `population` section: galaxies, stars and the cosmology behind them.
//!
//! The Stuff-style model parameters (luminosity functions, sizes, B/T,
//! K-corrections) are documented in `docs/population.md`.

use super::{check_positive, check_range};
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
}

impl Default for RawGalaxies {
    fn default() -> Self {
        Self {
            mag_bright: 17.0,
            mag_faint: 26.0,
            flattening: Flattening::default(),
            inclination: InclinationLaw::Flat,
            max_inclination_deg: 85.0,
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
    pub(crate) fn validate(&self) -> Result<(), (String, String)> {
        let f = &self.galaxies.flattening;
        check_range("population.galaxies.flattening.min", f.min, 0.0, 1.0)?;
        check_range("population.galaxies.flattening.max", f.max, 0.0, 1.0)?;
        if f.min >= f.max {
            return Err((
                "population.galaxies.flattening".into(),
                format!("empty range: min {} ≥ max {}", f.min, f.max),
            ));
        }
        check_positive("population.galaxies.flattening.sigma", f.sigma)?;
        check_range("population.galaxies.flattening.mean", f.mean, -10.0, 10.0)?;
        check_range(
            "population.galaxies.max_inclination_deg",
            self.galaxies.max_inclination_deg,
            0.0,
            90.0,
        )?;
        let g = &self.galaxies;
        check_range("population.galaxies.mag_bright", g.mag_bright, 0.0, 40.0)?;
        check_range(
            "population.galaxies.mag_faint",
            g.mag_faint,
            g.mag_bright,
            40.0,
        )?;
        let s = &self.stars;
        check_range(
            "population.stars.density_per_arcmin2",
            s.density_per_arcmin2,
            0.0,
            1e5,
        )?;
        check_range("population.stars.slope", s.slope, -2.0, 2.0)?;
        check_range("population.stars.mag_bright", s.mag_bright, 0.0, 40.0)?;
        check_range(
            "population.stars.mag_faint",
            s.mag_faint,
            s.mag_bright,
            40.0,
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
                return Err((
                    "population.source.skymaker_list.path".into(),
                    "empty path".into(),
                ));
            }
        }
        Ok(())
    }
}
