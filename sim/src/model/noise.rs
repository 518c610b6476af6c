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
//! bytes never depend on the number of threads. Within a block, four
//! generators seeded from it (the lanes, `draws`) serve the pixels in turn:
//! pixel p of the block draws from lane p mod 4, so that four neighbouring
//! pixels are drawn side by side (`noisy_group`). What one pixel draws is
//! `noisy_pixel`; [`realise_slow`] is the slow, obvious sequential twin
//! (one pixel at a time) that the fast [`realise`] is tested against, bit
//! for bit.
//!
//! Measured statistics are in `docs/noise.md`.

#[cfg(target_arch = "x86_64")]
mod avx2;
mod draws;

use draws::{LANES, Lanes, Source};
use rand_distr::Poisson;
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

/// One noise block: its lanes from the block's keyed generator, then the
/// pixels four at a time ([`noisy_group`]), the last few one at a time.
fn noisy_block(values: &mut [f32], det: &Detector, block: &mut SimRng) {
    let mut lanes = Lanes::from_block(block);
    #[cfg(target_arch = "x86_64")]
    if stepsim_numerics::simd::has_avx2() {
        // SAFETY: the CPU runs AVX2 (checked just above).
        return unsafe { avx2::noisy_block(values, det, &mut lanes) };
    }
    noisy_block_body(values, det, &mut lanes);
}

#[inline(always)]
fn noisy_block_body(values: &mut [f32], det: &Detector, lanes: &mut Lanes) {
    let mut groups = values.chunks_exact_mut(LANES);
    for group in &mut groups {
        noisy_group(group.try_into().expect("LANES values"), det, lanes);
    }
    for (l, v) in groups.into_remainder().iter_mut().enumerate() {
        *v = noisy_pixel(*v, det, &mut lanes.lane(l));
    }
}

/// Four neighbouring pixels, pixel l drawing from lane l: the same draws and
/// bits as [`noisy_pixel`] on each lane, with the common path (a normal from
/// the ziggurat's inner rectangles, steps I and S of PD, the read noise) done
/// for the four lanes at once. A lane that leaves the common path (a
/// ziggurat's wedge or tail, PD's steps F and E) finishes its draw alone,
/// from its own generator, so every lane sees the order of [`noisy_pixel`].
#[inline(always)]
fn noisy_group(v: &mut [f32; LANES], det: &Detector, lanes: &mut Lanes) {
    let lam: [f64; LANES] = std::array::from_fn(|l| expected_e(v[l], det.sky_e_per_px));
    if !lam.iter().all(|&x| (PD_MIN..=MAX_LAMBDA).contains(&x)) {
        for (l, x) in v.iter_mut().enumerate() {
            *x = noisy_pixel(*x, det, &mut lanes.lane(l));
        }
        return;
    }
    let z = group_normal(lanes);
    let mut s = [0.0; LANES];
    let mut g = [0.0; LANES];
    let mut k = [0.0; LANES];
    let mut take = [false; LANES];
    let mut need_u = [false; LANES];
    for l in 0..LANES {
        s[l] = lam[l].sqrt();
        g[l] = lam[l] + s[l] * z[l];
        k[l] = g[l].floor();
        take[l] = g[l] >= 0.0 && step_i(lam[l], k[l]);
        need_u[l] = g[l] >= 0.0 && !take[l];
    }
    let mut e = k;
    if !take.iter().all(|&t| t) {
        let bits = lanes.next_where(need_u);
        for l in 0..LANES {
            if take[l] {
                continue;
            }
            let candidate = need_u[l].then(|| (k[l], draws::uniform_of(bits[l])));
            e[l] = match candidate {
                Some((k, u)) if step_s(lam[l], k, u) => k,
                _ => pd_tail(lam[l], s[l], candidate, &mut lanes.lane(l)),
            };
        }
    }
    let ron = det.read_noise_e;
    if ron > 0.0 {
        let r = group_normal(lanes);
        for l in 0..LANES {
            e[l] += ron * r[l];
        }
    }
    for l in 0..LANES {
        v[l] = to_adu(e[l], det);
    }
}

/// A standard normal on each lane ([`draws::normal`], four at once).
#[inline(always)]
fn group_normal(lanes: &mut Lanes) -> [f64; LANES] {
    let table = draws::ziggurat();
    let bits = lanes.next_all();
    let mut z = [0.0; LANES];
    let mut inside = [false; LANES];
    for l in 0..LANES {
        let (i, negative, u) = draws::split(bits[l]);
        let x = u * table.x[i];
        inside[l] = x < table.x[i + 1];
        z[l] = draws::signed(x, negative);
    }
    if !inside.iter().all(|&t| t) {
        for l in 0..LANES {
            if !inside[l] {
                z[l] = draws::finish_normal(bits[l], &mut lanes.lane(l));
            }
        }
    }
    z
}

/// Smallest mean drawn by PD; below it [`draws::small_poisson`].
const PD_MIN: f64 = 12.0;

