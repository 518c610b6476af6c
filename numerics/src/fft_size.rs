//! FFT lengths whose only prime factors are 2, 3 and 5, for which the FFT
//! libraries run their fastest kernels.

/// The smallest even n ≥ `m` of the form 2^a 3^b 5^c (a ≥ 1).
pub fn fft_friendly(m: usize) -> usize {
    let mut n = m.max(2);
    n += n % 2;
    while !is_friendly(n) {
        n += 2;
    }
    n
}

/// The largest even n ≤ `m` of the form 2^a 3^b 5^c (at least 2).
pub fn fft_friendly_below(m: usize) -> usize {
    let mut n = m.max(2);
    n -= n % 2;
    while n > 2 && !is_friendly(n) {
        n -= 2;
    }
    n
}

/// Whether `n` has no prime factor but 2, 3 and 5.
pub fn is_friendly(mut n: usize) -> bool {
    for f in [2, 3, 5] {
        while n > 0 && n % f == 0 {
            n /= f;
        }
    }
    n == 1
}

/// [`is_friendly`]'s slow, obvious twin: n's prime factors by trial
/// division, none above 5 (and n ≥ 1).
pub fn is_friendly_slow(n: usize) -> bool {
    let (mut rest, mut p) = (n, 2);
    while rest > 1 {
        if rest % p == 0 {
            if p > 5 {
                return false;
            }
            rest /= p;
        } else {
            p += 1;
        }
    }
    n >= 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn friendly_sizes() {
        assert_eq!(fft_friendly(1), 2);
        assert_eq!(fft_friendly(31), 32);
        assert_eq!(fft_friendly(33), 36);
        assert_eq!(fft_friendly(98), 100);
        assert_eq!(fft_friendly(101), 108);
        assert_eq!(fft_friendly(1091), 1152);
        assert_eq!(fft_friendly_below(1023), 1000);
        assert_eq!(fft_friendly_below(1024), 1024);
        assert!(!is_friendly(0) && is_friendly(1) && !is_friendly(7));
        for n in 0..2000 {
            assert_eq!(is_friendly(n), is_friendly_slow(n), "{n}");
        }
        for n in 2..400 {
            let f = fft_friendly(n);
            assert!(f >= n && f % 2 == 0 && is_friendly(f));
            assert!((n..f).all(|m| m % 2 == 1 || !is_friendly(m)));
            let b = fft_friendly_below(n);
            assert!(b <= n && b % 2 == 0 && is_friendly(b));
            assert!((b + 1..=n).all(|m| m % 2 == 1 || !is_friendly(m)));
        }
    }
}
