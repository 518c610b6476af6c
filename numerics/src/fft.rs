//! Fast Fourier transforms of eight sequences at once, with the same bits
//! on every CPU.
//!
//! A [`BatchFft`] transforms [`LANES`] sequences of one length side by
//! side: element k of the eight sequences is one [`Lanes`] value (eight
//! real parts, eight imaginary parts), and every operation acts on all
//! eight lanes alike. Each lane therefore goes through exactly the
//! arithmetic a one-sequence transform would do, in the same order: the
//! compiler may put the lanes in vector registers (two SSE2 registers, or
//! one AVX2 register for `f32`), but that changes how many lanes an
//! instruction handles, not what is computed. No fused multiply-add is ever
//! enabled (`stepsim_numerics::simd`), and Rust never reassociates
//! floating-point arithmetic, so the plain x86-64 build and the AVX2 build
//! give the same bits (tested), unlike an FFT library that picks other
//! algorithms, or fused instructions, by CPU.
//!
//! The algorithm is Stockham's self-sorting FFT (decimation in frequency,
//! ping-pong between the data and a scratch buffer, no bit reversal) with
//! butterflies of radix 4, 2, 3 and 5, so lengths of the form 2^a 3^b 5^c
//! ([`crate::fft_size`]). Stage s of length L (the part of the transform
//! left) and stride S (what is done, S·L = n) reads
//! x\[q + S(j + k·L/p)\] for k < p, takes their p-point DFT b_t and writes
//! b_t · w_L^{jt} to y\[q + S(p·j + t)\], w_L = e^{∓2πi/L}.
//!
//! [`RealFft`] turns a real sequence of even length n into its n/2 + 1
//! non-negative frequencies and back, by a complex transform of length n/2
//! (the even samples as real parts, the odd ones as imaginary parts).
//!
//! [`fft2`] transforms an n × n array, eight rows and then eight columns
//! at a time; [`transpose`] (and [`transpose_avx2`], the same moves by AVX
//! shuffles) turns eight rows of an array into lanes and back.
//!
//! Conventions are rustfft's and realfft's: forward e^{−2πi jk/n},
//! inverse e^{+2πi jk/n}, neither normalised (forward then inverse
//! multiplies by n). The slow twins are the direct sums [`dft_slow`],
//! [`real_dft_slow`] and [`fft2_slow`], in f64.

use std::f64::consts::PI;
use std::ops::{Add, Mul, Neg, Sub};

/// How many sequences a transform handles at once.
pub const LANES: usize = 8;

/// The float types the transforms run in (`f32` and `f64`).
pub trait Real:
    Copy
    + Default
    + PartialEq
    + std::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Neg<Output = Self>
    + Send
    + Sync
    + 'static
{
    /// The value nearest to `x`.
    fn from_f64_rounded(x: f64) -> Self;
}

impl Real for f32 {
    #[inline(always)]
    fn from_f64_rounded(x: f64) -> Self {
        x as f32
    }
}

impl Real for f64 {
    #[inline(always)]
    fn from_f64_rounded(x: f64) -> Self {
        x
    }
}

/// Element k of [`LANES`] complex sequences: `re[l] + i·im[l]` is lane l's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Lanes<T> {
    /// Real parts, one per lane.
    pub re: [T; LANES],
    /// Imaginary parts, one per lane.
    pub im: [T; LANES],
}

#[inline(always)]
fn map2<T: Real>(a: &[T; LANES], b: &[T; LANES], f: impl Fn(T, T) -> T) -> [T; LANES] {
    let mut o = *a;
    for l in 0..LANES {
        o[l] = f(a[l], b[l]);
    }
    o
}

impl<T: Real> Lanes<T> {
    /// All lanes zero.
    pub fn zero() -> Self {
        Self::default()
    }

    #[inline(always)]
    fn add(&self, b: &Self) -> Self {
        Self {
            re: map2(&self.re, &b.re, |x, y| x + y),
            im: map2(&self.im, &b.im, |x, y| x + y),
        }
    }

    #[inline(always)]
    fn sub(&self, b: &Self) -> Self {
        Self {
            re: map2(&self.re, &b.re, |x, y| x - y),
            im: map2(&self.im, &b.im, |x, y| x - y),
        }
    }

