//! Synthetic scenes for the reference pipeline's tests and benchmark: a
//! reference drawing of elliptical Gaussians (never used on real data; slow
//! and obvious on purpose), a STEP-like scene of them, and its public half
//! written to disk.
//!
//! Shapes follow SPEC §1: an elliptical Gaussian of geometric-mean width σ
//! and ellipticity e (eq. 1 type, |e| = (1−β)/(1+β)) has covariance
//! C = σ² A_e⁻², where A_e is the shear matrix of
//! [`stepsim_contract::shear::shear_matrix`] at g = e (it maps the ellipse
//! onto a circle); a shear g maps C to A_g⁻¹ C A_g⁻ᵀ. Both take A⁻¹ from
//! [`stepsim_contract::shear::inverse_shear_matrix`].
//!
//! The file names the pipeline's crate as `stepsim_ksb`: ksb's own unit
//! tests compile it in by `#[path]` (with `extern crate self as
//! stepsim_ksb`), so that it draws into that crate's own [`Image`].

use rand::RngExt;
use stepsim_contract::seed::SeedKey;
use stepsim_contract::shear::inverse_shear_matrix;
use stepsim_ksb::{Image, KsbError, Mat2};

/// The product `a b` of two 2 × 2 matrices (the pipeline's own product is
/// internal to it; a fixture does not reach into the pipeline's insides).
fn mul(a: &Mat2, b: &Mat2) -> Mat2 {
    let mut m = [[0.0; 2]; 2];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j];
        }
    }
    m
}

/// Covariance (pixels²) of an elliptical Gaussian of geometric-mean σ (px)
/// and eq. 1 ellipticity `e`.
pub fn covariance(sigma: f64, e: [f64; 2]) -> Mat2 {
    let ainv = inverse_shear_matrix(e[0], e[1]);
    let m = mul(&ainv, &ainv);
    [
        [sigma * sigma * m[0][0], sigma * sigma * m[0][1]],
        [sigma * sigma * m[1][0], sigma * sigma * m[1][1]],
    ]
}

/// The covariance of the object sheared by reduced shear `g` (SPEC §1).
pub fn shear_covariance(cov: &Mat2, g: [f64; 2]) -> Mat2 {
    let ainv = inverse_shear_matrix(g[0], g[1]);
    mul(&mul(&ainv, cov), &ainv)
}

/// Sum of two covariances (convolution of two Gaussians).
pub fn convolve(a: &Mat2, b: &Mat2) -> Mat2 {
    [
        [a[0][0] + b[0][0], a[0][1] + b[0][1]],
        [a[1][0] + b[1][0], a[1][1] + b[1][1]],
    ]
}

/// The Gaussian density of covariance `cov` and flux `flux` at offset (dx, dy).
pub fn gaussian_value(flux: f64, cov: &Mat2, dx: f64, dy: f64) -> f64 {
    let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    let q = (cov[1][1] * dx * dx - 2.0 * cov[0][1] * dx * dy + cov[0][0] * dy * dy) / det;
    flux / (2.0 * std::f64::consts::PI * det.sqrt()) * (-0.5 * q).exp()
}

fn stamp_radius(cov: &Mat2) -> f64 {
    let tr = cov[0][0] + cov[1][1];
    let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    let lmax = 0.5 * tr + (0.25 * tr * tr - det).max(0.0).sqrt();
    7.0 * lmax.sqrt() + 2.0
}

/// Adds the Gaussian point-sampled at pixel centres (array coordinates).
pub fn draw_gaussian_sampled(img: &mut Image, x: f64, y: f64, flux: f64, cov: &Mat2) {
    draw_with(img, x, y, cov, |dx, dy| gaussian_value(flux, cov, dx, dy));
}

