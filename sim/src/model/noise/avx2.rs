//! The noise block with AVX2 intrinsics: the four lanes' Xoshiro256++
//! states in four vector registers, the ziggurat's common path, PD's step I,
//! the read noise and the conversion to ADU four pixels at a time. Integer
//! operations, IEEE additions, products, quotients, square roots, floors and
//! comparisons only (no FMA), so every value has the bits of
//! [`super::noisy_group`]'s plain build (tested through
//! [`super::realise_slow`]). Whatever leaves the common path (a mean outside
//! PD's range, a ziggurat wedge or tail, PD's steps S, F and E) goes back
//! to the scalar code of one lane, with the states stored and reloaded
//! around it.

use super::draws::{self, LANES, Lanes};
use super::{Detector, MAX_LAMBDA, PD_MIN};
use std::arch::x86_64::*;

/// Four Xoshiro256++ states, word-major: register w holds word w of the
/// four lanes (the layout of [`Lanes`]).
struct State([__m256i; 4]);

impl State {
    #[target_feature(enable = "avx2")]
    fn load(lanes: &Lanes) -> Self {
        let s = lanes.words();
        // SAFETY: each row of `s` is four u64, 32 bytes; loadu has no
        // alignment requirement.
        Self(std::array::from_fn(|w| unsafe {
            _mm256_loadu_si256(s[w].as_ptr().cast())
        }))
    }

    #[target_feature(enable = "avx2")]
    fn store(&self, lanes: &mut Lanes) {
        let s = lanes.words_mut();
        for (w, reg) in self.0.iter().enumerate() {
            // SAFETY: as in `load`.
            unsafe { _mm256_storeu_si256(s[w].as_mut_ptr().cast(), *reg) };
        }
    }

    /// One step of every lane, as [`Lanes::next_all`].
    #[target_feature(enable = "avx2")]
    fn next(&mut self) -> __m256i {
        let [s0, s1, s2, s3] = &mut self.0;
        let out = _mm256_add_epi64(rotl::<23, 41>(_mm256_add_epi64(*s0, *s3)), *s0);
        let t = _mm256_slli_epi64::<17>(*s1);
        *s2 = _mm256_xor_si256(*s2, *s0);
        *s3 = _mm256_xor_si256(*s3, *s1);
        *s1 = _mm256_xor_si256(*s1, *s2);
        *s0 = _mm256_xor_si256(*s0, *s3);
        *s2 = _mm256_xor_si256(*s2, t);
        *s3 = rotl::<45, 19>(*s3);
        out
    }
}

/// Rotation of each 64-bit lane left by `L` (`R` = 64 − `L`).
#[target_feature(enable = "avx2")]
fn rotl<const L: i32, const R: i32>(x: __m256i) -> __m256i {
    _mm256_or_si256(_mm256_slli_epi64::<L>(x), _mm256_srli_epi64::<R>(x))
}

/// Lane l of a vector of four u64.
#[target_feature(enable = "avx2")]
fn words(x: __m256i) -> [u64; LANES] {
    let mut out = [0u64; LANES];
    // SAFETY: 32 bytes into a [u64; 4].
    unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), x) };
    out
}

/// Lane l of a vector of four f64.
#[target_feature(enable = "avx2")]
fn reals(x: __m256d) -> [f64; LANES] {
    let mut out = [0.0; LANES];
    // SAFETY: 32 bytes into a [f64; 4].
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), x) };
    out
}

/// One noise block (see [`super::noisy_block_body`], the plain build).
#[target_feature(enable = "avx2")]
pub(super) fn noisy_block(values: &mut [f32], det: &Detector, lanes: &mut Lanes) {
    let mut state = State::load(lanes);
    let mut groups = values.chunks_exact_mut(LANES);
    for group in &mut groups {
        let v: &mut [f32; LANES] = group.try_into().expect("LANES values");
        group_pixels(v, det, &mut state, lanes);
    }
    state.store(lanes);
    for (l, v) in groups.into_remainder().iter_mut().enumerate() {
        *v = super::noisy_pixel(*v, det, &mut lanes.lane(l));
    }
}

