//! Sky, photon noise, read noise, gain and saturation: from a noise-free model
//! in electrons to the pixel values of a FITS image in ADU (SPEC §4).
//!
//! For each pixel with noise-free, sky-free model value `m` (electrons over
//! the exposure):
//!
//! ```text
//! λ    = max(m + sky, 0)                      expected electrons
//! e    = Poisson(λ) + Normal(0, read_noise)   exact Poisson, any λ
//! adu  = min(e / gain, saturation_adu)
//! ```
//!
//! and without noise (`output.noise = false`) `adu = min(λ / gain, saturation_adu)`.
//! The sky level per pixel is `mag_to_electrons(sky_mag_arcsec2) × p²` for
//! pixel scale `p` (the sky stays in the image, as in STEP1). Negative model
//! values (ringing of a Fourier renderer) are clamped so that λ ≥ 0.
//!
//! Reproducibility: the image is cut into blocks of [`BLOCK_ROWS`] rows; block
//! `b` draws from its own generator keyed by [`block_key`]`(key, b)`, so the
//! bytes never depend on the number of threads. [`realise_slow`] is the
//! slow, obvious sequential twin (one pixel at a time, a fresh distribution
//! per pixel) that the fast [`realise`] is tested against, bit for bit.
//!
//! Measured statistics are in `docs/noise.md`.

use rand::RngExt;
use rand_distr::{Distribution, Exp1, Normal, Poisson, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use stepsim_contract::seed::{SeedKey, SimRng};

/// Rows per noise block (each block has its own generator). Part of the
/// on-disk contract: changing it changes every noisy image.
pub const BLOCK_ROWS: usize = 64;

/// Sky, exposure and detector (SPEC §4 defaults); the config's
/// `instrument` section, spelled as here.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Instrument {
    /// Sky surface brightness, I band, Vega (STEP1: 19.2 mag arcsec⁻²).
    pub sky_mag_arcsec2: f64,
    /// Magnitude giving 1 e⁻/s.
    pub zeropoint_mag: f64,
    /// Exposure time.
    pub exposure_s: f64,
    /// Electrons per ADU.
    pub gain_e_per_adu: f64,
    /// Gaussian read noise, electrons rms.
    pub read_noise_e: f64,
    /// Pixel values are clipped here (ADU) and SATURATE is written.
    pub saturation_adu: f64,
}

impl Default for Instrument {
    fn default() -> Self {
        Self {
            sky_mag_arcsec2: 19.2,
            zeropoint_mag: 26.0,
            exposure_s: 3600.0,
            gain_e_per_adu: 4.0,
            read_noise_e: 5.0,
            saturation_adu: 65535.0,
        }
    }
}

impl Instrument {
    /// Effective zeropoint: m = zp_eff − 2.5 log10(electrons) (SPEC §1).
    pub fn zp_eff(&self) -> f64 {
        self.zeropoint_mag + 2.5 * self.exposure_s.log10()
    }

    /// Total electrons of a source of magnitude `mag`.
    pub fn mag_to_electrons(&self, mag: f64) -> f64 {
        10f64.powf(-0.4 * (mag - self.zp_eff()))
    }

    /// Magnitude of a source with `electrons` in total.
    pub fn electrons_to_mag(&self, electrons: f64) -> f64 {
        self.zp_eff() - 2.5 * electrons.log10()
    }
}

/// The detector and sky seen by one image, in electrons and ADU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detector {
    /// Sky level per pixel, electrons over the exposure.
    pub sky_e_per_px: f64,
    /// Electrons per ADU.
    pub gain_e_per_adu: f64,
    /// Gaussian read noise, electrons rms.
    pub read_noise_e: f64,
    /// Clip level in ADU.
    pub saturation_adu: f64,
}

impl Detector {
    /// The detector of `instrument` at pixel scale `pixel_scale_arcsec`.
    pub fn new(instrument: &Instrument, pixel_scale_arcsec: f64) -> Self {
        Self {
            sky_e_per_px: sky_e_per_pixel(instrument, pixel_scale_arcsec),
            gain_e_per_adu: instrument.gain_e_per_adu,
            read_noise_e: instrument.read_noise_e,
            saturation_adu: instrument.saturation_adu,
        }
    }

