//! The random draws of the noise (output version 6): four Xoshiro256++
//! generators per noise block, a standard normal by the ziggurat method,
//! uniforms, exponentials and small-mean Poisson counts, all written here so
//! that the four generators can advance side by side in vector registers.
//!
//! **Generators.** Block `b` of an image has the keyed generator of
//! [`super::block_key`]; its first sixteen outputs are the states of four
//! Xoshiro256++ generators, the *lanes* (outputs 4l … 4l + 3 are the words
//! s₀ … s₃ of lane l). Pixel p of the block (row-major within the block)
//! draws from lane p mod 4. [`Lanes`] holds the four states word-major
//! (`s[w][l]`), so that one step of all four is a handful of vector
//! instructions; a lane steps exactly as `rand_xoshiro::Xoshiro256PlusPlus`
//! does (tested against it).
//!
//! **Standard normal** (Marsaglia & Tsang 2000, *J. Stat. Softw.* 5(8)):
//! 256 layers of equal area under f(x) = e^{−x²/2}, the base layer holding
//! the tail beyond r = 3.654152885361009. One 64-bit draw gives the layer
//! (bits 0–7), the sign (bit 8) and a uniform u in [0, 1) (bits 12–63);
//! x = u X_i is taken when x < X_{i+1} (about 98.8 % of draws), otherwise
//! [`finish_normal`] tests the wedge against f(x) or draws from the tail
//! (Marsaglia 1964: x = −ln U₁ / r, y = −ln U₂ until 2y > x²) and starts
//! again with a fresh draw when the point is rejected. The method is exact
//! for the layers it builds; the tables are computed once with the `libm`
//! crate (the same bits on every machine).
//!
//! **Uniform**: the top 53 bits of one draw times 2⁻⁵³, in [0, 1).
//! **Exponential**: −ln(1 − U). **Poisson of a small mean** (0 < λ < 12):
//! the number of uniforms multiplied before the product (of 1 − U) falls
//! to e^{−λ} or below, less one (Knuth's method; at most a few dozen draws).

use std::f64::consts::PI;
use std::sync::OnceLock;

/// Generators per block, advancing side by side.
pub(crate) const LANES: usize = 4;

/// Start of the base layer's tail.
const R: f64 = 3.654_152_885_361_009;

/// Anything that hands out 64-bit draws: one lane of [`Lanes`].
pub(crate) trait Source {
    /// The next 64-bit draw.
    fn next_u64(&mut self) -> u64;
}

/// Four Xoshiro256++ states, word-major: `s[w][l]` is word w of lane l.
#[derive(Clone, Debug)]
pub(crate) struct Lanes {
    s: [[u64; LANES]; 4],
}

impl Lanes {
    /// The lanes of the block whose keyed generator is `block`: its first
    /// sixteen outputs, four words per lane.
    pub(crate) fn from_block(block: &mut impl rand::Rng) -> Self {
        let mut s = [[0; LANES]; 4];
        for l in 0..LANES {
            for word in &mut s {
                word[l] = block.next_u64();
            }
        }
        Self { s }
    }

    /// One step of every lane.
    #[inline(always)]
    pub(crate) fn next_all(&mut self) -> [u64; LANES] {
        std::array::from_fn(|l| step(&mut self.s, l))
    }

    /// One step of the lanes where `step` holds, the others unchanged; the
    /// outputs of the lanes that stepped.
    #[inline(always)]
    pub(crate) fn next_where(&mut self, step: [bool; LANES]) -> [u64; LANES] {
        let before = self.s;
        let out = self.next_all();
        for (word, old) in self.s.iter_mut().zip(&before) {
            for ((now, &was), &stepped) in word.iter_mut().zip(old).zip(&step) {
                if !stepped {
                    *now = was;
                }
            }
        }
        out
    }