/// Four pixels, as [`super::noisy_group`].
#[target_feature(enable = "avx2")]
fn group_pixels(v: &mut [f32; LANES], det: &Detector, state: &mut State, lanes: &mut Lanes) {
    // SAFETY: 16 bytes from a [f32; 4].
    let m = _mm256_cvtps_pd(unsafe { _mm_loadu_ps(v.as_ptr()) });
    let lam = _mm256_max_pd(
        _mm256_add_pd(m, _mm256_set1_pd(det.sky_e_per_px)),
        _mm256_setzero_pd(),
    );
    let in_range = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_GE_OQ>(lam, _mm256_set1_pd(PD_MIN)),
        _mm256_cmp_pd::<_CMP_LE_OQ>(lam, _mm256_set1_pd(MAX_LAMBDA)),
    );
    if _mm256_movemask_pd(in_range) != 0b1111 {
        state.store(lanes);
        for (l, x) in v.iter_mut().enumerate() {
            *x = super::noisy_pixel(*x, det, &mut lanes.lane(l));
        }
        *state = State::load(lanes);
        return;
    }
    let z = normal(state, lanes);
    let s = _mm256_sqrt_pd(lam);
    let g = _mm256_add_pd(lam, _mm256_mul_pd(s, z));
    let k = _mm256_round_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(g);
    let limit = _mm256_round_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(_mm256_sub_pd(
        lam,
        _mm256_set1_pd(1.1484),
    ));
    let nonnegative = _mm256_cmp_pd::<_CMP_GE_OQ>(g, _mm256_setzero_pd());
    let take = _mm256_and_pd(nonnegative, _mm256_cmp_pd::<_CMP_GE_OQ>(k, limit));
    let mut e = k;
    let mut done = _mm256_movemask_pd(take);
    if done != 0b1111 {
        let need_u = _mm256_andnot_pd(take, nonnegative);
        let mut u = _mm256_setzero_pd();
        if _mm256_movemask_pd(need_u) != 0 {
            let before = State(state.0);
            let bits = state.next();
            // Lanes that draw no uniform keep their state.
            let step = _mm256_castpd_si256(need_u);
            for w in 0..4 {
                state.0[w] = _mm256_blendv_epi8(before.0[w], state.0[w], step);
            }
            u = uniform(bits);
            // Step S: 6 (λ λ) u ≥ (d d) d with d = λ − k.
            let d = _mm256_sub_pd(lam, k);
            let lhs = _mm256_mul_pd(
                _mm256_mul_pd(_mm256_set1_pd(6.0), _mm256_mul_pd(lam, lam)),
                u,
            );
            let rhs = _mm256_mul_pd(_mm256_mul_pd(d, d), d);
            let accepted = _mm256_and_pd(need_u, _mm256_cmp_pd::<_CMP_GE_OQ>(lhs, rhs));
            done |= _mm256_movemask_pd(accepted);
        }
        if done != 0b1111 {
            state.store(lanes);
            let (lam, s, k, u) = (reals(lam), reals(s), reals(k), reals(u));
            let need_u = _mm256_movemask_pd(need_u);
            let mut out = reals(e);
            for l in 0..LANES {
                if done & (1 << l) == 0 {
                    let candidate = (need_u & (1 << l) != 0).then_some((k[l], u[l]));
                    out[l] = super::pd_tail(lam[l], s[l], candidate, &mut lanes.lane(l));
                }
            }
            *state = State::load(lanes);
            // SAFETY: 32 bytes from a [f64; 4].
            e = unsafe { _mm256_loadu_pd(out.as_ptr()) };
        }
    }
    if det.read_noise_e > 0.0 {
        let r = normal(state, lanes);
        e = _mm256_add_pd(e, _mm256_mul_pd(_mm256_set1_pd(det.read_noise_e), r));
    }
    let adu = _mm256_min_pd(
        _mm256_div_pd(e, _mm256_set1_pd(det.gain_e_per_adu)),
        _mm256_set1_pd(det.saturation_adu),
    );
    // SAFETY: 16 bytes into a [f32; 4].
    unsafe { _mm_storeu_ps(v.as_mut_ptr(), _mm256_cvtpd_ps(adu)) };
}