    /// Noise σ of an empty sky pixel in electrons: sqrt(sky + read_noise²).
    pub fn sky_sigma_e(&self) -> f64 {
        (self.sky_e_per_px + self.read_noise_e * self.read_noise_e).sqrt()
    }

    /// Expected value of a pixel in ADU before clipping: (m + sky) / gain.
    pub fn expected_adu(&self, model_e: f32) -> f64 {
        expected_e(model_e, self.sky_e_per_px) / self.gain_e_per_adu
    }
}

/// Sky electrons per pixel: the sky surface brightness converted with the
/// instrument's effective zeropoint, times the pixel area in arcsec².
pub fn sky_e_per_pixel(instrument: &Instrument, pixel_scale_arcsec: f64) -> f64 {
    instrument.mag_to_electrons(instrument.sky_mag_arcsec2)
        * pixel_scale_arcsec
        * pixel_scale_arcsec
}

/// Key of the generator of noise block `block` of the image keyed by `key`:
/// the sub-stream index is `(key.index << 32) | block`, so that an image can
/// use `key.index` to tell apart two images of the same field and dataset
/// (e.g. the 90°-rotated twin uses index 1).
pub fn block_key(key: SeedKey, block: usize) -> SeedKey {
    key.with_index((key.index << 32) | block as u64)
}

fn expected_e(model_e: f32, sky_e: f64) -> f64 {
    (f64::from(model_e) + sky_e).max(0.0)
}

fn to_adu(e: f64, det: &Detector) -> f32 {
    (e / det.gain_e_per_adu).min(det.saturation_adu) as f32
}

/// Turns a noise-free, sky-free model (electrons, row-major, `width` pixels
/// per row) into the pixel values of the image in ADU: sky added, then photon
/// and read noise drawn when `noise` holds a key (none: noise-free image with
/// sky), divided by the gain and clipped at saturation. Parallel over blocks
/// of [`BLOCK_ROWS`] rows; the result does not depend on the thread count.
pub fn realise(model_e: &[f32], width: usize, det: &Detector, noise: Option<SeedKey>) -> Vec<f32> {
    let mut out = model_e.to_vec();
    realise_in_place(&mut out, width, det, noise);
    out
}

/// [`realise`] into the model's own buffer: each model value is replaced by
/// its pixel value (the same bits; one image-sized buffer fewer).
pub fn realise_in_place(pixels: &mut [f32], width: usize, det: &Detector, noise: Option<SeedKey>) {
    assert!(
        width > 0 && pixels.len() % width == 0,
        "model length {} is not a multiple of width {width}",
        pixels.len()
    );
    let chunk = BLOCK_ROWS * width;
    pixels
        .par_chunks_mut(chunk)
        .enumerate()
        .for_each(|(block, values)| match noise {
            None => {
                for v in values.iter_mut() {
                    *v = to_adu(expected_e(*v, det.sky_e_per_px), det);
                }
            }
            Some(key) => noisy_block(values, det, &mut block_key(key, block).rng()),
        });
}

/// Fast path of one block: the same draws as [`realise_slow`] (a
/// Poisson of the pixel's mean, then read noise as σ × a standard normal)
/// without its fresh `Normal` per pixel. No Poisson distribution is kept
/// from pixel to pixel: galaxy light covers a STEP1 image, so the mean
/// almost never repeats, and keeping the last one cost 7 % of the stage.
fn noisy_block(values: &mut [f32], det: &Detector, rng: &mut SimRng) {
    #[cfg(target_arch = "x86_64")]
    if stepsim_numerics::simd::has_avx2() {
        // SAFETY: the CPU runs AVX2 (checked just above).
        return unsafe { noisy_block_avx2(values, det, rng) };
    }
    noisy_block_body(values, det, rng);
}

/// [`noisy_block_body`] built for AVX2, where `floor` is one instruction
/// instead of a library call (same bits; `stepsim_numerics::simd`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn noisy_block_avx2(values: &mut [f32], det: &Detector, rng: &mut SimRng) {
    noisy_block_body(values, det, rng);
}