/// Means above this are drawn as this (1.8e19 e⁻, far above any saturation
/// level; rand_distr's bound for its Poisson).
const MAX_LAMBDA: f64 = Poisson::<f64>::MAX_LAMBDA;

/// PD's step I: the candidate ⌊g⌋ is taken at once.
#[inline(always)]
fn step_i(lambda: f64, k: f64) -> bool {
    k >= (lambda - 1.1484).floor()
}

/// PD's step S: the candidate is taken after its uniform `u`.
#[inline(always)]
fn step_s(lambda: f64, k: f64, u: f64) -> bool {
    let d = lambda - k;
    6.0 * (lambda * lambda) * u >= d * d * d
}

/// One pixel of model value `m` from generator `src`: what every pixel
/// draws (output version 6), written one step at a time.
///
/// - λ = max(m + sky, 0); λ ≤ 0 gives 0 e⁻ and no draw.
/// - 0 < λ < 12: Knuth's product of uniforms ([`draws::small_poisson`]).
/// - λ ≥ 12 (at most [`MAX_LAMBDA`]): Ahrens & Dieter's method PD (1982,
///   ACM TOMS 8, 163): a standard normal z ([`draws::normal`]) gives
///   g = λ + √λ z; when g ≥ 0 the candidate k = ⌊g⌋ is taken if
///   k ≥ ⌊λ − 1.1484⌋ (step I, about half the draws), else after one
///   uniform u if 6λ² u ≥ (λ − k)³ (step S); the rest go through steps F
///   and E ([`pd_tail`]).
/// - Read noise: `read_noise_e` × a standard normal, when it is > 0.
/// - ADU: min(e / gain, saturation).
fn noisy_pixel(m: f32, det: &Detector, src: &mut impl Source) -> f32 {
    let lambda = expected_e(m, det.sky_e_per_px);
    let mut e = if lambda <= 0.0 {
        0.0
    } else if lambda < PD_MIN {
        draws::small_poisson(lambda, src)
    } else {
        let lambda = lambda.min(MAX_LAMBDA);
        let s = lambda.sqrt();
        let g = lambda + s * draws::normal(src);
        if g >= 0.0 {
            let k = g.floor();
            if step_i(lambda, k) {
                k
            } else {
                let u = draws::uniform(src);
                if step_s(lambda, k, u) {
                    k
                } else {
                    pd_tail(lambda, s, Some((k, u)), src)
                }
            }
        } else {
            pd_tail(lambda, s, None, src)
        }
    };
    if det.read_noise_e > 0.0 {
        e += det.read_noise_e * draws::normal(src);
    }
    to_adu(e, det)
}

