//! The Stuff-style luminosity model: six Hubble types with evolving
//! Schechter luminosity functions in the reference band B_J (Vega), placed
//! in a ΛCDM light cone and observed in I (Vega).
//!
//! Per type t (parameters in `docs/population.md`):
//! * φ_t(M, z) dM = 0.4 ln 10 · φ*(z) x^(α+1) e^(−x) dM,
//!   x = 10^(0.4 (M*(z) − M)), with φ*(z) = φ* (1+z)^(d ln φ*/d ln(1+z))
//!   and M*(z) = M* + (dM*/d ln(1+z)) ln(1+z) (Stuff's evolution laws),
//!   for M in the `abs_mag_limits`.
//! * Apparent I = M_B + DM(z) + K_t(z), K_t the cross-band K-correction of
//!   [`Sed`].
//! * Counts per arcmin² per dz: dV/dz/dΩ · ∫ φ_t dM over the M range that
//!   lands inside [mag_bright, mag_faint].
//!
//! Absolute magnitudes of the config are M − 5 log10 h and densities
//! h³ Mpc⁻³ (Stuff's conventions); they are converted with the config's h.
//!
//! Internal extinction of disks (Stuff's approach, simplified): the disk
//! of a type with de Vaucouleurs coefficient α is dimmed by
//! A(i, λ) = α log10(sec i) · (λ_B/λ) at rest wavelength λ (a λ⁻¹ law, an
//! analytic stand-in for an LMC-like extinction curve). The luminosity
//! functions describe galaxies at the average inclination, so each type's
//! M* is brightened to face-on by Δ = −2.5 log10(B/T + (1 − B/T)
//! ⟨10^(−0.4 A(i, λ_B))⟩), the average taken over the inclination law.
//! Extinction only dims, so the table is built for face-on magnitudes in
//! [mag_bright − A_max, mag_faint]; each drawn galaxy gets its inclination,
//! is dimmed, and is kept only if it lands in [mag_bright, mag_faint]
//! (thinning a Poisson process keeps it Poisson).
//!
//! Drawing: the expected counts are tabulated on a fine z grid
//! (dz ≤ 0.005) per type; a galaxy picks (type, z-cell) from the cumulative
//! table, z uniform in the cell, then M from φ_t restricted to the M range
//! that gives mag_bright ≤ I ≤ mag_faint at that z, by rejection under the
//! exact maximum of φ_t on the range.

use super::cosmology::{DistanceTable, Lcdm};
use super::{GalaxySpec, GalaxyType, InclinationLaw};
use rand::RngExt;
use stepsim_contract::seed::SimRng;

/// One arcmin² in steradians.
pub const ARCMIN2_SR: f64 =
    (std::f64::consts::PI / (180.0 * 60.0)) * (std::f64::consts::PI / (180.0 * 60.0));

/// Effective wavelength of B (µm).
pub const LAMBDA_B_UM: f64 = 0.44;
/// Effective wavelength of Cousins I (µm).
pub const LAMBDA_I_UM: f64 = 0.80;
/// Wavelength of the 4000 Å break (µm).
pub const LAMBDA_BREAK_UM: f64 = 0.40;
/// B_AB − B_Vega (Frei & Gunn 1994; Blanton & Roweis 2007: −0.09).
pub const B_AB_MINUS_VEGA: f64 = -0.09;
/// I_AB − I_Vega for Cousins I (SPEC §1: 0.45).
pub const I_AB_MINUS_VEGA: f64 = 0.45;

/// Analytic spectral energy distribution of a type: a broken power law in
/// f_ν, f_ν ∝ λ^s with s = `opt_slope` redward of 4000 Å and `uv_slope`
/// blueward (continuous at the break). `opt_slope` is set by the rest-frame
/// colour: (B − I)_AB = 2.5 s log10(λ_I/λ_B).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sed {
    /// Optical slope s of f_ν ∝ λ^s.
    pub opt_slope: f64,
    /// Slope blueward of the 4000 Å break.
    pub uv_slope: f64,
}