    /// The lanes times the real `c`.
    #[inline(always)]
    fn scale(&self, c: T) -> Self {
        let mut o = *self;
        for l in 0..LANES {
            o.re[l] = self.re[l] * c;
            o.im[l] = self.im[l] * c;
        }
        o
    }

    /// The lanes times i (`INV`) or −i (not `INV`).
    #[inline(always)]
    fn rot<const INV: bool>(&self) -> Self {
        let mut o = *self;
        for l in 0..LANES {
            (o.re[l], o.im[l]) = if INV {
                (-self.im[l], self.re[l])
            } else {
                (self.im[l], -self.re[l])
            };
        }
        o
    }

    /// The lanes times the complex `(wr, wi)`.
    #[inline(always)]
    fn twiddle(&self, (wr, wi): (T, T)) -> Self {
        let mut o = *self;
        for l in 0..LANES {
            o.re[l] = self.re[l] * wr - self.im[l] * wi;
            o.im[l] = self.re[l] * wi + self.im[l] * wr;
        }
        o
    }
}

/// One pass of the Stockham transform.
#[derive(Debug, Clone)]
struct Stage<T> {
    /// Radix (2, 3, 4 or 5).
    p: usize,
    /// Length of the part left (L).
    len: usize,
    /// Stride (S).
    stride: usize,
    /// w_L^{jt} for j < L/p and 1 ≤ t < p, j-major.
    twiddles: Vec<(T, T)>,
}

/// A planned transform of [`LANES`] complex sequences of one length.
#[derive(Debug, Clone)]
pub struct BatchFft<T> {
    n: usize,
    inverse: bool,
    stages: Vec<Stage<T>>,
}

/// The radices of n: fours, a two if needed, threes, fives (fours rather
/// than eights: sixteen registers hold the four inputs of a radix-4
/// butterfly, not the eight of a radix-8 one); `None` if n has a prime
/// factor above 5.
fn radices(mut n: usize) -> Option<Vec<usize>> {
    let mut out = Vec::new();
    while n % 4 == 0 {
        out.push(4);
        n /= 4;
    }
    for p in [2, 3, 5] {
        while n % p == 0 {
            out.push(p);
            n /= p;
        }
    }
    (n == 1).then_some(out)
}

/// e^{∓2πi k/n} (− forward, + inverse), rounded to T.
fn unit<T: Real>(k: usize, n: usize, inverse: bool) -> (T, T) {
    let a = 2.0 * PI * (k % n) as f64 / n as f64;
    let s = if inverse { a.sin() } else { -a.sin() };
    (T::from_f64_rounded(a.cos()), T::from_f64_rounded(s))
}

impl<T: Real> BatchFft<T> {
    /// A transform of length `n` (≥ 1, no prime factor above 5), forward
    /// (e^{−2πi jk/n}) or `inverse` (e^{+2πi jk/n}).
    ///
    /// # Panics
    /// If n is 0 or has a prime factor above 5 (the callers choose their
    /// lengths with [`crate::fft_size::fft_friendly`]).
    pub fn new(n: usize, inverse: bool) -> Self {
        assert!(n >= 1, "an FFT of length 0");
        let Some(ps) = radices(n) else {
            panic!("FFT length {n} has a prime factor above 5");
        };
        let (mut len, mut stride) = (n, 1);
        let mut stages = Vec::with_capacity(ps.len());
        for p in ps {
            let m = len / p;
            let mut twiddles = Vec::with_capacity(m * (p - 1));
            for j in 0..m {
                for t in 1..p {
                    twiddles.push(unit(j * t, len, inverse));
                }
            }
            stages.push(Stage {
                p,
                len,
                stride,
                twiddles,
            });
            len = m;
            stride *= p;
        }
        Self { n, inverse, stages }
    }

    /// The length.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether the length is 0 (never: kept for the convention).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Transforms `data` (length n) in place, using `scratch` (length n).
    ///
    /// Where the CPU runs AVX2 the same code runs built for it (the same
    /// bits, [`crate::simd`]).
    pub fn process(&self, data: &mut [Lanes<T>], scratch: &mut [Lanes<T>]) {
        assert!(
            data.len() == self.n && scratch.len() == self.n,
            "FFT buffers of the wrong length"
        );
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has_avx2() {
            // SAFETY: the CPU runs AVX2 (checked just above).
            return unsafe { self.process_avx2(data, scratch) };
        }
        self.process_body(data, scratch);
    }