#[inline(always)]
fn noisy_block_body(values: &mut [f32], det: &Detector, rng: &mut SimRng) {
    let ron = det.read_noise_e;
    for d in values.iter_mut() {
        let lambda = expected_e(*d, det.sky_e_per_px);
        let mut e = if lambda > 0.0 {
            poisson_count(lambda, rng)
        } else {
            0.0
        };
        if ron > 0.0 {
            let n: f64 = rng.sample(StandardNormal);
            e += ron * n;
        }
        *d = to_adu(e, det);
    }
}

fn poisson(lambda: f64) -> Poisson<f64> {
    // λ is finite and > 0 here; beyond MAX_LAMBDA (1.8e19 e⁻, far above any
    // saturation level) the count is clipped anyway.
    Poisson::new(lambda.min(Poisson::<f64>::MAX_LAMBDA)).expect("0 < λ ≤ MAX_LAMBDA")
}

/// A Poisson(λ) count, λ > 0: the same draws and the same bits as
/// `rng.sample(Poisson::new(λ))` of rand_distr 0.6, at about 0.6 of its
/// cost (docs/noise.md, "Speed").
///
/// For λ ≥ 12 rand_distr uses the method of Ahrens & Dieter (1982, ACM TOMS
/// 8, 163), "PD": a normal deviate g ~ N(λ, λ) gives the candidate ⌊g⌋,
/// which is accepted at once when it is not below ⌊λ − 1.1484⌋ (step I, about
/// half the draws) or after one uniform u when 6λ² u ≥ (λ − k)³ (step S,
/// nearly all the rest at the sky's λ ≈ 80 000); only the few left over need
/// the comparison with the Poisson probabilities (steps F and E). Building a
/// `Poisson` sets up all of these steps for every pixel's λ, about ten
/// divisions, square roots and products, although the first two steps use
/// only √λ, ⌊λ − 1.1484⌋ and 6λ². Here those are all that is computed before
/// the first two steps; the rest ([`pd_tail`]) is set up only when reached.
/// Every operation is the one rand_distr does, in its order, so the results
/// are bit for bit its results (tested, [`realise_slow`] keeps using
/// rand_distr itself). Below λ = 12 rand_distr's own sampler is used.
#[inline(always)]
fn poisson_count(lambda: f64, rng: &mut SimRng) -> f64 {
    if !(12.0..=Poisson::<f64>::MAX_LAMBDA).contains(&lambda) {
        return rng.sample(poisson(lambda));
    }
    let s = lambda.sqrt();
    // Step N: g = λ + s z, as `Normal::new(λ, s)` draws it.
    let z: f64 = rng.sample(StandardNormal);
    let g = lambda + s * z;
    let mut u = None;
    if g >= 0.0 {
        let k = g.floor();
        // Step I.
        if k >= (lambda - 1.1484).floor() {
            return k;
        }
        // Step S.
        let uniform: f64 = rng.random();
        if 6.0 * lambda.powi(2) * uniform >= (lambda - k).powi(3) {
            return k;
        }
        u = Some((k, uniform));
    }
    pd_tail(lambda, s, u, rng)
}

/// Steps F (for the candidate `k` of step N and its uniform, when there is
/// one) and E of Ahrens & Dieter's PD for λ ≥ 12, with √λ = `s`: what
/// [`poisson_count`] leaves to the rare pixels that get past steps I and S.
#[cold]
#[inline(never)]
fn pd_tail(lambda: f64, s: f64, candidate: Option<(f64, f64)>, rng: &mut SimRng) -> f64 {
    #[cfg(test)]
    tests::PD_TAILS.with(|n| n.set(n.get() + 1));
    let pd = PdTail::new(lambda, s);
    if let Some((k, u)) = candidate {
        let (px, py, fx, fy) = pd.f(k);
        if fy * (1.0 - u) <= py * (px - fx).exp() {
            return k;
        }
    }
    loop {
        let e: f64 = rng.sample(Exp1);
        let u: f64 = rng.random::<f64>() * 2.0 - 1.0;
        let t = 1.8 + e * u.signum();
        if t > -0.6744 {
            let k = (lambda + s * t).floor();
            let (px, py, fx, fy) = pd.f(k);
            // Step H.
            if pd.c * u.abs() <= py * (px + e).exp() - fy * (fx + e).exp() {
                return k;
            }
        }
    }
}