impl Sed {
    /// From a rest-frame (B − I) Vega colour and the UV slope.
    pub fn new(b_minus_i_vega: f64, uv_slope: f64) -> Self {
        let bi_ab = b_minus_i_vega + B_AB_MINUS_VEGA - I_AB_MINUS_VEGA;
        Self {
            opt_slope: bi_ab / (2.5 * (LAMBDA_I_UM / LAMBDA_B_UM).log10()),
            uv_slope,
        }
    }

    /// AB magnitude at rest wavelength `lambda_um` minus that at λ_B.
    pub fn mag_rel_b(&self, lambda_um: f64) -> f64 {
        let above = |l: f64| -2.5 * self.opt_slope * (l / LAMBDA_B_UM).log10();
        if lambda_um >= LAMBDA_BREAK_UM {
            above(lambda_um)
        } else {
            above(LAMBDA_BREAK_UM) - 2.5 * self.uv_slope * (lambda_um / LAMBDA_BREAK_UM).log10()
        }
    }

    /// Cross-band K-correction: I(Vega, observed) = M_B(Vega) + DM(z) + K(z).
    /// K(z) = (B_AB − B) − (I_AB − I) − 2.5 log10(1+z) + [m(λ_I/(1+z)) − m(λ_B)]_AB
    /// (the f_ν bandwidth term of Hogg et al. 2002 eq. 13 for narrow bands).
    /// At z = 0 it is −(B − I).
    pub fn k_correction(&self, z: f64) -> f64 {
        B_AB_MINUS_VEGA - I_AB_MINUS_VEGA - 2.5 * (1.0 + z).log10()
            + self.mag_rel_b(LAMBDA_I_UM / (1.0 + z))
    }
}

/// One type with its parameters in real (not h-scaled) units.
#[derive(Debug, Clone, PartialEq)]
pub struct TypeModel {
    /// Hubble type code (0 E … 5 Irr).
    pub code: i32,
    /// Bulge-to-total ratio.
    pub bt: f64,
    /// φ* at z = 0, Mpc⁻³.
    pub phi_star: f64,
    /// M* at z = 0 (B_J Vega, real units).
    pub m_star: f64,
    /// α.
    pub alpha: f64,
    /// d ln φ* / d ln(1+z).
    pub phi_evol: f64,
    /// dM*/d ln(1+z).
    pub m_evol: f64,
    /// SED for the K-correction.
    pub sed: Sed,
    /// Disk extinction coefficient α (A_B = α log10 sec i).
    pub extinction: f64,
    /// Face-on brightening Δ applied to M* (magnitudes, ≥ 0).
    pub face_on_shift: f64,
}

impl TypeModel {
    /// From the config entry, with h = H0/100, without extinction.
    pub fn new(code: i32, t: &GalaxyType, h: f64) -> Self {
        Self {
            code,
            bt: t.bt,
            phi_star: t.phi_star_h3_mpc3 * h * h * h,
            m_star: t.m_star + 5.0 * h.log10(),
            alpha: t.alpha,
            phi_evol: t.phi_star_evol,
            m_evol: t.m_star_evol,
            sed: Sed::new(t.b_minus_i, t.uv_slope),
            extinction: 0.0,
            face_on_shift: 0.0,
        }
    }

    /// From the config entry with disk extinction: M* brightened to
    /// face-on by the mean over the inclination law.
    pub fn with_extinction(
        code: i32,
        t: &GalaxyType,
        h: f64,
        law: InclinationLaw,
        max_incl: f64,
    ) -> Self {
        let mut m = Self::new(code, t, h);
        m.extinction = t.disk_extinction;
        let mean = mean_over_inclination(law, max_incl, |i| {
            10f64.powf(-0.4 * m.disk_extinction(i, LAMBDA_B_UM))
        });
        m.face_on_shift = -2.5 * (t.bt + (1.0 - t.bt) * mean).log10();
        m.m_star -= m.face_on_shift;
        m
    }