    /// [`Self::process_body`] built for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn process_avx2(&self, data: &mut [Lanes<T>], scratch: &mut [Lanes<T>]) {
        self.process_body(data, scratch);
    }

    /// The body of [`Self::process`], in whichever build its caller has.
    #[inline(always)]
    fn process_body(&self, data: &mut [Lanes<T>], scratch: &mut [Lanes<T>]) {
        let mut in_data = true;
        for st in &self.stages {
            let (x, y): (&[Lanes<T>], &mut [Lanes<T>]) = if in_data {
                (&*data, &mut *scratch)
            } else {
                (&*scratch, &mut *data)
            };
            if self.inverse {
                stage::<T, true>(st, x, y);
            } else {
                stage::<T, false>(st, x, y);
            }
            in_data = !in_data;
        }
        if !in_data {
            data.copy_from_slice(scratch);
        }
    }
}

/// One Stockham pass from `x` into `y`.
#[inline(always)]
fn stage<T: Real, const INV: bool>(st: &Stage<T>, x: &[Lanes<T>], y: &mut [Lanes<T>]) {
    match st.p {
        2 => pass::<T, INV, 2, _>(st, x, y, Radix2),
        4 => pass::<T, INV, 4, _>(st, x, y, Radix4),
        3 => pass::<T, INV, 3, _>(st, x, y, Radix3::new()),
        5 => pass::<T, INV, 5, _>(st, x, y, Radix5::new()),
        p => unreachable!("radix {p}"),
    }
}

/// A P-point DFT of lanes (a butterfly).
trait Butterfly<T: Real, const P: usize> {
    /// b_t = Σ_k a_k e^{∓2πi kt/P} (+ when `INV`).
    fn dft<const INV: bool>(&self, a: &[Lanes<T>; P]) -> [Lanes<T>; P];
}

struct Radix2;
struct Radix4;
struct Radix3<T> {
    half: T,
    s: T,
}
struct Radix5<T> {
    c1: T,
    c2: T,
    s1: T,
    s2: T,
}

impl<T: Real> Radix3<T> {
    fn new() -> Self {
        Self {
            half: T::from_f64_rounded(0.5),
            s: T::from_f64_rounded((2.0 * PI / 3.0).sin()),
        }
    }
}

impl<T: Real> Radix5<T> {
    fn new() -> Self {
        Self {
            c1: T::from_f64_rounded((2.0 * PI / 5.0).cos()),
            c2: T::from_f64_rounded((4.0 * PI / 5.0).cos()),
            s1: T::from_f64_rounded((2.0 * PI / 5.0).sin()),
            s2: T::from_f64_rounded((4.0 * PI / 5.0).sin()),
        }
    }
}

impl<T: Real> Butterfly<T, 2> for Radix2 {
    #[inline(always)]
    fn dft<const INV: bool>(&self, a: &[Lanes<T>; 2]) -> [Lanes<T>; 2] {
        [a[0].add(&a[1]), a[0].sub(&a[1])]
    }
}

impl<T: Real> Butterfly<T, 4> for Radix4 {
    #[inline(always)]
    fn dft<const INV: bool>(&self, a: &[Lanes<T>; 4]) -> [Lanes<T>; 4] {
        let (t0, t1) = (a[0].add(&a[2]), a[0].sub(&a[2]));
        let (t2, t3) = (a[1].add(&a[3]), a[1].sub(&a[3]).rot::<INV>());
        [t0.add(&t2), t1.add(&t3), t0.sub(&t2), t1.sub(&t3)]
    }
}

impl<T: Real> Butterfly<T, 3> for Radix3<T> {
    #[inline(always)]
    fn dft<const INV: bool>(&self, a: &[Lanes<T>; 3]) -> [Lanes<T>; 3] {
        let (t, d) = (a[1].add(&a[2]), a[1].sub(&a[2]));
        let m = a[0].sub(&t.scale(self.half));
        let r = d.scale(self.s).rot::<INV>();
        [a[0].add(&t), m.add(&r), m.sub(&r)]
    }
}