/// Adds the Gaussian integrated over each pixel (5 × 5-point Gauss–Legendre
/// quadrature per pixel: relative error below 1e-9 for σ ≥ 1 px).
pub fn draw_gaussian_integrated(img: &mut Image, x: f64, y: f64, flux: f64, cov: &Mat2) {
    const NODES: [f64; 5] = [
        -0.906_179_845_938_664,
        -0.538_469_310_105_683,
        0.0,
        0.538_469_310_105_683,
        0.906_179_845_938_664,
    ];
    const WEIGHTS: [f64; 5] = [
        0.236_926_885_056_189,
        0.478_628_670_499_366,
        0.568_888_888_888_889,
        0.478_628_670_499_366,
        0.236_926_885_056_189,
    ];
    draw_with(img, x, y, cov, |dx, dy| {
        let mut s = 0.0;
        for (u, wu) in NODES.iter().zip(WEIGHTS) {
            for (v, wv) in NODES.iter().zip(WEIGHTS) {
                s += wu * wv * gaussian_value(flux, cov, dx + 0.5 * u, dy + 0.5 * v);
            }
        }
        0.25 * s
    });
}

fn draw_with(img: &mut Image, x: f64, y: f64, cov: &Mat2, f: impl Fn(f64, f64) -> f64) {
    let r = stamp_radius(cov);
    let x0 = (x - r).floor().max(0.0) as usize;
    let y0 = (y - r).floor().max(0.0) as usize;
    let x1 = ((x + r).ceil()).min(img.width as f64 - 1.0);
    let y1 = ((y + r).ceil()).min(img.height as f64 - 1.0);
    if x1 < 0.0 || y1 < 0.0 {
        return;
    }
    for iy in y0..=y1 as usize {
        for ix in x0..=x1 as usize {
            *img.at_mut(ix, iy) += f(ix as f64 - x, iy as f64 - y) as f32;
        }
    }
}

/// Adds sky and noise in electrons: each pixel becomes
/// value + sky + N(0, sky + max(value, 0) + read²) — the Gaussian limit of
/// photon noise, adequate for synthetic test images (the simulator itself
/// draws exact Poisson deviates). Rows are drawn from generators keyed by
/// `key.with_index(row)`, so the result does not depend on threads.
pub fn add_sky_and_noise(img: &mut Image, sky_e: f64, read_noise_e: f64, key: SeedKey) {
    let w = img.width;
    for (iy, row) in img.data.chunks_mut(w).enumerate() {
        let mut rng = key.with_index(iy as u64).rng();
        for v in row {
            let var = sky_e + f64::from(*v).max(0.0) + read_noise_e * read_noise_e;
            let n: f64 = rng.sample(rand_distr::StandardNormal);
            *v = (f64::from(*v) + sky_e + var.sqrt() * n) as f32;
        }
    }
}

/// Uniform random number in `[lo, hi)` (helper for synthetic scenes).
pub fn uniform(rng: &mut stepsim_contract::seed::SimRng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covariance_has_the_axis_ratio_of_eq1_and_shear_composes_by_eq8() {
        let c = covariance(2.0, [0.3, 0.0]);
        let beta = (c[1][1] / c[0][0]).sqrt();
        assert!(((1.0 - beta) / (1.0 + beta) - 0.3).abs() < 1e-12);
        assert!((c[0][0] * c[1][1] - c[0][1] * c[1][0] - 16.0).abs() < 1e-9);
        // A round source sheared by g has e = g (eq. 8 with e_s = 0).
        let s = shear_covariance(&covariance(2.0, [0.0, 0.0]), [0.05, -0.02]);
        let (a, b, cc) = (s[0][0], s[1][1], s[0][1]);
        let chi = [(a - b) / (a + b), 2.0 * cc / (a + b)];
        let chi2 = chi[0] * chi[0] + chi[1] * chi[1];
        let f = 1.0 / (1.0 + (1.0 - chi2).sqrt()); // e = χ / (1 + sqrt(1 − χ²))
        assert!((chi[0] * f - 0.05).abs() < 1e-12 && (chi[1] * f + 0.02).abs() < 1e-12);
    }

    #[test]
    fn integrated_drawing_conserves_flux_and_adds_the_pixel_variance() {
        let cov = covariance(1.5, [0.2, 0.1]);
        let mut img = Image::zeros(40, 40);
        draw_gaussian_integrated(&mut img, 20.3, 19.6, 100.0, &cov);
        let (mut s, mut sxx) = (0.0, 0.0);
        for iy in 0..40 {
            for ix in 0..40 {
                let v = f64::from(img.at(ix, iy));
                s += v;
                sxx += v * (ix as f64 - 20.3).powi(2);
            }
        }
        assert!((s - 100.0).abs() < 1e-4, "{s}");
        // Box pixel adds 1/12 px² of variance.
        assert!(
            (sxx / s - (cov[0][0] + 1.0 / 12.0)).abs() < 1e-5,
            "{}",
            sxx / s
        );
    }
}