    /// Disk extinction (mag) at inclination `incl` (radians) and rest
    /// wavelength `lambda_um`: α log10(sec i) λ_B/λ, with i capped at 89°.
    pub fn disk_extinction(&self, incl: f64, lambda_um: f64) -> f64 {
        let c = incl.cos().max(89f64.to_radians().cos());
        self.extinction * (-c.log10()) * LAMBDA_B_UM / lambda_um
    }

    /// Observed I magnitude and B/T of a galaxy whose face-on total I
    /// magnitude is `mag_face_on`, at inclination `incl` and redshift `z`:
    /// only the disk is dimmed.
    pub fn observe(&self, mag_face_on: f64, incl: f64, z: f64) -> (f64, f64) {
        let a = self.disk_extinction(incl, LAMBDA_I_UM / (1.0 + z));
        let fb = self.bt;
        let fd = (1.0 - self.bt) * 10f64.powf(-0.4 * a);
        let tot = fb + fd;
        (
            mag_face_on - 2.5 * tot.log10(),
            if tot > 0.0 { fb / tot } else { 0.0 },
        )
    }

    /// Luminosity evolution of M* at z (magnitudes).
    pub fn dm_star(&self, z: f64) -> f64 {
        self.m_evol * (1.0 + z).ln()
    }

    /// φ(M, z) in Mpc⁻³ mag⁻¹.
    pub fn phi(&self, m: f64, z: f64) -> f64 {
        let phi_star = self.phi_star * (1.0 + z).powf(self.phi_evol);
        let x = 10f64.powf(0.4 * (self.m_star + self.dm_star(z) - m));
        0.4 * std::f64::consts::LN_10 * phi_star * x.powf(self.alpha + 1.0) * (-x).exp()
    }

    /// ∫ φ(M, z) dM over [m1, m2] (composite Simpson, 128 intervals).
    pub fn phi_integral(&self, m1: f64, m2: f64, z: f64) -> f64 {
        if m2 <= m1 {
            return 0.0;
        }
        stepsim_numerics::quad::simpson(|m| self.phi(m, z), m1, m2, 128)
    }

    /// Maximum of φ(·, z) on [m1, m2]: φ peaks at M* − 2.5 log10(α+1) when
    /// α > −1 and rises monotonically to the faint end otherwise.
    pub fn phi_max(&self, m1: f64, m2: f64, z: f64) -> f64 {
        let peak = if self.alpha > -1.0 {
            self.m_star + self.dm_star(z) - 2.5 * (self.alpha + 1.0).log10()
        } else {
            f64::INFINITY
        };
        self.phi(peak.clamp(m1, m2), z)
    }
}

/// The model, tabulated for one apparent-magnitude range.
#[derive(Debug, Clone)]
pub struct StuffModel {
    /// The six types.
    pub types: Vec<TypeModel>,
    /// Cosmology.
    pub cosmo: Lcdm,
    /// Tabulated distances for the draws.
    pub distances: DistanceTable,
    /// Absolute-magnitude bounds of the LFs (real units).
    pub abs_limits: (f64, f64),
    /// Face-on apparent I range of the table.
    pub mag_range: (f64, f64),
    /// Observed apparent I range.
    pub observed_range: (f64, f64),
    /// Redshift cell width.
    pub dz: f64,
    /// Number of z cells.
    pub nz: usize,
    /// Cumulative expected counts per arcmin², index t·nz + i.
    cumulative: Vec<f64>,
}

/// A galaxy's luminosity, type and redshift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Luminous {
    /// Index of the type (Hubble code).
    pub code: i32,
    /// Redshift.
    pub z: f64,
    /// Absolute B_J magnitude (Vega, real units).
    pub m_abs: f64,
    /// Face-on apparent I (Vega).
    pub mag: f64,
    /// Angular-diameter distance (Mpc).
    pub d_a_mpc: f64,
}