impl<T: Real> Butterfly<T, 5> for Radix5<T> {
    #[inline(always)]
    fn dft<const INV: bool>(&self, a: &[Lanes<T>; 5]) -> [Lanes<T>; 5] {
        let (t1, d1) = (a[1].add(&a[4]), a[1].sub(&a[4]));
        let (t2, d2) = (a[2].add(&a[3]), a[2].sub(&a[3]));
        let b0 = a[0].add(&t1).add(&t2);
        let m1 = a[0].add(&t1.scale(self.c1)).add(&t2.scale(self.c2));
        let m2 = a[0].add(&t1.scale(self.c2)).add(&t2.scale(self.c1));
        let n1 = d1.scale(self.s1).add(&d2.scale(self.s2)).rot::<INV>();
        let n2 = d1.scale(self.s2).sub(&d2.scale(self.s1)).rot::<INV>();
        [b0, m1.add(&n1), m2.add(&n2), m2.sub(&n2), m1.sub(&n1)]
    }
}

/// The loops of one pass of radix `P`.
#[inline(always)]
fn pass<T: Real, const INV: bool, const P: usize, B: Butterfly<T, P>>(
    st: &Stage<T>,
    x: &[Lanes<T>],
    y: &mut [Lanes<T>],
    bf: B,
) {
    let (s, m) = (st.stride, st.len / P);
    let step = s * m;
    let xs: [&[Lanes<T>]; P] = std::array::from_fn(|k| &x[k * step..(k + 1) * step]);
    if s == 1 {
        // The first pass: one butterfly per j, no inner loop to set up.
        for (j, (out, w)) in y[..P * step]
            .chunks_exact_mut(P)
            .zip(st.twiddles.chunks_exact(P - 1))
            .enumerate()
        {
            let b = bf.dft::<INV>(&std::array::from_fn(|k| xs[k][j]));
            out[0] = b[0];
            for t in 1..P {
                out[t] = if j == 0 { b[t] } else { b[t].twiddle(w[t - 1]) };
            }
        }
        return;
    }
    for (j, out) in y[..P * step].chunks_exact_mut(P * s).enumerate() {
        let w = &st.twiddles[j * (P - 1)..(j + 1) * (P - 1)];
        let ins: [&[Lanes<T>]; P] = std::array::from_fn(|k| &xs[k][s * j..s * j + s]);
        let mut outs = out.chunks_exact_mut(s);
        let ys: [&mut [Lanes<T>]; P] = std::array::from_fn(|_| outs.next().expect("P chunks of s"));
        if j == 0 {
            for q in 0..s {
                let b = bf.dft::<INV>(&std::array::from_fn(|k| ins[k][q]));
                for t in 0..P {
                    ys[t][q] = b[t];
                }
            }
        } else {
            for q in 0..s {
                let b = bf.dft::<INV>(&std::array::from_fn(|k| ins[k][q]));
                ys[0][q] = b[0];
                for t in 1..P {
                    ys[t][q] = b[t].twiddle(w[t - 1]);
                }
            }
        }
    }
}

/// A planned real transform of [`LANES`] sequences of one even length n:
/// forward from n real values to the n/2 + 1 frequencies 0..=n/2, inverse
/// back (unnormalised: forward then inverse multiplies by n).
#[derive(Debug, Clone)]
pub struct RealFft<T> {
    n: usize,
    half: BatchFft<T>,
    /// e^{−2πi k/n} for k ≤ n/2 (forward) or its conjugate (inverse).
    w: Vec<(T, T)>,
}

impl<T: Real> RealFft<T> {
    /// A real transform of even length `n` ≥ 2 (n/2 with no prime factor
    /// above 5), forward or `inverse`.
    ///
    /// # Panics
    /// If n is odd or 0, or n/2 has a prime factor above 5.
    pub fn new(n: usize, inverse: bool) -> Self {
        assert!(n >= 2 && n % 2 == 0, "a real FFT of odd length {n}");
        let h = n / 2;
        Self {
            n,
            half: BatchFft::new(h, inverse),
            w: (0..=h).map(|k| unit(k, n, inverse)).collect(),
        }
    }

