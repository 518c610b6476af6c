//! A galaxy: the sum of a sheared de Vaucouleurs bulge and a sheared
//! exponential disk, built from a truth row.
//!
//! Geometry (as the population writes it, SPEC §2 and §5): component sizes
//! are along the major axis (`bulge_re_arcsec` the bulge half-light radius,
//! `disk_h_arcsec` the disk scale length); component c is the circular
//! profile stretched to axis ratio `bulge_ba` / `disk_ba` at position angle
//! `pa_deg` (CCW from +x, intrinsic), then sheared by A(g1, g2) of the row.
//! Bulge flux = `bt · flux_e`, disk flux = (1 − bt) · `flux_e`. The sheared
//! `*_e1`/`*_e2` columns are truth for scoring and are *not* used here.

use super::transform::{LinearMap, ellipticity_of_moments, shear_matrix};
use super::{DeVaucouleurs, Exponential, RadialProfile};
use stepsim_contract::truth::TruthRow;

/// A truth row that cannot be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("truth row id {id}: column `{column}` = {value}: {reason}")]
pub struct RowError {
    /// The row's `id`.
    pub id: i64,
    /// The offending column.
    pub column: &'static str,
    /// Its value.
    pub value: f64,
    /// What is wrong.
    pub reason: &'static str,
}

/// Which radial law a component follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProfileKind {
    /// De Vaucouleurs bulge; size = half-light radius.
    DeVaucouleurs,
    /// Exponential disk; size = scale length.
    Exponential,
}

impl ProfileKind {
    /// The unit profile.
    pub fn profile(self) -> &'static dyn RadialProfile {
        match self {
            Self::DeVaucouleurs => &DeVaucouleurs,
            Self::Exponential => &Exponential,
        }
    }

    /// f̃ as a function of t = |Lᵀk|² (k in cycles per arcsec).
    #[inline]
    pub fn transform_k2(self, t: f64) -> f64 {
        match self {
            Self::DeVaucouleurs => DeVaucouleurs::transform_k2(t),
            Self::Exponential => Exponential::transform_k2(t),
        }
    }
}

/// One elliptical, sheared component.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Component {
    /// Radial law.
    pub kind: ProfileKind,
    /// Flux in electrons.
    pub flux_e: f64,
    /// Unit-profile coordinates → arcsec (size, flattening, angle, shear).
    pub map: LinearMap,
}

impl Component {
    /// A component of major-axis size `size_arcsec`, axis ratio `ba`,
    /// position angle `pa_rad`, sheared by (g1, g2).
    pub fn new(
        kind: ProfileKind,
        flux_e: f64,
        size_arcsec: f64,
        ba: f64,
        pa_rad: f64,
        g1: f64,
        g2: f64,
    ) -> Self {
        let map = shear_matrix(g1, g2)
            .inverse()
            .then_after(LinearMap::ellipse(size_arcsec, ba, pa_rad));
        Self { kind, flux_e, map }
    }

    /// Transform at (u, v) cycles per arcsec, centred, in electrons.
    pub fn transform(&self, u: f64, v: f64) -> f64 {
        self.flux_e * self.kind.transform_k2(gram_k2(self.map.gram(), u, v))
    }

    /// Surface brightness (electrons per arcsec²) at offset (dx, dy) arcsec
    /// from the centre.
    pub fn density(&self, dx: f64, dy: f64) -> f64 {
        let (x, y) = self.map.inverse().apply(dx, dy);
        self.flux_e / self.map.det().abs() * self.kind.profile().density(x.hypot(y))
    }

    /// Unweighted second-moment tensor (xx, xy, yy) per unit flux, arcsec²,
    /// of the untruncated profile: ⟨r²⟩/2 · L Lᵀ.
    pub fn moments(&self) -> [f64; 3] {
        let h = 0.5 * self.kind.profile().mean_r2();
        self.map.gram().map(|q| q * h)
    }

    /// Radius (arcsec) outside which at most 1 − `fraction` of the flux lies
    /// (bound: the unit radius times the longest semi-axis).
    pub fn radius_enclosing(&self, fraction: f64) -> f64 {
        self.kind.profile().radius_enclosing(fraction) * self.map.max_stretch()
    }

