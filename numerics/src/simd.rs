//! Choosing, at run time, a build of a hot loop for the CPU's vector
//! instructions.
//!
//! The release binary targets plain x86-64 (SSE2): two f64 lanes, and
//! `floor` or `round` as library calls. A loop written once as an
//! `#[inline(always)]` body can also be compiled inside a
//! `#[target_feature(enable = "avx2")]` wrapper, with four f64 lanes and
//! `floor` as one instruction, and called there when [`has_avx2`] says the
//! CPU runs it. Only the enable list `avx2` is used, never `fma`: without
//! it the compiler cannot fuse a product and a sum, and Rust never
//! reassociates floating-point arithmetic, so both builds do the same IEEE
//! operations in the same order and give the same bits (each user has a test
//! that compares them with its slow twin on this machine).

/// Whether this CPU runs AVX2 code (x86-64 only; `false` elsewhere).
/// `STEPSIM_SIMD=0` in the environment answers `false`, so that the plain
/// build can be run and timed on any machine.
#[inline]
pub fn has_avx2() -> bool {
    use std::sync::atomic::{AtomicU8, Ordering};
    // 0: not asked yet, 1: no, 2: yes.
    static ANSWER: AtomicU8 = AtomicU8::new(0);
    match ANSWER.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => {
            let yes = detect() && !off_by_environment();
            ANSWER.store(if yes { 2 } else { 1 }, Ordering::Relaxed);
            yes
        }
    }
}

fn off_by_environment() -> bool {
    std::env::var("STEPSIM_SIMD").is_ok_and(|v| matches!(v.trim(), "0" | "off" | "false"))
}

#[cfg(target_arch = "x86_64")]
fn detect() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

#[cfg(not(target_arch = "x86_64"))]
fn detect() -> bool {
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_answer_is_the_cpus_and_stays_the_same() {
        let first = has_avx2();
        assert_eq!(first, detect() && !off_by_environment());
        assert_eq!(has_avx2(), first);
    }
}