    /// The length n of the real sequences.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether the length is 0 (never).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Forward: `real` (n values per lane; each [`Lanes`] entry k holds
    /// samples 2k in `re` and 2k + 1 in `im`, n/2 entries) to `freq`
    /// (n/2 + 1 entries). `real` is used as the scratch buffer's half and
    /// left changed.
    pub fn forward(&self, real: &mut [Lanes<T>], freq: &mut [Lanes<T>], scratch: &mut [Lanes<T>]) {
        let h = self.n / 2;
        assert!(
            real.len() == h && freq.len() == h + 1 && scratch.len() >= h,
            "real FFT buffers of the wrong length"
        );
        self.half.process(real, &mut scratch[..h]);
        let z = real;
        let half = T::from_f64_rounded(0.5);
        for l in 0..LANES {
            let (zr, zi) = (z[0].re[l], z[0].im[l]);
            freq[0].re[l] = zr + zi;
            freq[0].im[l] = T::default();
            freq[h].re[l] = zr - zi;
            freq[h].im[l] = T::default();
        }
        for k in 1..h {
            let (a, b) = (z[k], z[h - k]);
            let (wr, wi) = self.w[k];
            for l in 0..LANES {
                // E = (a + b̄)/2, O = (a − b̄)/(2i), X = E + w O.
                let er = (a.re[l] + b.re[l]) * half;
                let ei = (a.im[l] - b.im[l]) * half;
                let or = (a.im[l] + b.im[l]) * half;
                let oi = (b.re[l] - a.re[l]) * half;
                freq[k].re[l] = er + (or * wr - oi * wi);
                freq[k].im[l] = ei + (or * wi + oi * wr);
            }
        }
    }

    /// Inverse: `freq` (n/2 + 1 entries; the imaginary parts of entries 0
    /// and n/2 are taken as 0) to `real` (n/2 entries, samples 2k in `re`
    /// and 2k + 1 in `im`), n times the sequence whose forward transform
    /// `freq` is.
    pub fn inverse(&self, freq: &[Lanes<T>], real: &mut [Lanes<T>], scratch: &mut [Lanes<T>]) {
        let h = self.n / 2;
        assert!(
            real.len() == h && freq.len() == h + 1 && scratch.len() >= h,
            "real FFT buffers of the wrong length"
        );
        for l in 0..LANES {
            let (x0, xh) = (freq[0].re[l], freq[h].re[l]);
            real[0].re[l] = x0 + xh;
            real[0].im[l] = x0 - xh;
        }
        for k in 1..h {
            let (a, b) = (freq[k], freq[h - k]);
            let (wr, wi) = self.w[k];
            for l in 0..LANES {
                // Z = (a + b̄) + i w (a − b̄), w = e^{+2πi k/n}.
                let (sr, si) = (a.re[l] + b.re[l], a.im[l] - b.im[l]);
                let (dr, di) = (a.re[l] - b.re[l], a.im[l] + b.im[l]);
                let (pr, pi) = (dr * wr - di * wi, dr * wi + di * wr);
                real[k].re[l] = sr - pi;
                real[k].im[l] = si + pr;
            }
        }
        self.half.process(real, &mut scratch[..h]);
    }
}

/// The 8 × 8 block `a` transposed (`out[i][j] = a[j][i]`): how rows of
/// a 2-D array become lanes and back.
#[inline(always)]
pub fn transpose<T: Copy>(a: &[[T; LANES]; LANES]) -> [[T; LANES]; LANES] {
    let mut o = *a;
    for (i, row) in o.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[j][i];
        }
    }
    o
}