/// A synthetic STEP-like scene for tests and the benchmark: Gaussian
/// galaxies and Gaussian stars through one Gaussian PSF, point-sampled,
/// with sky and noise.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    /// NAXIS1.
    pub width: usize,
    /// NAXIS2.
    pub height: usize,
    /// Number of galaxy *pairs*: each galaxy also appears rotated by 90°
    /// elsewhere on the image (shape noise cancels in the mean).
    pub n_galaxy_pairs: usize,
    /// Number of stars.
    pub n_stars: usize,
    /// PSF covariance (pixels²).
    pub psf: Mat2,
    /// Optional PSF halo: this fraction of every object's flux is drawn
    /// through this second (wider) PSF covariance instead, giving the PSF
    /// non-Gaussian wings.
    pub psf_halo: Option<(f64, Mat2)>,
    /// Reduced shear applied to the galaxies.
    pub shear: [f64; 2],
    /// Galaxy intrinsic σ range (pixels, log-uniform).
    pub galaxy_sigma_px: (f64, f64),
    /// Galaxy flux range (electrons, log-uniform).
    pub galaxy_flux_e: (f64, f64),
    /// Star flux range (electrons); counts rise by 10^0.3 per magnitude.
    pub star_flux_e: (f64, f64),
    /// Rms of each intrinsic ellipticity component (clipped at |e| < 0.7).
    pub sigma_e: f64,
    /// Sky per pixel (electrons).
    pub sky_e: f64,
    /// Read noise (electrons).
    pub read_noise_e: f64,
    /// Seed of every draw.
    pub seed: u64,
}

impl SceneSpec {
    /// A 1024² STEP-like scene: 0.9″ PSF at 0.206″/px (σ 1.856 px) with
    /// ellipticity `psf_e`, sky 80 000 e⁻, read noise 5 e⁻, 250 galaxy
    /// pairs I ≈ 20–24.5 (σ 1–4 px, σ_e 0.25) and 150 stars I ≈ 17–25.
    /// Tests and benchmarks change size and counts with struct update syntax.
    pub fn step_like(shear: [f64; 2], psf_e: [f64; 2], seed: u64) -> Self {
        Self {
            width: 1024,
            height: 1024,
            n_galaxy_pairs: 250,
            n_stars: 150,
            psf: covariance(4.37 / 2.3548, psf_e),
            psf_halo: None,
            shear,
            galaxy_sigma_px: (1.0, 4.0),
            galaxy_flux_e: (1.5e4, 1e6),
            star_flux_e: (1.4e4, 1.4e7),
            sigma_e: 0.25,
            sky_e: 80_000.0,
            read_noise_e: 5.0,
            seed,
        }
    }
}

/// One object of a synthetic scene (array coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneObject {
    /// Centre x.
    pub x: f64,
    /// Centre y.
    pub y: f64,
    /// Flux (electrons).
    pub flux_e: f64,
    /// Covariance after shear and PSF.
    pub cov: Mat2,
    /// A star.
    pub is_star: bool,
}