    /// Radius (arcsec) beyond which the surface brightness is below
    /// `level_e_arcsec2` in every direction.
    pub fn radius_density_below(&self, level_e_arcsec2: f64) -> f64 {
        let det = self.map.det().abs();
        if self.flux_e <= 0.0 || det <= 0.0 {
            return 0.0;
        }
        let unit_level = level_e_arcsec2 * det / self.flux_e;
        self.kind.profile().radius_density_below(unit_level) * self.map.max_stretch()
    }
}

/// A galaxy: the sum of its components about a common centre.
#[derive(Debug, Clone, PartialEq)]
pub struct Galaxy {
    /// FITS pixel x of the centre.
    pub x: f64,
    /// FITS pixel y of the centre.
    pub y: f64,
    /// Components with non-zero flux (bulge first).
    pub components: Vec<Component>,
}

impl Galaxy {
    /// Checks a row and builds its galaxy (see the module docs for the
    /// geometry). Stars are refused here: they are drawn as the PSF.
    pub fn from_row(row: &TruthRow) -> Result<Self, RowError> {
        check_row(row)?;
        if row.is_star() {
            return Err(RowError {
                id: row.id,
                column: "kind",
                value: f64::from(row.kind),
                reason: "a star has no galaxy profile",
            });
        }
        let pa = row.pa_deg.to_radians();
        let mut components = Vec::with_capacity(2);
        let fb = row.bt * row.flux_e;
        let fd = (1.0 - row.bt) * row.flux_e;
        if fb > 0.0 {
            components.push(Component::new(
                ProfileKind::DeVaucouleurs,
                fb,
                row.bulge_re_arcsec,
                row.bulge_ba,
                pa,
                row.g1,
                row.g2,
            ));
        }
        if fd > 0.0 {
            components.push(Component::new(
                ProfileKind::Exponential,
                fd,
                row.disk_h_arcsec,
                row.disk_ba,
                pa,
                row.g1,
                row.g2,
            ));
        }
        Ok(Self {
            x: row.x,
            y: row.y,
            components,
        })
    }

    /// Total flux in electrons.
    pub fn flux_e(&self) -> f64 {
        self.components.iter().map(|c| c.flux_e).sum()
    }

    /// Centred transform at (u, v) cycles per arcsec (electrons).
    pub fn transform(&self, u: f64, v: f64) -> f64 {
        self.components.iter().map(|c| c.transform(u, v)).sum()
    }

    /// Surface brightness (e⁻/arcsec²) at offset (dx, dy) arcsec.
    pub fn density(&self, dx: f64, dy: f64) -> f64 {
        self.components.iter().map(|c| c.density(dx, dy)).sum()
    }

    /// Flux-weighted unweighted second moments (xx, xy, yy), arcsec², per
    /// unit flux, of the untruncated profiles (the SPEC §5 truth definition).
    pub fn moments(&self) -> [f64; 3] {
        let f = self.flux_e();
        let mut q = [0.0; 3];
        for c in &self.components {
            let m = c.moments();
            for i in 0..3 {
                q[i] += c.flux_e / f * m[i];
            }
        }
        q
    }

    /// Eq. 1 ellipticity of [`Self::moments`].
    pub fn ellipticity(&self) -> (f64, f64) {
        ellipticity_of_moments(self.moments())
    }
}

