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
//! of each to rustfft's planner by CPU.

use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftDirection, FftPlanner, FftPlannerScalar};
use std::sync::Arc;
use std::time::Instant;
use stepsim_numerics::fft::{BatchFft, LANES, Lanes};

const POINTS: usize = 4_000_000;
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

fn rustfft_ms(fft: &Arc<dyn Fft<f32>>, n: usize, count: usize) -> f64 {
    let mut buf: Vec<Complex32> = (0..n * count)
        .map(|i| Complex32::new((i % 1000) as f32 / 1000.0, 0.25))
        .collect();
    let mut scratch = vec![Complex32::new(0.0, 0.0); fft.get_inplace_scratch_len()];
    1e3 * best_of(|| fft.process_with_scratch(&mut buf, &mut scratch))
}

fn lanes_ms(n: usize, count: usize) -> f64 {
    let fft = BatchFft::<f32>::new(n, true);
    let mut data: Vec<Lanes<f32>> = (0..n * count / LANES)
        .map(|i| Lanes {
            re: std::array::from_fn(|l| ((i * LANES + l) % 1000) as f32 / 1000.0),
            im: [0.25; LANES],
        })
        .collect();
    let mut scratch = vec![Lanes::zero(); n];
    1e3 * best_of(|| {
        for group in data.chunks_exact_mut(n) {
            fft.process(group, &mut scratch);
        }
    })
}

fn main() {
    let mut lengths: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    if lengths.is_empty() {
        lengths = vec![32, 48, 64, 96, 128, 675, 1350];
    }
    println!(
        "| length | transforms | rustfft by CPU ms | rustfft scalar ms (ratio) | stepsim lanes ms (ratio) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for n in lengths {
        if n == 0 || !stepsim_numerics::fft_size::is_friendly(n) {
            eprintln!("fft_bench: {n} has a prime factor above 5 (or is 0); skipped");
            continue;
        }
        let count = (POINTS / n / LANES).max(1) * LANES;
        let by_cpu = rustfft_ms(
            &FftPlanner::new().plan_fft(n, FftDirection::Inverse),
            n,
            count,
        );
        let scalar = rustfft_ms(
            &FftPlannerScalar::new().plan_fft(n, FftDirection::Inverse),
            n,
            count,
        );
        let lanes = lanes_ms(n, count);
        println!(
            "| {n} | {count} | {by_cpu:.2} | {scalar:.2} ({:.2}) | {lanes:.2} ({:.2}) |",
            scalar / by_cpu,
            lanes / by_cpu
        );
    }
}