/// Draws the scene: returns its objects and the image (electrons, sky in).
pub fn synthetic_scene(spec: &SceneSpec) -> (Vec<SceneObject>, Image) {
    use stepsim_contract::seed::Stream;
    let mut rng = SeedKey::base(spec.seed, 0, Stream::Test).rng();
    let (w, h) = (spec.width as f64, spec.height as f64);
    let mut objects = Vec::new();
    for _ in 0..spec.n_galaxy_pairs {
        let sigma = uniform(
            &mut rng,
            spec.galaxy_sigma_px.0.ln(),
            spec.galaxy_sigma_px.1.ln(),
        )
        .exp();
        let flux = uniform(
            &mut rng,
            spec.galaxy_flux_e.0.ln(),
            spec.galaxy_flux_e.1.ln(),
        )
        .exp();
        let e = loop {
            let e1: f64 = spec.sigma_e * rng.sample::<f64, _>(rand_distr::StandardNormal);
            let e2: f64 = spec.sigma_e * rng.sample::<f64, _>(rand_distr::StandardNormal);
            if e1.hypot(e2) < 0.7 {
                break [e1, e2];
            }
        };
        for rot in [e, [-e[0], -e[1]]] {
            let cov = convolve(
                &shear_covariance(&covariance(sigma, rot), spec.shear),
                &spec.psf,
            );
            objects.push(SceneObject {
                x: uniform(&mut rng, -5.0, w + 5.0),
                y: uniform(&mut rng, -5.0, h + 5.0),
                flux_e: flux,
                cov,
                is_star: false,
            });
        }
    }
    // Star fluxes with dN/dm ∝ 10^(0.3 m): flux^(−0.75) per ln flux.
    let (a, b) = (
        spec.star_flux_e.0.powf(-0.75),
        spec.star_flux_e.1.powf(-0.75),
    );
    for _ in 0..spec.n_stars {
        let flux = uniform(&mut rng, b, a).powf(-1.0 / 0.75);
        objects.push(SceneObject {
            x: uniform(&mut rng, 0.0, w),
            y: uniform(&mut rng, 0.0, h),
            flux_e: flux,
            cov: spec.psf,
            is_star: true,
        });
    }
    let mut img = Image::zeros(spec.width, spec.height);
    for o in &objects {
        match spec.psf_halo {
            None => draw_gaussian_sampled(&mut img, o.x, o.y, o.flux_e, &o.cov),
            Some((f, halo)) => {
                // Intrinsic covariance = cov − psf; convolve it with each
                // PSF component.
                let intrinsic = [
                    [o.cov[0][0] - spec.psf[0][0], o.cov[0][1] - spec.psf[0][1]],
                    [o.cov[1][0] - spec.psf[1][0], o.cov[1][1] - spec.psf[1][1]],
                ];
                draw_gaussian_sampled(&mut img, o.x, o.y, (1.0 - f) * o.flux_e, &o.cov);
                draw_gaussian_sampled(
                    &mut img,
                    o.x,
                    o.y,
                    f * o.flux_e,
                    &convolve(&intrinsic, &halo),
                );
            }
        }
    }
    add_sky_and_noise(
        &mut img,
        spec.sky_e,
        spec.read_noise_e,
        SeedKey::base(spec.seed, 1, Stream::Test),
    );
    (objects, img)
}

/// Writes a public half for tests and benchmarks: `dir/manifest.json` and one
/// FITS image per `(dataset id, image id, image in electrons)`, stored in ADU
/// at gain 4 under `<dataset>/<image>.fits`, with the STEP1 instrument facts
/// (0.206″ pixels, read noise 5 e⁻, saturation 65535 ADU, 3600 s, zeropoint
/// 26) and the size of the first image. Checksums are left empty.
pub fn write_public_run(
    dir: &std::path::Path,
    images: &[(&str, &str, &Image)],
) -> Result<(), KsbError> {
    use stepsim_contract::run_dir::PublicDir;
    use stepsim_contract::run_layout::{InstrumentFacts, MANIFEST_FORMAT, Manifest, ManifestImage};
    let gain: f64 = 4.0;
    let public = PublicDir::new(dir);
    let mut entries = Vec::new();
    for (dataset, id, img) in images {
        let file = PublicDir::image_file(dataset, id);
        stepsim_ksb::write_fits_image(
            &public.file(&file),
            &(*img).clone().scaled((1.0 / gain) as f32),
        )?;
        entries.push(ManifestImage {
            image: (*id).into(),
            dataset: (*dataset).into(),
            file,
            sha256: String::new(),
        });
    }
    let (width, height) = images
        .first()
        .map_or((0, 0), |(_, _, i)| (i.width, i.height));
    let manifest = Manifest {
        format: MANIFEST_FORMAT.into(),
        instrument: InstrumentFacts {
            width_px: width as u32,
            height_px: height as u32,
            pixel_scale_arcsec: 0.206,
            gain_e_per_adu: gain,
            read_noise_e: 5.0,
            saturation_adu: 65535.0,
            exposure_s: 3600.0,
            zeropoint_mag: 26.0,
        },
        images: entries,
    };
    let text = serde_json::to_string_pretty(&manifest).expect("manifest serialises");
    stepsim_contract::io::write_bytes_atomically(&public.manifest(), text.as_bytes())?;
    Ok(())
}