/// Steps F (for the candidate `k` of step N and its uniform, when there is
/// one) and E of Ahrens & Dieter's PD for λ ≥ 12, with √λ = `s`: what
/// [`noisy_pixel`] leaves to the rare pixels that get past steps I and S.
#[cold]
#[inline(never)]
fn pd_tail(lambda: f64, s: f64, candidate: Option<(f64, f64)>, src: &mut impl Source) -> f64 {
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
        let e = draws::exponential(src);
        let u = draws::uniform(src) * 2.0 - 1.0;
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

/// The slow, obvious twin of [`realise`]: one thread, blocks in order,
/// pixels in order, each drawn by `noisy_pixel` from its lane (pixel p of
/// a block from lane p mod 4). Kept as the reference that [`realise`] must
/// match bit for bit.
pub fn realise_slow(
    model_e: &[f32],
    width: usize,
    det: &Detector,
    noise: Option<SeedKey>,
) -> Vec<f32> {
    let mut out = Vec::with_capacity(model_e.len());
    for (block, src) in model_e.chunks(BLOCK_ROWS * width).enumerate() {
        let mut lanes = noise.map(|k| Lanes::from_block(&mut block_key(k, block).rng()));
        for (p, &m) in src.iter().enumerate() {
            out.push(match lanes.as_mut() {
                None => to_adu(expected_e(m, det.sky_e_per_px), det),
                Some(lanes) => noisy_pixel(m, det, &mut lanes.lane(p % LANES)),
            });
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

    /// χ² of `n` counts of mean `lambda` drawn by `draw` against the
    /// Poisson probabilities, over the bins expecting ≥ 20 counts (the tails
    /// pooled into the outermost bins); returns (χ², degrees of freedom).
    fn poisson_chi2(lambda: f64, n: usize, mut draw: impl FnMut() -> f64) -> (f64, usize) {
        let centre = lambda.floor() as i64;
        let width = (12.0 * lambda.sqrt()).ceil() as i64 + 12;
        let lo = (centre - width).max(0);
        let mut counts = vec![0u64; (2 * width + 1) as usize];
        for _ in 0..n {
            let k = draw();
            assert!(k >= 0.0 && k.fract() == 0.0, "λ {lambda}: count {k}");
            let i = (k as i64 - lo).clamp(0, counts.len() as i64 - 1);
            counts[i as usize] += 1;
        }
        // ln P(k) by Stirling's series for ln k! (exact enough at k ≥ 10)
        // and by the product below it.
        let ln_fact = |k: i64| -> f64 {
            if k < 10 {
                (1..=k).map(|j| (j as f64).ln()).sum()
            } else {
                let x = k as f64;
                x * x.ln() - x + 0.5 * (2.0 * PI * x).ln() + 1.0 / (12.0 * x)
                    - 1.0 / (360.0 * x.powi(3))
            }
        };
        let p = |k: i64| (k as f64 * lambda.ln() - lambda - ln_fact(k)).exp();
        // Neighbouring counts pooled until a bin expects ≥ 20; what is left
        // at the top joins the last bin.
        let mut bins: Vec<(f64, u64)> = Vec::new();
        let mut open = (0.0, 0u64);
        for (i, &c) in counts.iter().enumerate() {
            open = (open.0 + n as f64 * p(lo + i as i64), open.1 + c);
            if open.0 >= 20.0 {
                bins.push(open);
                open = (0.0, 0);
            }
        }
        if let Some(last) = bins.last_mut() {
            *last = (last.0 + open.0, last.1 + open.1);
        }
        let chi2 = bins.iter().map(|&(e, c)| (c as f64 - e).powi(2) / e).sum();
        let dof = bins.len();
        (chi2, dof.saturating_sub(1))
    }

    #[test]
    fn pd_counts_follow_the_poisson_probabilities() {
        // From the switch at λ = 12 (where steps F and E run for a large
        // share of the draws) through the sky's λ ≈ 80 000, and the small-λ
        // method just below the switch.
        let before = PD_TAILS.with(std::cell::Cell::get);
        let mut g = Lanes::from_block(&mut key().rng());
        let zero_sky = Detector {
            saturation_adu: 1e30,
            ..det(0.0, 1.0, 0.0)
        };
        for (lambda, n) in [
            (0.4, 200_000),
            (11.99, 200_000),
            (12.0, 200_000),
            (15.3, 200_000),
            (80_174.6, 400_000),
            (1e6, 200_000),
        ] {
            let mut i = 0;
            let (chi2, dof) = poisson_chi2(lambda, n, || {
                i += 1;
                f64::from(noisy_pixel(
                    lambda as f32,
                    &zero_sky,
                    &mut g.lane(i % LANES),
                ))
            });
            eprintln!("λ {lambda}: χ² {chi2:.1} for {dof} degrees of freedom");
            assert!(dof >= 3, "λ {lambda}: {dof} bins");
            let bound = dof as f64 + 5.0 * (2.0 * dof as f64).sqrt();
            assert!(
                chi2 < bound,
                "λ {lambda}: χ² {chi2:.1} for {dof} degrees of freedom"
            );
        }
        let tails = PD_TAILS.with(std::cell::Cell::get) - before;
        eprintln!("{tails} draws through steps F/E");
        assert!(tails > 1000, "only {tails} draws reached steps F and E");
        // Means beyond the bound are drawn at the bound.
        let huge = noisy_pixel(1e30, &zero_sky, &mut g.lane(0));
        assert!((f64::from(huge) / MAX_LAMBDA - 1.0).abs() < 1e-6, "{huge}");
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
        // Blocks whose groups of four lie wholly in PD's range (the AVX2
        // build's vector path), near its lower end (steps S, F and E often),
        // at the sky's level with and without read noise, and mixed with
        // means below 12; each by the plain build of a block and by the
        // dispatched one (the AVX2 build where the CPU has it).
        let (rw, rh) = (37, BLOCK_ROWS + 5);
        let ramp: Vec<f32> = (0..rw * rh).map(|i| (i % 101) as f32 * 0.37).collect();
        for dr in [
            det(12.0, 1.0, 0.0),
            det(13.5, 2.0, 3.0),
            det(80_174.6, 4.0, 5.0),
            det(80_174.6, 4.0, 0.0),
            det(8.0, 1.5, 2.0),
        ] {
            let want = realise_slow(&ramp, rw, &dr, Some(key()));
            let got = realise(&ramp, rw, &dr, Some(key()));
            assert!(
                got.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "dispatched build, sky {}",
                dr.sky_e_per_px
            );
            for (block, values) in ramp.chunks(BLOCK_ROWS * rw).enumerate() {
                let mut plain = values.to_vec();
                noisy_block_body(
                    &mut plain,
                    &dr,
                    &mut Lanes::from_block(&mut block_key(key(), block).rng()),
                );
                let first = block * BLOCK_ROWS * rw;
                assert!(
                    plain
                        .iter()
                        .zip(&want[first..])
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "plain build, sky {}, block {block}",
                    dr.sky_e_per_px
                );
            }
        }
        // A different image key gives different noise.
        let a = realise(&model, w, &d, Some(key()));
        let b = realise(&model, w, &d, Some(key().with_index(1)));
        assert_ne!(a, b);
    }
}