/// [`transpose`] of an f32 block by AVX shuffles (unpack, shuffle, swap of
/// halves): the same values, a few instructions instead of 64 loads and
/// stores. For callers built for AVX2 (`stepsim_numerics::simd`).
///
/// # Safety
/// The CPU must run AVX2 ([`crate::simd::has_avx2`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn transpose_avx2(a: &[[f32; LANES]; LANES]) -> [[f32; LANES]; LANES] {
    use std::arch::x86_64::*;
    // SAFETY: each row is 8 contiguous f32, as the loads and stores read
    // and write; unaligned access is allowed by loadu/storeu.
    unsafe {
        let r: [__m256; LANES] = std::array::from_fn(|i| _mm256_loadu_ps(a[i].as_ptr()));
        let t0 = _mm256_unpacklo_ps(r[0], r[1]);
        let t1 = _mm256_unpackhi_ps(r[0], r[1]);
        let t2 = _mm256_unpacklo_ps(r[2], r[3]);
        let t3 = _mm256_unpackhi_ps(r[2], r[3]);
        let t4 = _mm256_unpacklo_ps(r[4], r[5]);
        let t5 = _mm256_unpackhi_ps(r[4], r[5]);
        let t6 = _mm256_unpacklo_ps(r[6], r[7]);
        let t7 = _mm256_unpackhi_ps(r[6], r[7]);
        let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
        let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
        let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
        let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
        let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
        let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
        let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
        let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
        let o = [
            _mm256_permute2f128_ps::<0x20>(u0, u4),
            _mm256_permute2f128_ps::<0x20>(u1, u5),
            _mm256_permute2f128_ps::<0x20>(u2, u6),
            _mm256_permute2f128_ps::<0x20>(u3, u7),
            _mm256_permute2f128_ps::<0x31>(u0, u4),
            _mm256_permute2f128_ps::<0x31>(u1, u5),
            _mm256_permute2f128_ps::<0x31>(u2, u6),
            _mm256_permute2f128_ps::<0x31>(u3, u7),
        ];
        let mut out = [[0.0f32; LANES]; LANES];
        for (row, v) in out.iter_mut().zip(o) {
            _mm256_storeu_ps(row.as_mut_ptr(), v);
        }
        out
    }
}

/// In-place 2-D FFT of an `n × n` row-major array (n with no prime
/// factor above 5), forward or `inverse`, unnormalised: eight rows at a
/// time in the lanes (gathered from and scattered back to their rows),
/// then eight neighbouring columns at a time (contiguous in each row).
///
/// # Panics
/// If `data` is not n × n or n has a prime factor above 5.
pub fn fft2<T: Real>(data: &mut [num_complex::Complex<T>], n: usize, inverse: bool) {
    assert_eq!(data.len(), n * n, "fft2: data is not n × n");
    if n == 0 {
        return;
    }
    let fft = BatchFft::<T>::new(n, inverse);
    let (mut buf, mut scratch) = (vec![Lanes::zero(); n], vec![Lanes::zero(); n]);
    for r0 in (0..n).step_by(LANES) {
        let rows = LANES.min(n - r0);
        for (k, e) in buf.iter_mut().enumerate() {
            *e = Lanes::zero();
            for l in 0..rows {
                let z = data[(r0 + l) * n + k];
                (e.re[l], e.im[l]) = (z.re, z.im);
            }
        }
        fft.process(&mut buf, &mut scratch);
        for (k, e) in buf.iter().enumerate() {
            for l in 0..rows {
                data[(r0 + l) * n + k] = num_complex::Complex::new(e.re[l], e.im[l]);
            }
        }
    }
    for c0 in (0..n).step_by(LANES) {
        let width = LANES.min(n - c0);
        for (v, e) in buf.iter_mut().enumerate() {
            *e = Lanes::zero();
            for (l, z) in data[v * n + c0..][..width].iter().enumerate() {
                (e.re[l], e.im[l]) = (z.re, z.im);
            }
        }
        fft.process(&mut buf, &mut scratch);
        for (v, e) in buf.iter().enumerate() {
            for (l, z) in data[v * n + c0..][..width].iter_mut().enumerate() {
                *z = num_complex::Complex::new(e.re[l], e.im[l]);
            }
        }
    }
}

/// [`fft2`]'s slow twin: the direct 2-D sum in f64.
pub fn fft2_slow(x: &[(f64, f64)], n: usize, inverse: bool) -> Vec<(f64, f64)> {
    (0..n * n)
        .map(|k| {
            let (kv, ku) = (k / n, k % n);
            x.iter()
                .enumerate()
                .fold((0.0, 0.0), |(sr, si), (j, &(xr, xi))| {
                    let (c, s): (f64, f64) = unit((j / n) * kv + (j % n) * ku, n, inverse);
                    (sr + xr * c - xi * s, si + xr * s + xi * c)
                })
        })
        .collect()
}