/// [`draws::uniform_of`] of each lane: the top 53 bits as two exact
/// halves of 27 and 26 bits (each converted exactly by the 2⁵² trick), their
/// exact sum, times 2⁻⁵³.
#[target_feature(enable = "avx2")]
fn uniform(bits: __m256i) -> __m256d {
    let magic = _mm256_set1_epi64x(0x4330_0000_0000_0000);
    let two52 = _mm256_set1_pd(4_503_599_627_370_496.0);
    let exact = |v: __m256i| _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(v, magic)), two52);
    let hi = exact(_mm256_srli_epi64::<37>(bits));
    let lo = exact(_mm256_and_si256(
        _mm256_srli_epi64::<11>(bits),
        _mm256_set1_epi64x((1 << 26) - 1),
    ));
    let whole = _mm256_add_pd(_mm256_mul_pd(hi, _mm256_set1_pd(67_108_864.0)), lo);
    _mm256_mul_pd(whole, _mm256_set1_pd(1.0 / 9_007_199_254_740_992.0))
}

/// A standard normal on each lane, as [`super::group_normal`].
#[target_feature(enable = "avx2")]
fn normal(state: &mut State, lanes: &mut Lanes) -> __m256d {
    let table = draws::ziggurat();
    let bits = state.next();
    let layer = _mm256_and_si256(bits, _mm256_set1_epi64x(0xff));
    let one = _mm256_set1_epi64x(0x3ff0_0000_0000_0000);
    let u = _mm256_sub_pd(
        _mm256_castsi256_pd(_mm256_or_si256(_mm256_srli_epi64::<12>(bits), one)),
        _mm256_set1_pd(1.0),
    );
    // SAFETY: layer ∈ [0, 255], so layer and layer + 1 index the 257
    // entries of `x`.
    let (edge, inner) = unsafe {
        (
            _mm256_i64gather_pd::<8>(table.x.as_ptr(), layer),
            _mm256_i64gather_pd::<8>(table.x.as_ptr().add(1), layer),
        )
    };
    let x = _mm256_mul_pd(u, edge);
    let inside = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LT_OQ>(x, inner));
    // Bit 8 of the draw moved to the sign bit.
    let sign = _mm256_and_si256(_mm256_slli_epi64::<55>(bits), _mm256_set1_epi64x(i64::MIN));
    let z = _mm256_xor_pd(x, _mm256_castsi256_pd(sign));
    if inside == 0b1111 {
        return z;
    }
    state.store(lanes);
    let bits = words(bits);
    let mut out = reals(z);
    for l in 0..LANES {
        if inside & (1 << l) == 0 {
            out[l] = draws::finish_normal(bits[l], &mut lanes.lane(l));
        }
    }
    *state = State::load(lanes);
    // SAFETY: 32 bytes from a [f64; 4].
    unsafe { _mm256_loadu_pd(out.as_ptr()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use stepsim_contract::seed::SimRng;

    #[test]
    fn uniforms_are_the_scalar_uniforms_bit_for_bit() {
        if !stepsim_numerics::simd::has_avx2() {
            return;
        }
        let mut rng = SimRng::seed_from_u64(9);
        let mut quartets: Vec<[u64; LANES]> = vec![[0, u64::MAX, 1 << 11, (1 << 11) - 1]];
        quartets.extend((0..10_000).map(|_| std::array::from_fn(|_| rng.next_u64())));
        for q in quartets {
            // SAFETY: the CPU runs AVX2 (checked above); 32 bytes from q.
            let got = unsafe { reals(uniform(_mm256_loadu_si256(q.as_ptr().cast()))) };
            for l in 0..LANES {
                let want = draws::uniform_of(q[l]);
                assert_eq!(got[l].to_bits(), want.to_bits(), "draw {:#x}", q[l]);
            }
        }
    }
}