    /// The states, word-major (`[w][l]`: word w of lane l).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn words(&self) -> &[[u64; LANES]; 4] {
        &self.s
    }

    /// The same, to be written.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn words_mut(&mut self) -> &mut [[u64; LANES]; 4] {
        &mut self.s
    }

    /// Lane `l` as a [`Source`] of its own.
    pub(crate) fn lane(&mut self, l: usize) -> Lane<'_> {
        Lane { lanes: self, l }
    }
}

/// One lane of [`Lanes`].
pub(crate) struct Lane<'a> {
    lanes: &'a mut Lanes,
    l: usize,
}

impl Source for Lane<'_> {
    #[inline]
    fn next_u64(&mut self) -> u64 {
        step(&mut self.lanes.s, self.l)
    }
}

/// One step of lane `l` of the word-major states `s`: its output
/// (Xoshiro256++: rotl(s₀ + s₃, 23) + s₀) and the state's transition.
#[inline(always)]
fn step(s: &mut [[u64; LANES]; 4], l: usize) -> u64 {
    let [s0, s1, s2, s3] = s;
    let out = s0[l]
        .wrapping_add(s3[l])
        .rotate_left(23)
        .wrapping_add(s0[l]);
    let t = s1[l] << 17;
    s2[l] ^= s0[l];
    s3[l] ^= s1[l];
    s1[l] ^= s2[l];
    s0[l] ^= s3[l];
    s2[l] ^= t;
    s3[l] = s3[l].rotate_left(45);
    out
}

/// The ziggurat's layers: `x[i]` the right edge of layer i (x₀ = v / f(r)
/// for the base layer, x₁ = r, …, x₂₅₆ = 0) and `f[i] = e^{−x[i]²/2}`.
pub(crate) struct Ziggurat {
    pub(crate) x: [f64; 257],
    pub(crate) f: [f64; 257],
}

/// The layers, computed on first use: v = r f(r) + √(π/2) erfc(r/√2) is the
/// area of each layer, and x_{i+1} = f⁻¹(f(x_i) + v / x_i).
pub(crate) fn ziggurat() -> &'static Ziggurat {
    static TABLES: OnceLock<Ziggurat> = OnceLock::new();
    TABLES.get_or_init(|| {
        let f = |x: f64| libm::exp(-0.5 * x * x);
        let v = R * f(R) + libm::sqrt(PI / 2.0) * libm::erfc(R / libm::sqrt(2.0));
        let mut x = [0.0; 257];
        x[0] = v / f(R);
        x[1] = R;
        for i in 1..255 {
            x[i + 1] = libm::sqrt(-2.0 * libm::log(v / x[i] + f(x[i])));
        }
        x[256] = 0.0;
        let mut fx = [0.0; 257];
        for i in 0..257 {
            fx[i] = f(x[i]);
        }
        Ziggurat { x, f: fx }
    })
}

/// Layer, sign and uniform of one 64-bit draw.
#[inline(always)]
pub(crate) fn split(bits: u64) -> (usize, bool, f64) {
    let u = f64::from_bits((bits >> 12) | 0x3ff0_0000_0000_0000) - 1.0;
    ((bits & 0xff) as usize, bits & 0x100 != 0, u)
}

/// `x` with the sign of the draw.
#[inline(always)]
pub(crate) fn signed(x: f64, negative: bool) -> f64 {
    if negative { -x } else { x }
}

/// A standard normal deviate from `src`.
#[inline]
pub(crate) fn normal(src: &mut impl Source) -> f64 {
    let z = ziggurat();
    let bits = src.next_u64();
    let (i, negative, u) = split(bits);
    let x = u * z.x[i];
    if x < z.x[i + 1] {
        signed(x, negative)
    } else {
        finish_normal(bits, src)
    }
}

