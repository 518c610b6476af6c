//! Zernike polynomials, Noll (1976) ordering and normalisation.
//!
//! Z_j(ρ, θ) = sqrt(n + 1) R_n^|m|(ρ) × {√2 cos mθ (m > 0, j even);
//! √2 sin |m|θ (m < 0, j odd); 1 (m = 0)} on the unit disk, so that
//! (1/π) ∫ Z_i Z_j = δ_ij over the unobstructed disk: an amplitude of a
//! waves is a wavefront of a waves rms. The ones stepsim names:
//! Z4 defocus √3(2ρ²−1), Z5/Z6 astigmatism √6 ρ² sin/cos 2θ,
//! Z7/Z8 coma √8(3ρ³−2ρ) sin/cos θ, Z9/Z10 trefoil √8 ρ³ sin/cos 3θ,
//! Z11 spherical √5(6ρ⁴−6ρ²+1).

/// (n, m) of Noll index `j` (j ≥ 1); m < 0 means a sine term.
pub fn noll_to_nm(j: u32) -> (u32, i32) {
    assert!(j >= 1, "Noll indices start at 1");
    let (mut n, mut j1) = (0u32, j - 1);
    while j1 > n {
        n += 1;
        j1 -= n;
    }
    let m = (n % 2) + 2 * ((j1 + (n + 1) % 2) / 2);
    let m = m as i32;
    (n, if j % 2 == 0 { m } else { -m })
}

fn factorial(k: u32) -> f64 {
    (1..=k).map(f64::from).product()
}

/// Radial polynomial R_n^m(ρ) (m ≥ 0, n − m even).
pub fn radial(n: u32, m: u32, rho: f64) -> f64 {
    (0..=(n - m) / 2)
        .map(|k| {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            sign * factorial(n - k)
                / (factorial(k) * factorial((n + m) / 2 - k) * factorial((n - m) / 2 - k))
                * rho.powi((n - 2 * k) as i32)
        })
        .sum()
}

/// Z_j at polar position (ρ, θ) on the unit disk (Noll normalisation).
pub fn noll(j: u32, rho: f64, theta: f64) -> f64 {
    let (n, m) = noll_to_nm(j);
    let r = (f64::from(n) + 1.0).sqrt() * radial(n, m.unsigned_abs(), rho);
    match m {
        0 => r,
        m if m > 0 => r * std::f64::consts::SQRT_2 * (f64::from(m) * theta).cos(),
        m => r * std::f64::consts::SQRT_2 * (f64::from(-m) * theta).sin(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_and_closed_forms() {
        assert_eq!(noll_to_nm(1), (0, 0));
        assert_eq!(noll_to_nm(4), (2, 0));
        assert_eq!(noll_to_nm(5), (2, -2));
        assert_eq!(noll_to_nm(6), (2, 2));
        assert_eq!(noll_to_nm(7), (3, -1));
        assert_eq!(noll_to_nm(8), (3, 1));
        assert_eq!(noll_to_nm(9), (3, -3));
        assert_eq!(noll_to_nm(10), (3, 3));
        assert_eq!(noll_to_nm(11), (4, 0));
        let (r, t) = (0.7_f64, 0.4_f64);
        let s3 = 3f64.sqrt();
        let s6 = 6f64.sqrt();
        let s8 = 8f64.sqrt();
        let cases = [
            (4, s3 * (2.0 * r * r - 1.0)),
            (5, s6 * r * r * (2.0 * t).sin()),
            (6, s6 * r * r * (2.0 * t).cos()),
            (7, s8 * (3.0 * r.powi(3) - 2.0 * r) * t.sin()),
            (8, s8 * (3.0 * r.powi(3) - 2.0 * r) * t.cos()),
            (9, s8 * r.powi(3) * (3.0 * t).sin()),
            (10, s8 * r.powi(3) * (3.0 * t).cos()),
            (11, 5f64.sqrt() * (6.0 * r.powi(4) - 6.0 * r * r + 1.0)),
        ];
        for (j, want) in cases {
            assert!((noll(j, r, t) - want).abs() < 1e-12, "Z{j}");
        }
    }

    #[test]
    fn orthonormal_on_the_unit_disk() {
        // Midpoint quadrature in (ρ, θ): exact enough for polynomials of degree ≤ 8.
        let (nr, nt) = (400, 64);
        for i in 4..=11 {
            for j in i..=11 {
                let mut s = 0.0;
                for a in 0..nr {
                    let rho = (a as f64 + 0.5) / nr as f64;
                    for b in 0..nt {
                        let th = (b as f64 + 0.5) / nt as f64 * std::f64::consts::TAU;
                        s += noll(i, rho, th) * noll(j, rho, th) * rho;
                    }
                }
                s *= (1.0 / nr as f64) * (std::f64::consts::TAU / nt as f64) / std::f64::consts::PI;
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 1e-4, "<Z{i} Z{j}> = {s}");
            }
        }
    }
}