impl StuffModel {
    /// Tabulates the model for observed I in [`mag_bright`, `mag_faint`]:
    /// face-on magnitudes in [`mag_bright` − A_max, `mag_faint`].
    pub fn new(g: &GalaxySpec, cosmo: Lcdm, mag_bright: f64, mag_faint: f64) -> Self {
        let h = cosmo.h();
        let max_incl = g.max_inclination_deg.to_radians();
        let types: Vec<TypeModel> = g
            .types
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let mut m = TypeModel::with_extinction(i as i32, t, h, g.inclination, max_incl);
                m.phi_star *= g.phi_star_scale;
                m
            })
            .collect();
        let a_max = types
            .iter()
            .map(|t| t.disk_extinction(max_incl, LAMBDA_I_UM / (1.0 + g.z_max)))
            .fold(0.0, f64::max);
        let dh = 5.0 * h.log10();
        let abs_limits = (g.abs_mag_limits[0] + dh, g.abs_mag_limits[1] + dh);
        let nz = (g.z_max / 0.005).ceil().max(1.0) as usize;
        let dz = g.z_max / nz as f64;
        let mut m = Self {
            types,
            cosmo,
            distances: DistanceTable::new(cosmo, g.z_max, 4096),
            abs_limits,
            mag_range: (mag_bright - a_max, mag_faint),
            observed_range: (mag_bright, mag_faint),
            dz,
            nz,
            cumulative: Vec::new(),
        };
        let mut cum = Vec::with_capacity(nz * m.types.len());
        let mut total = 0.0;
        let dist: Vec<(f64, f64)> = (0..nz)
            .map(|i| {
                let z = (i as f64 + 0.5) * dz;
                (cosmo.distance_modulus(z), cosmo.dv_dz_dsr_mpc3(z))
            })
            .collect();
        for t in &m.types {
            for (i, &(dmod, dv)) in dist.iter().enumerate() {
                let z = (i as f64 + 0.5) * dz;
                let (m1, m2) = m.abs_range(t, z, dmod);
                total += dv * ARCMIN2_SR * dz * t.phi_integral(m1, m2, z);
                cum.push(total);
            }
        }
        m.cumulative = cum;
        m
    }

    /// The absolute-magnitude range of type `t` at z that lands in the
    /// apparent range.
    fn abs_range(&self, t: &TypeModel, z: f64, dmod: f64) -> (f64, f64) {
        let k = t.sed.k_correction(z);
        let m1 = (self.mag_range.0 - dmod - k).max(self.abs_limits.0);
        let m2 = (self.mag_range.1 - dmod - k).min(self.abs_limits.1);
        (m1, m2)
    }

    /// Expected galaxies per arcmin² in the face-on range of the table
    /// (an upper bound of the observed density; drawn galaxies are thinned).
    pub fn density_per_arcmin2(&self) -> f64 {
        self.cumulative.last().copied().unwrap_or(0.0)
    }

    /// Slow reference for [`Self::density_per_arcmin2`]: a plain midpoint
    /// double sum over z (`nz` cells) and M (`nm` cells across the
    /// absolute-magnitude bounds), with the distance integral evaluated
    /// directly at every z and the magnitude window tested per cell.
    pub fn density_per_arcmin2_slow(&self, z_max: f64, nz: usize, nm: usize) -> f64 {
        let dz = z_max / nz as f64;
        let (a0, a1) = self.abs_limits;
        let dm = (a1 - a0) / nm as f64;
        let mut total = 0.0;
        for i in 0..nz {
            let z = (i as f64 + 0.5) * dz;
            let dmod = self.cosmo.distance_modulus(z);
            let dv = self.cosmo.dv_dz_dsr_mpc3(z) * ARCMIN2_SR * dz;
            for t in &self.types {
                let k = t.sed.k_correction(z);
                for j in 0..nm {
                    let m = a0 + (j as f64 + 0.5) * dm;
                    let app = m + dmod + k;
                    if app >= self.mag_range.0 && app <= self.mag_range.1 {
                        total += dv * t.phi(m, z) * dm;
                    }
                }
            }
        }
        total
    }

    /// Fraction of the table's galaxies at redshift < `z` (all types; linear
    /// within a cell): the CDF that [`Self::draw`] samples.
    pub fn z_cdf(&self, z: f64) -> f64 {
        let total = self.density_per_arcmin2();
        let t = (z / self.dz).clamp(0.0, self.nz as f64);
        let i = (t.floor() as usize).min(self.nz - 1);
        let f = t - i as f64;
        let mut below = 0.0;
        for ty in 0..self.types.len() {
            let base = ty * self.nz;
            let before = if base + i == 0 {
                0.0
            } else {
                self.cumulative[base + i - 1]
            };
            let start = if base == 0 {
                0.0
            } else {
                self.cumulative[base - 1]
            };
            let cell = self.cumulative[base + i] - before;
            below += before - start + f * cell;
        }
        below / total
    }

    /// Expected galaxies per arcmin² of type `code` in the apparent range.
    pub fn type_density_per_arcmin2(&self, code: usize) -> f64 {
        let end = self.cumulative[(code + 1) * self.nz - 1];
        let start = if code == 0 {
            0.0
        } else {
            self.cumulative[code * self.nz - 1]
        };
        end - start
    }

    /// Draws the type, redshift and magnitudes of one galaxy.
    pub fn draw(&self, rng: &mut SimRng) -> Luminous {
        let total = self.density_per_arcmin2();
        let u = rng.random::<f64>() * total;
        let k = self
            .cumulative
            .partition_point(|&c| c <= u)
            .min(self.cumulative.len() - 1);
        let (ti, zi) = (k / self.nz, k % self.nz);
        let t = &self.types[ti];
        let z = (zi as f64 + rng.random::<f64>()) * self.dz;
        let z = z.max(1e-6);
        let dmod = self.distances.distance_modulus(z);
        let (m1, m2) = self.abs_range(t, z, dmod);
        let m_abs = if m2 > m1 {
            let fmax = self.phi_max(t, m1, m2, z);
            loop {
                let m = m1 + (m2 - m1) * rng.random::<f64>();
                if rng.random::<f64>() * fmax <= t.phi(m, z) {
                    break m;
                }
            }
        } else {
            // The cell had weight only at its centre (a sliver at the edge
            // of the magnitude range): take the nearest allowed magnitude.
            m1.min(self.abs_limits.1).max(self.abs_limits.0)
        };
        let mag = (m_abs + dmod + t.sed.k_correction(z)).clamp(self.mag_range.0, self.mag_range.1);
        Luminous {
            code: t.code,
            z,
            m_abs,
            mag,
            d_a_mpc: self.distances.angular_distance_mpc(z),
        }
    }

    fn phi_max(&self, t: &TypeModel, m1: f64, m2: f64, z: f64) -> f64 {
        t.phi_max(m1, m2, z)
    }
}