/// Checks every column the renderer reads.
pub fn check_row(row: &TruthRow) -> Result<(), RowError> {
    let bad = |column, value, reason| {
        Err(RowError {
            id: row.id,
            column,
            value,
            reason,
        })
    };
    if row.kind != stepsim_contract::truth::KIND_STAR
        && row.kind != stepsim_contract::truth::KIND_GALAXY
    {
        return bad(
            "kind",
            f64::from(row.kind),
            "must be 0 (star) or 1 (galaxy)",
        );
    }
    for (column, value) in [("x", row.x), ("y", row.y)] {
        if !value.is_finite() || value.abs() > 1e9 {
            return bad(column, value, "must be a finite pixel coordinate");
        }
    }
    if !(row.flux_e.is_finite() && row.flux_e >= 0.0) {
        return bad("flux_e", row.flux_e, "must be finite and >= 0");
    }
    if row.is_star() {
        return Ok(());
    }
    if !(0.0..=1.0).contains(&row.bt) {
        return bad("bt", row.bt, "must be in [0, 1]");
    }
    for (column, value) in [
        ("bulge_re_arcsec", row.bulge_re_arcsec),
        ("disk_h_arcsec", row.disk_h_arcsec),
    ] {
        if !(value.is_finite() && (0.0..=3600.0).contains(&value)) {
            return bad(column, value, "must be in [0, 3600] arcsec");
        }
    }
    for (column, value) in [("bulge_ba", row.bulge_ba), ("disk_ba", row.disk_ba)] {
        if !(value > 0.0 && value <= 1.0) {
            return bad(column, value, "axis ratio must be in (0, 1]");
        }
    }
    if !row.pa_deg.is_finite() {
        return bad("pa_deg", row.pa_deg, "must be finite");
    }
    for (column, value) in [("g1", row.g1), ("g2", row.g2)] {
        if !value.is_finite() {
            return bad(column, value, "must be finite");
        }
    }
    if row.g1.hypot(row.g2) >= 1.0 {
        return bad("g1", row.g1.hypot(row.g2), "|g| must be < 1");
    }
    Ok(())
}

/// The squared radial frequency a u² + 2 b u v + c v² that a component's
/// profile sees at (u, v), from the Gram matrix [a, b, c] of its map
/// ([`LinearMap::gram`]); the renderer's fills evaluate it in this order.
#[inline(always)]
pub(crate) fn gram_k2([a, b, c]: [f64; 3], u: f64, v: f64) -> f64 {
    a * u * u + 2.0 * b * u * v + c * v * v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::profile::shear_ellipticity;

    fn row(bt: f64, g1: f64, g2: f64) -> TruthRow {
        TruthRow {
            id: 7,
            kind: 1,
            x: 10.0,
            y: 20.0,
            flux_e: 1000.0,
            bt,
            bulge_re_arcsec: 0.4,
            bulge_ba: 0.8,
            disk_h_arcsec: 0.5,
            disk_ba: 0.3,
            pa_deg: 30.0,
            g1,
            g2,
            ..TruthRow::default()
        }
    }

    #[test]
    fn whole_galaxy_moments_obey_eq8_exactly() {
        for bt in [0.0, 0.3, 1.0] {
            let e_int = Galaxy::from_row(&row(bt, 0.0, 0.0)).unwrap().ellipticity();
            let g = (0.1, -0.04);
            let e = Galaxy::from_row(&row(bt, g.0, g.1)).unwrap().ellipticity();
            let want = shear_ellipticity(e_int, g);
            assert!((e.0 - want.0).abs() < 1e-13 && (e.1 - want.1).abs() < 1e-13);
        }
        // Disk alone: eq. 1 with β = 0.3, θ = 30°.
        let e = Galaxy::from_row(&row(0.0, 0.0, 0.0)).unwrap().ellipticity();
        let m = 0.7 / 1.3;
        assert!((e.0 - m * 60f64.to_radians().cos()).abs() < 1e-14);
    }

    #[test]
    fn bad_rows_are_refused_with_the_column() {
        let mut r = row(0.5, 0.0, 0.0);
        r.disk_ba = 0.0;
        assert_eq!(Galaxy::from_row(&r).unwrap_err().column, "disk_ba");
        let mut r = row(0.5, 0.0, 0.0);
        r.flux_e = f64::NAN;
        assert_eq!(check_row(&r).unwrap_err().column, "flux_e");
        let mut r = row(0.5, 0.8, 0.8);
        r.id = 99;
        let e = check_row(&r).unwrap_err();
        assert!(e.to_string().contains("id 99"), "{e}");
        let mut r = row(1.5, 0.0, 0.0);
        r.kind = 1;
        assert_eq!(check_row(&r).unwrap_err().column, "bt");
    }
}