/// The constants of steps F and E for one λ (Ahrens & Dieter 1982, their
/// notation): the coefficients c₀…c₃ of the normal density's correction,
/// ω = 1 / √(2πλ) and c = 0.1069 / λ.
struct PdTail {
    lambda: f64,
    s: f64,
    c: f64,
    c0: f64,
    c1: f64,
    c2: f64,
    c3: f64,
    omega: f64,
}

impl PdTail {
    fn new(lambda: f64, s: f64) -> Self {
        let b1 = (1.0 / 24.0) / lambda;
        let b2 = 0.3 * b1 * b1;
        let c3 = (1.0 / 7.0) * b1 * b2;
        let c2 = b2 - 15.0 * c3;
        let c1 = b1 - 6.0 * b2 + 45.0 * c3;
        let c0 = 1.0 - b1 + 3.0 * b2 - 15.0 * c3;
        Self {
            lambda,
            s,
            c: 0.1069 / lambda,
            c0,
            c1,
            c2,
            c3,
            omega: 1.0 / (2.0 * PI).sqrt() / lambda.sqrt(),
        }
    }

    /// Step F: (p_x, p_y, f_x, f_y), the log of the Poisson probability of
    /// `k` split as p_y e^{p_x}, and the corrected normal density at `k` as
    /// f_y e^{f_x}.
    fn f(&self, k: f64) -> (f64, f64, f64, f64) {
        /// 0! … 9!.
        const FACTORIAL: [f64; 10] = [
            1.0, 1.0, 2.0, 6.0, 24.0, 120.0, 720.0, 5040.0, 40320.0, 362880.0,
        ];
        /// The coefficients a₀…a₉ of Ahrens & Dieter's Table 1.
        const A: [f64; 10] = [
            -0.5000000002,
            0.3333333343,
            -0.2499998565,
            0.1999997049,
            -0.1666848753,
            0.1428833286,
            -0.1241963125,
            0.1101687109,
            -0.1142650302,
            0.1055093006,
        ];
        let lambda = self.lambda;
        let (px, py) = if k < 10.0 {
            (-lambda, lambda.powf(k) / FACTORIAL[k as usize])
        } else {
            let delta = (12.0 * k).recip();
            let delta = delta - 4.8 * delta.powi(3);
            let v = (lambda - k) / k;
            let px = if v.abs() <= 0.25 {
                k * v.powi(2) * A.iter().rev().fold(0.0, |sum, &a| sum * v + a) - delta
            } else {
                k * (1.0 + v).ln() - (lambda - k) - delta
            };
            (px, 1.0 / (2.0 * PI).sqrt() / k.sqrt())
        };
        let x = (k - lambda + 0.5) / self.s;
        let fx = -0.5 * x * x;
        let fy = self.omega * (((self.c3 * x * x + self.c2) * x * x + self.c1) * x * x + self.c0);
        (px, py, fx, fy)
    }
}

