//! Galaxy light profiles, each in real space and in Fourier space.
//!
//! A profile file holds one circularly symmetric profile of **unit flux and
//! unit size** (scale length for the exponential, half-light radius for the
//! de Vaucouleurs law): its surface density f(r), its Hankel transform
//! f̃(k) = ∫ f(r) J₀(2πkr) 2πr dr (k in cycles per unit size, so f̃(0) = 1),
//! its enclosed flux and its second moment. Sizes, flattening, position
//! angle and shear are applied by the linear maps ([`LinearMap`]); a galaxy
//! is the [`Galaxy`] sum of such transformed components; convolution
//! with the PSF and the pixel is a product in Fourier space done by
//! [`crate::model::render`].
//!
//! Units: arcsec on the sky, cycles per arcsec in Fourier space, electrons.

mod devaucouleurs;
mod exponential;
mod galaxy;
pub mod sersic;
mod transform;

pub(crate) use devaucouleurs::GL8;
pub use devaucouleurs::{DeVaucouleurs, hankel_slow};
pub use exponential::Exponential;
pub(crate) use galaxy::gram_k2;
pub use galaxy::{Component, Galaxy, ProfileKind, RowError, check_row};
pub use transform::{LinearMap, ellipticity_of_moments, shear_ellipticity, shear_matrix};

/// A circularly symmetric profile of unit flux and unit size.
pub trait RadialProfile {
    /// Surface density f(r) per unit area (∫ f dA = 1).
    fn density(&self, r: f64) -> f64;
    /// Hankel transform f̃(k), k in cycles per unit length; f̃(0) = 1.
    fn transform(&self, k: f64) -> f64;
    /// Flux fraction inside radius `r`.
    fn enclosed(&self, r: f64) -> f64;
    /// ⟨r²⟩ = ∫ r² f dA of the untruncated profile (= Qxx + Qyy).
    fn mean_r2(&self) -> f64;

    /// Radius enclosing `fraction` of the flux (bisection on [`Self::enclosed`]).
    fn radius_enclosing(&self, fraction: f64) -> f64 {
        let fraction = fraction.clamp(0.0, 1.0 - 1e-15);
        monotone_root(|r| self.enclosed(r) >= fraction)
    }

    /// Smallest radius beyond which the density is below `level` (absolute,
    /// per unit area).
    fn radius_density_below(&self, level: f64) -> f64 {
        if self.density(0.0) <= level {
            return 0.0;
        }
        monotone_root(|r| self.density(r) <= level)
    }
}

/// Smallest r ≥ 0 (to 1e-12 relative) at which the monotone predicate
/// becomes true; r is searched up to 1e12.
pub(crate) fn monotone_root(pred: impl Fn(f64) -> bool) -> f64 {
    let mut hi = 1.0;
    while !pred(hi) && hi < 1e12 {
        hi *= 2.0;
    }
    stepsim_numerics::roots::Bisection::to_relative_width(1e-12)
        .run(0.0, hi, pred)
        .1
}