/// The rest of a normal draw whose first 64 bits `bits` fell outside the
/// layers' inner rectangles: the wedge or the tail, then fresh draws until
/// one is taken.
#[cold]
#[inline(never)]
pub(crate) fn finish_normal(mut bits: u64, src: &mut impl Source) -> f64 {
    let z = ziggurat();
    loop {
        let (i, negative, u) = split(bits);
        let x = u * z.x[i];
        if x < z.x[i + 1] {
            return signed(x, negative);
        }
        if i == 0 {
            loop {
                let t = -libm::log(open_uniform(src)) / R;
                let y = -libm::log(open_uniform(src));
                if 2.0 * y > t * t {
                    return signed(R + t, negative);
                }
            }
        }
        let y = z.f[i] + uniform(src) * (z.f[i + 1] - z.f[i]);
        if y < libm::exp(-0.5 * x * x) {
            return signed(x, negative);
        }
        bits = src.next_u64();
    }
}

/// A uniform deviate in [0, 1) from one draw.
#[inline(always)]
pub(crate) fn uniform_of(bits: u64) -> f64 {
    (bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A uniform deviate in [0, 1).
#[inline]
pub(crate) fn uniform(src: &mut impl Source) -> f64 {
    uniform_of(src.next_u64())
}

/// A uniform deviate in (0, 1]: 1 − [`uniform`].
#[inline]
fn open_uniform(src: &mut impl Source) -> f64 {
    1.0 - uniform(src)
}

/// A standard exponential deviate, −ln(1 − U).
pub(crate) fn exponential(src: &mut impl Source) -> f64 {
    -libm::log(open_uniform(src))
}

/// A Poisson count of mean 0 < λ < 12 (Knuth's product of uniforms).
pub(crate) fn small_poisson(lambda: f64, src: &mut impl Source) -> f64 {
    let limit = libm::exp(-lambda);
    let mut k = 0.0;
    let mut p = open_uniform(src);
    while p > limit {
        k += 1.0;
        p *= open_uniform(src);
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use stepsim_contract::seed::SimRng;

    fn lanes(seed: u64) -> Lanes {
        Lanes::from_block(&mut SimRng::seed_from_u64(seed))
    }

    #[test]
    fn each_lane_is_the_xoshiro256plusplus_of_its_state() {
        let mut block = SimRng::seed_from_u64(11);
        let words: Vec<u64> = (0..16).map(|_| block.next_u64()).collect();
        let mut g = lanes(11);
        let mut twins: Vec<SimRng> = (0..LANES)
            .map(|l| {
                let mut seed = [0u8; 32];
                for (w, chunk) in seed.chunks_exact_mut(8).enumerate() {
                    chunk.copy_from_slice(&words[4 * l + w].to_le_bytes());
                }
                SimRng::from_seed(seed)
            })
            .collect();
        for step in 0..1000 {
            if step % 3 == 0 {
                let out = g.next_all();
                for l in 0..LANES {
                    assert_eq!(out[l], twins[l].next_u64(), "lane {l}, step {step}");
                }
            } else {
                let which = [step % 2 == 0, true, step % 5 == 0, false];
                let out = g.next_where(which);
                for l in 0..LANES {
                    if which[l] {
                        assert_eq!(out[l], twins[l].next_u64(), "lane {l}, step {step}");
                    }
                }
                let l = step % LANES;
                assert_eq!(g.lane(l).next_u64(), twins[l].next_u64());
            }
        }
    }

    #[test]
    fn the_layers_close_at_zero_with_equal_areas() {
        let z = ziggurat();
        let v = z.x[0] * z.f[1];
        // Each layer i ≥ 1 is the box [0, x_i] × [f(x_i), f(x_{i+1})].
        for i in 1..255 {
            let area = z.x[i] * (z.f[i + 1] - z.f[i]);
            assert!((area / v - 1.0).abs() < 1e-9, "layer {i}: {area} vs {v}");
        }
        // The top layer, [0, x₂₅₅] × [f(x₂₅₅), 1], closes the recursion.
        let top = z.x[255] * (1.0 - z.f[255]);
        assert!((top / v - 1.0).abs() < 1e-6, "top layer {top} vs {v}");
        assert!(z.x.windows(2).all(|w| w[0] > w[1]), "edges not decreasing");
        assert_eq!(z.x[1], R);
    }

    /// Φ, the standard normal distribution function.
    fn phi(x: f64) -> f64 {
        0.5 * libm::erfc(-x / 2f64.sqrt())
    }

    #[test]
    fn normal_deviates_follow_the_normal_distribution() {
        let mut g = lanes(3);
        let n = 2_000_000;
        let edges: Vec<f64> = (-16..=16).map(|k| f64::from(k) * 0.25).collect();
        let mut counts = vec![0u64; edges.len() + 1];
        let (mut s1, mut s2, mut s4) = (0.0, 0.0, 0.0);
        let mut beyond_r = 0u64;
        for i in 0..n {
            let x = normal(&mut g.lane(i % LANES));
            s1 += x;
            s2 += x * x;
            s4 += x * x * x * x;
            beyond_r += u64::from(x.abs() > R);
            counts[edges.partition_point(|&e| e <= x)] += 1;
        }
        let nf = n as f64;
        assert!(
            (s1 / nf).abs() < 5.0 * (1.0 / nf).sqrt(),
            "mean {}",
            s1 / nf
        );
        assert!(
            (s2 / nf - 1.0).abs() < 5.0 * (2.0 / nf).sqrt(),
            "variance {}",
            s2 / nf
        );
        assert!(
            (s4 / nf - 3.0).abs() < 5.0 * (96.0 / nf).sqrt(),
            "fourth moment {}",
            s4 / nf
        );
        let tail = 2.0 * (1.0 - phi(R));
        let expected = tail * nf;
        assert!(
            (beyond_r as f64 - expected).abs() < 5.0 * expected.sqrt(),
            "{beyond_r} beyond r, expected {expected:.0}"
        );
        // χ² over 34 bins (33 degrees of freedom: mean 33, σ ≈ 8.1).
        let mut chi2 = 0.0;
        for (b, &c) in counts.iter().enumerate() {
            let lo = if b == 0 {
                f64::NEG_INFINITY
            } else {
                edges[b - 1]
            };
            let hi = if b == edges.len() {
                f64::INFINITY
            } else {
                edges[b]
            };
            let p = phi(hi) - phi(lo);
            chi2 += (c as f64 - nf * p).powi(2) / (nf * p);
        }
        assert!(chi2 < 70.0, "χ² = {chi2:.1} over 34 bins");
    }

    #[test]
    fn small_poisson_and_exponential_follow_their_laws() {
        let mut g = lanes(5);
        let n = 400_000;
        for &lambda in &[0.4, 2.5, 11.9] {
            let mut counts = vec![0u64; 64];
            for i in 0..n {
                let k = small_poisson(lambda, &mut g.lane(i % LANES));
                assert_eq!(k.fract(), 0.0);
                counts[(k as usize).min(63)] += 1;
            }
            let mut chi2 = 0.0;
            let mut dof = 0;
            let mut p = libm::exp(-lambda);
            for (k, &c) in counts.iter().enumerate().take(40) {
                if k > 0 {
                    p *= lambda / k as f64;
                }
                let e = n as f64 * p;
                if e >= 20.0 {
                    chi2 += (c as f64 - e).powi(2) / e;
                    dof += 1;
                }
            }
            assert!(
                chi2 < dof as f64 + 6.0 * (2.0 * dof as f64).sqrt(),
                "λ {lambda}: χ² {chi2:.1}, {dof} bins"
            );
        }
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let e = exponential(&mut g.lane(i % LANES));
            assert!(e >= 0.0);
            s1 += e;
            s2 += e * e;
        }
        let nf = n as f64;
        assert!((s1 / nf - 1.0).abs() < 5.0 / nf.sqrt(), "mean {}", s1 / nf);
        assert!(
            (s2 / nf - 2.0).abs() < 5.0 * (20.0 / nf).sqrt(),
            "second moment {}",
            s2 / nf
        );
    }
}