/// The slow, obvious twin of [`realise`]: one thread, blocks in order, pixels
/// in order, a fresh Poisson and Normal distribution for every pixel. Kept as
/// the reference that [`realise`] must match bit for bit.
pub fn realise_slow(
    model_e: &[f32],
    width: usize,
    det: &Detector,
    noise: Option<SeedKey>,
) -> Vec<f32> {
    let mut out = Vec::with_capacity(model_e.len());
    for (block, src) in model_e.chunks(BLOCK_ROWS * width).enumerate() {
        let mut rng = noise.map(|k| block_key(k, block).rng());
        for &m in src {
            let lambda = (f64::from(m) + det.sky_e_per_px).max(0.0);
            let e = match rng.as_mut() {
                None => lambda,
                Some(rng) => {
                    let photons = if lambda > 0.0 {
                        Poisson::new(lambda).unwrap().sample(rng)
                    } else {
                        0.0
                    };
                    let read = if det.read_noise_e > 0.0 {
                        Normal::new(0.0, det.read_noise_e).unwrap().sample(rng)
                    } else {
                        0.0
                    };
                    photons + read
                }
            };
            out.push((e / det.gain_e_per_adu).min(det.saturation_adu) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use stepsim_contract::seed::Stream;

    fn key() -> SeedKey {
        SeedKey::image(7, 1, 2, Stream::Noise)
    }

    fn det(sky: f64, gain: f64, ron: f64) -> Detector {
        Detector {
            sky_e_per_px: sky,
            gain_e_per_adu: gain,
            read_noise_e: ron,
            saturation_adu: 65535.0,
        }
    }

    fn moments(x: &[f32]) -> (f64, f64, f64) {
        let n = x.len() as f64;
        let mean = x.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let m2 = x
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        let m3 = x
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(3))
            .sum::<f64>()
            / n;
        (mean, m2, m3)
    }

    #[test]
    fn step1_sky_level() {
        // 19.2 mag/arcsec² with zp_eff = 26 + 2.5 log10(3600): 10^(0.4 (34.890756 − 19.2))
        // = 1.88929e6 e⁻/arcsec², times 0.206² = 0.042436 arcsec² → 80 174.6 e⁻/px.
        let d = Detector::new(&Instrument::default(), 0.206);
        let want = 10f64.powf(0.4 * (26.0 + 2.5 * 3600f64.log10() - 19.2)) * 0.206 * 0.206;
        assert!((d.sky_e_per_px - want).abs() < 1e-6 * want);
        assert!(
            (d.sky_e_per_px - 80_138.0).abs() < 50.0,
            "{}",
            d.sky_e_per_px
        );
        assert!((d.sky_sigma_e() - (d.sky_e_per_px + 25.0).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn sky_only_mean_and_variance_match_poisson_plus_read_noise() {
        // 512² pixels: the relative standard error of the variance is
        // sqrt(2/262144) = 0.28%, so the 1% tolerance is > 3.5σ.
        let (w, h) = (512, 512);
        let model = vec![0f32; w * h];
        for (sky, gain, ron) in [(80_174.6, 4.0, 5.0), (30.0, 2.0, 5.0), (400.0, 1.5, 12.0)] {
            let d = det(sky, gain, ron);
            let img = realise(&model, w, &d, Some(key()));
            let (mean, var, _) = moments(&img);
            let want_mean = sky / gain;
            let want_var = sky / (gain * gain) + (ron / gain).powi(2);
            eprintln!(
                "sky {sky} e, gain {gain}, RON {ron}: mean/expected − 1 = {:+.5}, var/expected − 1 = {:+.5}",
                mean / want_mean - 1.0,
                var / want_var - 1.0
            );
            assert!(
                (mean / want_mean - 1.0).abs() < 0.01,
                "sky {sky}: mean {mean} vs {want_mean}"
            );
            assert!(
                (var / want_var - 1.0).abs() < 0.01,
                "sky {sky}: variance {var} vs {want_var}"
            );
        }
    }

    #[test]
    fn faint_level_follows_poisson_not_gaussian_statistics() {
        // λ = 2 e⁻, gain 1, no read noise: counts are non-negative integers
        // with P(k) = e^−2 2^k / k! and all central moments up to 3 equal to λ.
        let (w, h) = (512, 512);
        let model = vec![0f32; w * h];
        let img = realise(&model, w, &det(2.0, 1.0, 0.0), Some(key()));
        assert!(img.iter().all(|&v| v >= 0.0 && v.fract() == 0.0));
        let n = img.len() as f64;
        let mut p_want = (-2f64).exp();
        for k in 0..5 {
            let p = img.iter().filter(|&&v| v == k as f32).count() as f64 / n;
            eprintln!("P({k}) = {p:.5}, Poisson {p_want:.5}");
            // standard error ≤ sqrt(0.25/262144) = 0.001
            assert!((p - p_want).abs() < 0.004, "P({k}) = {p}, want {p_want}");
            p_want *= 2.0 / f64::from(k + 1);
        }
        let (mean, var, m3) = moments(&img);
        eprintln!("λ = 2: mean {mean:.5}, variance {var:.5}, third central moment {m3:.4}");
        assert!((mean - 2.0).abs() < 0.01, "{mean}");
        assert!((var / 2.0 - 1.0).abs() < 0.02, "{var}");
        // Third central moment = λ for Poisson, 0 for a Gaussian; standard
        // error here ≈ 0.06 (3%), tolerance 15%.
        assert!((m3 / 2.0 - 1.0).abs() < 0.15, "{m3}");
    }

    #[test]
    fn saturation_clips_exactly() {
        let mut d = det(100.0, 4.0, 5.0);
        d.saturation_adu = 1000.0;
        let mut model = vec![0f32; 64 * 3];
        model[5] = 1e9;
        model[100] = 3900.0; // 4000 e⁻ expected = 1000 ADU: clipped about half the time
        for noise in [None, Some(key())] {
            let img = realise(&model, 64, &d, noise);
            assert_eq!(img[5], 1000.0);
            assert!(img.iter().all(|&v| v <= 1000.0));
        }
    }

    #[test]
    fn noise_free_mode_is_model_plus_sky_over_gain() {
        let d = det(80.0, 4.0, 5.0);
        let model: Vec<f32> = (0..200).map(|i| i as f32 * 3.5 - 100.0).collect();
        let img = realise(&model, 20, &d, None);
        for (i, &v) in img.iter().enumerate() {
            let want = ((f64::from(model[i]) + 80.0).max(0.0) / 4.0) as f32;
            assert_eq!(v, want, "pixel {i}");
            assert_eq!(f64::from(v), f64::from(d.expected_adu(model[i]) as f32));
        }
    }

    thread_local! {
        /// Calls of [`pd_tail`] (steps F and E) on this thread, to show a
        /// test reached them.
        pub(super) static PD_TAILS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    #[test]
    fn poisson_count_draws_what_rand_distr_draws_bit_for_bit() {
        // From below the switch at λ = 12 (where steps F and E run for a
        // large share of the draws) through the sky's λ ≈ 80 000 to λ far
        // above saturation and beyond rand_distr's MAX_LAMBDA.
        let mut lambdas = vec![0.3, 11.999, 12.0, 1e25];
        lambdas.extend((0..400).map(|i| 12.0 + 0.0731 * f64::from(i)));
        lambdas.extend((0..50).map(|i| 80_174.6 + 3.7 * f64::from(i)));
        lambdas.extend([1e6, 3.3e9, 1e15]);
        let before = PD_TAILS.with(std::cell::Cell::get);
        let mut rng_a = key().rng();
        let mut rng_b = key().rng();
        let mut draws = 0;
        for &lambda in &lambdas {
            for _ in 0..200 {
                let want: f64 = rng_a.sample(poisson(lambda));
                let got = poisson_count(lambda, &mut rng_b);
                assert_eq!(got.to_bits(), want.to_bits(), "λ = {lambda}");
                draws += 1;
            }
        }
        // The two generators are still in step.
        assert_eq!(rng_a.random::<u64>(), rng_b.random::<u64>());
        let tails = PD_TAILS.with(std::cell::Cell::get) - before;
        eprintln!("{draws} draws, {tails} through steps F/E");
        assert!(tails > 1000, "only {tails} draws reached steps F and E");
    }

    #[test]
    fn fast_matches_reference_bit_for_bit_at_any_thread_count() {
        // Objects of all brightnesses (varying λ, including λ ≤ 0) over 3.5 blocks.
        let (w, h) = (50, BLOCK_ROWS * 3 + 32);
        let model: Vec<f32> = (0..w * h)
            .map(|i| match i % 7 {
                0 => 0.0,
                1 => 5e4 * ((i % 13) as f32),
                2 => -500.0,
                _ => (i % 97) as f32 * 0.25,
            })
            .collect();
        let d = det(60.0, 3.0, 4.0);
        for noise in [None, Some(key())] {
            let want = realise_slow(&model, w, &d, noise);
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| realise(&model, w, &d, noise));
                assert!(
                    got.iter()
                        .zip(&want)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "threads {threads}"
                );
                let mut in_place = model.clone();
                pool.install(|| realise_in_place(&mut in_place, w, &d, noise));
                assert!(
                    in_place
                        .iter()
                        .zip(&want)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "in place, threads {threads}"
                );
            }
        }
        // The plain build of a block (the dispatched one above is the AVX2
        // build where the CPU has it).
        let mut plain = model[..BLOCK_ROWS * w].to_vec();
        noisy_block_body(&mut plain, &d, &mut block_key(key(), 0).rng());
        let want = realise_slow(&model, w, &d, Some(key()));
        assert!(
            plain
                .iter()
                .zip(&want)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        // A different image key gives different noise.
        let a = realise(&model, w, &d, Some(key()));
        let b = realise(&model, w, &d, Some(key().with_index(1)));
        assert_ne!(a, b);
    }
}