/// [`BatchFft`]'s slow, obvious twin: the direct sum in f64 of one
/// sequence, Σ_j x_j e^{∓2πi jk/n}.
pub fn dft_slow(x: &[(f64, f64)], inverse: bool) -> Vec<(f64, f64)> {
    let n = x.len();
    (0..n)
        .map(|k| {
            x.iter()
                .enumerate()
                .fold((0.0, 0.0), |(sr, si), (j, &(xr, xi))| {
                    let (c, s): (f64, f64) = unit(j * k, n, inverse);
                    (sr + xr * c - xi * s, si + xr * s + xi * c)
                })
        })
        .collect()
}

/// [`RealFft::forward`]'s slow twin: the n/2 + 1 non-negative frequencies
/// of a real sequence by the direct sum in f64.
pub fn real_dft_slow(x: &[f64]) -> Vec<(f64, f64)> {
    let z: Vec<(f64, f64)> = x.iter().map(|&v| (v, 0.0)).collect();
    let mut out = dft_slow(&z, false);
    out.truncate(x.len() / 2 + 1);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    fn random_lanes(n: usize, seed: u64) -> Vec<Lanes<f64>> {
        let mut rng = crate::test_rng(seed);
        (0..n)
            .map(|_| Lanes {
                re: std::array::from_fn(|_| rng.random_range(-1.0..1.0)),
                im: std::array::from_fn(|_| rng.random_range(-1.0..1.0)),
            })
            .collect()
    }

    fn lane(v: &[Lanes<f64>], l: usize) -> Vec<(f64, f64)> {
        v.iter().map(|e| (e.re[l], e.im[l])).collect()
    }

    const LENGTHS: [usize; 22] = [
        1, 2, 3, 4, 5, 6, 8, 9, 10, 12, 15, 16, 18, 25, 30, 32, 60, 64, 96, 128, 256, 1350,
    ];

    #[test]
    fn every_lane_is_the_direct_sum() {
        for &n in &LENGTHS {
            for inverse in [false, true] {
                let x = random_lanes(n, n as u64);
                let mut y = x.clone();
                let mut scratch = vec![Lanes::zero(); n];
                BatchFft::new(n, inverse).process(&mut y, &mut scratch);
                for l in 0..LANES {
                    let want = dft_slow(&lane(&x, l), inverse);
                    let got = lane(&y, l);
                    let worst = want
                        .iter()
                        .zip(&got)
                        .map(|(a, b)| (a.0 - b.0).abs().max((a.1 - b.1).abs()))
                        .fold(0.0, f64::max);
                    assert!(worst < 1e-12 * n as f64, "n {n} lane {l}: {worst}");
                }
            }
        }
    }

    #[test]
    fn a_planted_error_is_caught() {
        // The direct-sum comparison would see one wrong twiddle.
        let n = 12;
        let mut fft = BatchFft::<f64>::new(n, false);
        fft.stages[0].twiddles[3].0 += 1e-6; // j = 1, t = 1 (j = 0 is not multiplied)
        let x = random_lanes(n, 3);
        let mut y = x.clone();
        fft.process(&mut y, &mut vec![Lanes::zero(); n]);
        let want = dft_slow(&lane(&x, 0), false);
        let worst = want
            .iter()
            .zip(&lane(&y, 0))
            .map(|(a, b)| (a.0 - b.0).abs().max((a.1 - b.1).abs()))
            .fold(0.0, f64::max);
        assert!(worst > 1e-8, "{worst}");
    }

    #[test]
    fn real_transforms_are_the_direct_sum_and_invert() {
        for &n in &[2usize, 4, 6, 10, 16, 32, 48, 100, 1350] {
            let h = n / 2;
            let x = random_lanes(h, 7 + n as u64);
            let fwd = RealFft::<f64>::new(n, false);
            let inv = RealFft::<f64>::new(n, true);
            let mut real = x.clone();
            let mut freq = vec![Lanes::zero(); h + 1];
            let mut scratch = vec![Lanes::zero(); h];
            fwd.forward(&mut real, &mut freq, &mut scratch);
            for l in 0..LANES {
                let seq: Vec<f64> = x.iter().flat_map(|e| [e.re[l], e.im[l]]).collect();
                let want = real_dft_slow(&seq);
                for (k, (a, b)) in want.iter().zip(lane(&freq, l)).enumerate() {
                    let err = (a.0 - b.0).abs().max((a.1 - b.1).abs());
                    assert!(err < 1e-12 * n as f64, "n {n} lane {l} k {k}: {err}");
                }
            }
            let mut back = vec![Lanes::zero(); h];
            inv.inverse(&freq, &mut back, &mut scratch);
            for (b, a) in back.iter().zip(&x) {
                for l in 0..LANES {
                    assert!((b.re[l] / n as f64 - a.re[l]).abs() < 1e-13 * n as f64);
                    assert!((b.im[l] / n as f64 - a.im[l]).abs() < 1e-13 * n as f64);
                }
            }
        }
    }

    #[test]
    fn the_plain_and_the_avx2_build_give_the_same_bits() {
        // f32, where a library's vector kernels and fused products would
        // round differently.
        for &n in &[30usize, 32, 48, 675, 1350] {
            for inverse in [false, true] {
                let x: Vec<Lanes<f32>> = random_lanes(n, 11)
                    .iter()
                    .map(|e| Lanes {
                        re: e.re.map(|v| v as f32),
                        im: e.im.map(|v| v as f32),
                    })
                    .collect();
                let fft = BatchFft::<f32>::new(n, inverse);
                let (mut a, mut b) = (x.clone(), x.clone());
                let mut scratch = vec![Lanes::zero(); n];
                fft.process_body(&mut a, &mut scratch);
                fft.process(&mut b, &mut scratch);
                let bits = |v: &[Lanes<f32>]| -> Vec<u32> {
                    v.iter()
                        .flat_map(|e| e.re.iter().chain(&e.im).map(|f| f.to_bits()))
                        .collect()
                };
                assert_eq!(bits(&a), bits(&b), "n {n}");
                // And lane l is the lane's own transform whatever the others hold.
                let mut c = x.clone();
                for e in &mut c {
                    for l in 1..LANES {
                        e.re[l] = 0.0;
                        e.im[l] = 0.0;
                    }
                }
                fft.process(&mut c, &mut scratch);
                assert!(
                    c.iter()
                        .zip(&a)
                        .all(|(p, q)| p.re[0].to_bits() == q.re[0].to_bits()
                            && p.im[0].to_bits() == q.im[0].to_bits())
                );
            }
        }
    }

    #[test]
    fn the_avx2_transpose_is_the_transpose() {
        let a: [[f32; LANES]; LANES] =
            std::array::from_fn(|i| std::array::from_fn(|j| (i * 10 + j) as f32));
        let t = transpose(&a);
        assert_eq!(t[2][5], 52.0);
        assert_eq!(t[7][0], 7.0);
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has_avx2() {
            // SAFETY: the CPU runs AVX2 (checked just above).
            assert_eq!(unsafe { transpose_avx2(&a) }, t);
        }
    }

    #[test]
    fn the_2d_transform_is_the_direct_sum() {
        // Sides below, at and above a multiple of the lanes.
        for n in [1usize, 6, 8, 10, 12] {
            for inverse in [false, true] {
                let x = random_lanes(n * n / LANES + 1, 40 + n as u64);
                let flat: Vec<(f64, f64)> = (0..n * n)
                    .map(|i| (x[i / LANES].re[i % LANES], x[i / LANES].im[i % LANES]))
                    .collect();
                let mut data: Vec<num_complex::Complex64> = flat
                    .iter()
                    .map(|&(r, i)| num_complex::Complex64::new(r, i))
                    .collect();
                fft2(&mut data, n, inverse);
                let want = fft2_slow(&flat, n, inverse);
                for (k, (a, b)) in want.iter().zip(&data).enumerate() {
                    let err = (a.0 - b.re).abs().max((a.1 - b.im).abs());
                    assert!(err < 1e-12 * (n * n) as f64, "n {n} k {k}: {err}");
                }
            }
        }
    }

    #[test]
    fn lengths_with_other_primes_are_refused() {
        assert!(radices(14).is_none());
        assert_eq!(radices(1350), Some(vec![2, 3, 3, 3, 5, 5]));
        assert_eq!(radices(10), Some(vec![2, 5]));
        assert_eq!(radices(32), Some(vec![4, 4, 2]));
        assert_eq!(radices(16), Some(vec![4, 4]));
        assert!(std::panic::catch_unwind(|| BatchFft::<f32>::new(7, false)).is_err());
    }
}