/// Average of `f(i)` over the inclination law on [0, `max_incl`]
/// (midpoint rule, 2000 cells).
pub fn mean_over_inclination(law: InclinationLaw, max_incl: f64, f: impl Fn(f64) -> f64) -> f64 {
    let n = 2000;
    let h = max_incl / n as f64;
    let (mut s, mut w) = (0.0, 0.0);
    for k in 0..n {
        let i = (k as f64 + 0.5) * h;
        let wt = match law {
            InclinationLaw::Flat => 1.0,
            InclinationLaw::Isotropic => i.sin(),
        };
        s += wt * f(i);
        w += wt;
    }
    if w > 0.0 { s / w } else { f(0.0) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::population::Cosmology;

    #[test]
    fn k_correction_limits() {
        let sed = Sed::new(2.27, 4.0);
        // z = 0: K = −(B − I).
        assert!((sed.k_correction(0.0) + 2.27).abs() < 1e-12);
        // At z = λ_I/λ_B − 1 the I band sees rest B: K = (B_AB−B) − (I_AB−I) − 2.5 log(1+z).
        let z = LAMBDA_I_UM / LAMBDA_B_UM - 1.0;
        let want = B_AB_MINUS_VEGA - I_AB_MINUS_VEGA - 2.5 * (1.0 + z).log10();
        assert!((sed.k_correction(z) - want).abs() < 1e-12);
        // A red SED dims faster with z than a blue one.
        let blue = Sed::new(1.05, 0.5);
        let dk_red = sed.k_correction(1.5) - sed.k_correction(0.0);
        let dk_blue = blue.k_correction(1.5) - blue.k_correction(0.0);
        assert!(dk_red > dk_blue + 1.0, "{dk_red} {dk_blue}");
    }

    #[test]
    fn schechter_integral_matches_the_gamma_function() {
        // ∫ φ dM over all M = φ* Γ(α + 1) (α = 0, 1: Γ = 1; α = −0.5: √π).
        let g = GalaxySpec::default();
        for (alpha, gamma) in [(0.0, 1.0), (1.0, 1.0), (-0.5, std::f64::consts::PI.sqrt())] {
            let mut t = TypeModel::new(0, &g.types[0], 1.0);
            t.alpha = alpha;
            let i = t.phi_integral(t.m_star - 8.0, t.m_star + 40.0, 0.0);
            assert!(
                (i / (t.phi_star * gamma) - 1.0).abs() < 1e-4,
                "{alpha}: {i}"
            );
        }
    }

    #[test]
    fn table_matches_brute_force_and_draws_follow_the_table() {
        let g = GalaxySpec::default();
        let m = StuffModel::new(&g, Lcdm::new(&Cosmology::default()), 20.0, 24.0);
        let fast = m.density_per_arcmin2();
        let slow = m.density_per_arcmin2_slow(g.z_max, 1000, 2000);
        assert!((fast / slow - 1.0).abs() < 2e-3, "{fast} vs {slow}");
        let mut rng =
            stepsim_contract::seed::SeedKey::base(6, 0, stepsim_contract::seed::Stream::Test).rng();
        let zs: Vec<f64> = (0..20_000).map(|_| m.draw(&mut rng).z).collect();
        let d = stepsim_numerics::stats::ks_statistic(&zs, |z| m.z_cdf(z));
        let p = stepsim_numerics::stats::ks_p_value(d, zs.len());
        assert!(p > 1e-3, "D = {d}, p = {p}");
        assert!((m.z_cdf(0.0)).abs() < 1e-15 && (m.z_cdf(g.z_max) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn drawn_magnitudes_stay_in_range_and_phi_max_bounds_phi() {
        let g = GalaxySpec::default();
        let m = StuffModel::new(&g, Lcdm::new(&Cosmology::default()), 20.0, 24.0);
        let mut rng =
            stepsim_contract::seed::SeedKey::base(5, 0, stepsim_contract::seed::Stream::Test).rng();
        for _ in 0..2000 {
            let l = m.draw(&mut rng);
            let (lo, hi) = m.mag_range;
            assert!(hi == 24.0 && lo < 20.0);
            assert!((lo..=hi).contains(&l.mag) && l.z > 0.0 && l.z <= g.z_max);
        }
        for t in &m.types {
            for z in [0.1, 1.0, 3.0] {
                let (m1, m2) = (-23.0, -16.0);
                let fmax = t.phi_max(m1, m2, z);
                for i in 0..=700 {
                    let mm = m1 + i as f64 * 0.01;
                    assert!(t.phi(mm, z) <= fmax * (1.0 + 1e-12));
                }
            }
        }
    }
}
