//! FFT benchmark: stepsim's own transforms of eight sequences at once
//! (`stepsim_numerics::fft::BatchFft`, the same bits on every CPU) against
//! rustfft's planner by CPU (AVX with fused multiply-adds here) and its
//! scalar planner, on about 4 M complex f32 points of each length.
//!
//! ```sh
//! cargo run --release -p stepsim-sim --example fft_bench [length ...]
//! ```
//!
//! Prints, per length, the best of seven passes of each (ms) and the ratio
//! of each to rustfft's planner by CPU; with `f64` as the first argument,
//! the same in f64 (about 2 M points of each length).

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftDirection, FftNum, FftPlanner, FftPlannerScalar};
use std::sync::Arc;
use std::time::Instant;
use stepsim_numerics::fft::{BatchFft, LANES, Lanes, Real};

const PASSES: usize = 7;

fn best_of(mut pass: impl FnMut()) -> f64 {
    (0..PASSES)
        .map(|_| {
            let t = Instant::now();
            pass();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn value<T: Real>(i: usize) -> T {
    T::from_f64_rounded((i % 1000) as f64 / 1000.0)
}

fn rustfft_ms<T: FftNum + Real>(fft: &Arc<dyn Fft<T>>, n: usize, count: usize) -> f64 {
    let quarter = T::from_f64_rounded(0.25);
    let mut buf: Vec<Complex<T>> = (0..n * count)
        .map(|i| Complex::new(value(i), quarter))
        .collect();
    let mut scratch = vec![Complex::new(T::default(), T::default()); fft.get_inplace_scratch_len()];
    1e3 * best_of(|| fft.process_with_scratch(&mut buf, &mut scratch))
}

fn lanes_ms<T: Real>(n: usize, count: usize) -> f64 {
    let fft = BatchFft::<T>::new(n, true);
    let mut data: Vec<Lanes<T>> = (0..n * count / LANES)
        .map(|i| Lanes {
            re: std::array::from_fn(|l| value(i * LANES + l)),
            im: [T::from_f64_rounded(0.25); LANES],
        })
        .collect();
    let mut scratch = vec![Lanes::zero(); n];
    1e3 * best_of(|| {
        for group in data.chunks_exact_mut(n) {
            fft.process(group, &mut scratch);
        }
    })
}

fn table<T: FftNum + Real>(lengths: &[usize], points: usize) {
    println!(
        "| length | transforms | rustfft by CPU ms | rustfft scalar ms (ratio) | stepsim lanes ms (ratio) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for &n in lengths {
        if n == 0 || !stepsim_numerics::fft_size::is_friendly(n) {
            eprintln!("fft_bench: {n} has a prime factor above 5 (or is 0); skipped");
            continue;
        }
        let count = (points / n / LANES).max(1) * LANES;
        let by_cpu = rustfft_ms(
            &FftPlanner::<T>::new().plan_fft(n, FftDirection::Inverse),
            n,
            count,
        );
        let scalar = rustfft_ms(
            &FftPlannerScalar::<T>::new().plan_fft(n, FftDirection::Inverse),
            n,
            count,
        );
        let lanes = lanes_ms::<T>(n, count);
        println!(
            "| {n} | {count} | {by_cpu:.2} | {scalar:.2} ({:.2}) | {lanes:.2} ({:.2}) |",
            scalar / by_cpu,
            lanes / by_cpu
        );
    }
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let f64_table = args.first().is_some_and(|a| a == "f64");
    if f64_table {
        args.remove(0);
    }
    let mut lengths: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    if lengths.is_empty() {
        lengths = vec![32, 48, 64, 96, 128, 1350];
    }
    if f64_table {
        table::<f64>(&lengths, 2_000_000);
    } else {
        table::<f32>(&lengths, 4_000_000);
    }
}
