//! A deterministic mutation fuzzer over every reader of participant input:
//! text and CSV tables, FITS tables (bytes flipped, header values replaced
//! by hostile ones, truncated, gzip-compressed), gzip streams, submission
//! directories (odd entries) and `report.json` files read by the
//! leaderboard. Every case must end in rows or in an error that names the
//! file; a panic fails the test, and a crash in cfitsio would kill it.
//!
//! `STEPSIM_FUZZ_CASES=N` sets the number of cases per reader (default
//! 600, a few seconds); `STEPSIM_FUZZ_SEED` the seed (default 2026).
//! With `STEPSIM_FUZZ_KEEP=DIR` the input being read is kept at a fixed
//! path in DIR, so that a crash leaves the offending file behind.

use crate::common;

use common::{Col, doubles, fits_table, good_table, gzip, index, text, zeros};
use rand::{RngExt, SeedableRng};
use std::path::{Path, PathBuf};
use stepsim_contract::seed::SimRng;
use stepsim_harness::{parse_file_limited, read_report, read_submission_limited};

fn cases() -> usize {
    std::env::var("STEPSIM_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(600)
}

fn rng(salt: u64) -> SimRng {
    let seed = std::env::var("STEPSIM_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2026u64);
    SimRng::seed_from_u64(seed ^ salt.wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// Where the inputs are written (kept when `STEPSIM_FUZZ_KEEP` is set).
struct Work {
    _tmp: Option<tempfile::TempDir>,
    dir: PathBuf,
}

fn work() -> Work {
    match std::env::var_os("STEPSIM_FUZZ_KEEP") {
        Some(d) => {
            let dir = PathBuf::from(d);
            std::fs::create_dir_all(&dir).unwrap();
            Work { _tmp: None, dir }
        }
        None => {
            let t = tempfile::tempdir().unwrap();
            let dir = t.path().to_path_buf();
            Work { _tmp: Some(t), dir }
        }
    }
}

/// Header values that have broken FITS readers.
const VALUES: &[&str] = &[
    "0",
    "-1",
    "1",
    "3",
    "2880",
    "2147483647",
    "2147483648",
    "-2147483648",
    "9223372036854775807",
    "-9223372036854775808",
    "99999999999999999999999",
    "1.5",
    "1E300",
    "NaN",
    "T",
    "'X'",
    "''",
    "",
];

/// TFORMs, legal and not.
const TFORMS: &[&str] = &[
    "D",
    "0D",
    "-1D",
    "1000000000D",
    "99999999999999999999D",
    "A",
    "0A",
    "8A",
    "8A2",
    "8A0",
    "1A9",
    "999999999A",
    "1PD(2)",
    "1PD(2147483647)",
    "1PD",
    "P",
    "1QE(99999999999)",
    "2Q",
    "C",
    "M",
    "X",
    "8X",
    "L",
    "E",
    "J",
    "K",
    "3D",
    "Z",
    "",
    "1",
    "()",
    "1PA(5)",
];

fn mutate_bytes(r: &mut SimRng, v: &mut Vec<u8>, from: usize) {
    for _ in 0..r.random_range(1..6) {
        if v.len() <= from {
            return;
        }
        let at = r.random_range(from..v.len());
        match r.random_range(0..4) {
            0 => v[at] = r.random::<u8>(),
            1 => v[at] ^= 1 << r.random_range(0..8),
            2 => v[at] = b"0123456789 -+.'ETPQ("[r.random_range(0..20)],
            _ => {
                v.remove(at);
            }
        }
    }
}

/// Replaces the value of a random header card of the header block starting
/// at `start` with a hostile value (or a TFORM with a hostile TFORM).
fn mutate_header_at(r: &mut SimRng, v: &mut [u8], start: usize) {
    let cards: Vec<usize> = (start..v.len().min(start + 2880))
        .step_by(80)
        .filter(|&i| v[i + 8] == b'=')
        .collect();
    if cards.is_empty() {
        return;
    }
    let at = cards[r.random_range(0..cards.len())];
    let value = if v[at..at + 5] == *b"TFORM" {
        format!("'{}'", TFORMS[r.random_range(0..TFORMS.len())])
    } else {
        VALUES[r.random_range(0..VALUES.len())].to_owned()
    };
    let mut field = format!("{value:>20}").into_bytes();
    field.resize(70, b' ');
    v[at + 10..at + 80].copy_from_slice(&field);
}

/// [`mutate_header_at`] on the extension's header.
fn mutate_header(r: &mut SimRng, v: &mut [u8]) {
    mutate_header_at(r, v, 2880);
}

/// Checks one outcome: rows that are sane, or an error naming the file.
fn check(p: &Path, r: Result<stepsim_harness::FileRows, stepsim_harness::HarnessError>) -> bool {
    match r {
        Ok(fr) => {
            assert!(!fr.rows.is_empty());
            for (_, row) in &fr.rows {
                assert!(row.x.is_finite() && row.y.is_finite());
                assert!(row.e1.abs() <= 1e6 && row.e2.abs() <= 1e6);
                assert!(row.weight.is_finite() && row.weight >= 0.0);
            }
            true
        }
        Err(e) => {
            let e = e.to_string();
            assert!(e.contains(&p.display().to_string()), "names the file: {e}");
            assert!(
                !e.contains("FitsError") && !e.contains("Fits error"),
                "raw cfitsio error: {e}"
            );
            false
        }
    }
}

const LIMIT: u64 = 1 << 20;

#[test]
fn fuzz_text_and_csv() {
    let idx = index();
    let w = work();
    let mut r = rng(1);
    let seeds: [&[u8]; 3] = [
        b"# image x y e1 e2 weight flags\nimA 10.5 20.25 0.01 -0.02 2.0 0\n# c\n\nimB\t0.5\t80.5\t0.1\t0.2\t1\t3\n",
        b"\xef\xbb\xbfIMAGE,X,Y,E1,E2\r\n\"imB\",3,4,0.5,-0.5\r\nimA, 7 ,8,0,0\r\n",
        b"# x y e1 e2\r1 2 0.1 0.2\r3 4 1e6 -1e6\r",
    ];
    let (mut ok, mut refused) = (0, 0);
    for case in 0..cases() {
        let k = case % seeds.len();
        let mut v = seeds[k].to_vec();
        mutate_bytes(&mut r, &mut v, 0);
        let p = w.dir.join("t.txt");
        let fixed = (k == 2).then_some(0);
        let res = if case % 7 == 0 {
            // The same through gzip.
            let g = gzip(&v, 1);
            std::fs::write(&p, &g).unwrap();
            parse_file_limited(&p, &g, &idx, fixed, LIMIT)
        } else {
            parse_file_limited(&p, &v, &idx, fixed, LIMIT)
        };
        if check(&p, res) {
            ok += 1;
        } else {
            refused += 1;
        }
    }
    eprintln!("text: {ok} read, {refused} refused");
    assert!(ok > cases() / 40 && refused > cases() / 4, "{ok} {refused}");
}

fn fits_seeds() -> Vec<Vec<u8>> {
    let odd = || -> Vec<Col> {
        vec![
            zeros("P", "1PD(2)", 8, 3),
            zeros("Q", "1QE(2)", 16, 3),
            zeros("C", "C", 8, 3),
            zeros("M", "M", 16, 3),
        ]
    };
    let weights = vec![
        text("IMAGE", &["imA", "imB", "imA"]),
        doubles("X", &[1.0, 2.0, 3.0]),
        doubles("Y", &[5.0, 5.0, 5.0]),
        doubles("E1", &[0.1, 0.2, 0.3]),
        doubles("E2", &[0.0, 0.0, 0.0]),
        doubles("WEIGHT", &[1.0, 2.0, 0.0]),
    ];
    vec![good_table(vec![]), good_table(odd()), fits_table(&weights)]
}

#[test]
fn fuzz_fits_tables() {
    let idx = index();
    let w = work();
    let mut r = rng(2);
    let seeds = fits_seeds();
    let (mut ok, mut refused) = (0, 0);
    for case in 0..cases() {
        let mut v = seeds[case % seeds.len()].clone();
        match case % 6 {
            0 | 1 => mutate_header(&mut r, &mut v),
            5 => mutate_header_at(&mut r, &mut v, 0),
            2 => {
                mutate_header(&mut r, &mut v);
                mutate_header(&mut r, &mut v);
            }
            3 => mutate_bytes(&mut r, &mut v, 9),
            _ => mutate_bytes(&mut r, &mut v, 5760),
        }
        if case % 11 == 0 {
            let n = r.random_range(9..v.len());
            v.truncate(n);
        }
        if case % 13 == 0 {
            v = gzip(&v, 1);
        }
        let p = w.dir.join("f.fits");
        std::fs::write(&p, &v).unwrap();
        if check(&p, parse_file_limited(&p, &v, &idx, None, LIMIT)) {
            ok += 1;
        } else {
            refused += 1;
        }
    }
    eprintln!("fits: {ok} read, {refused} refused");
    assert!(ok > cases() / 50 && refused > cases() / 4, "{ok} {refused}");
}

#[test]
fn fuzz_gzip_streams() {
    let idx = index();
    let w = work();
    let mut r = rng(3);
    let plain = b"# image x y e1 e2\nimA 1 2 0.1 0.2\nimB 3 4 0 0\n".repeat(20);
    let seeds = [gzip(&plain, 1), gzip(&fits_seeds()[0], 1)];
    for case in 0..cases() {
        let mut v = seeds[case % 2].clone();
        mutate_bytes(&mut r, &mut v, 2);
        let p = w.dir.join("g.gz");
        std::fs::write(&p, &v).unwrap();
        check(&p, parse_file_limited(&p, &v, &idx, None, LIMIT));
    }
}

#[test]
fn fuzz_submission_directories() {
    let idx = index();
    let w = work();
    let mut r = rng(4);
    let names = [
        "imA.txt", "imB.csv", "imA.fits", "imC.txt", ".hidden", "imB", "sub", "imA.t.gz",
    ];
    let bodies: Vec<Vec<u8>> = vec![
        b"# x y e1 e2\n1 2 0.1 0.2\n".to_vec(),
        b"x,y,e1,e2,image\n5,6,0.5,0.6,imB\n".to_vec(),
        fits_seeds()[1].clone(),
        gzip(b"# x y e1 e2\n1 2 0.1 0.2\n", 1),
        b"\x00\x01binary".to_vec(),
        Vec::new(),
    ];
    for case in 0..cases() / 4 {
        let d = w.dir.join(format!("dir{}", case % 2));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        for _ in 0..r.random_range(0..5) {
            let name = names[r.random_range(0..names.len())];
            let p = d.join(name);
            if std::fs::symlink_metadata(&p).is_ok() {
                continue; // never write through a FIFO made earlier
            }
            match r.random_range(0..10) {
                0 => {
                    let _ = std::fs::create_dir(&p);
                }
                #[cfg(unix)]
                1 => {
                    let _ = std::os::unix::fs::symlink("/dev/zero", &p);
                }
                #[cfg(unix)]
                2 => {
                    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
                    // SAFETY: a NUL-terminated path.
                    unsafe { libc::mkfifo(c.as_ptr(), 0o600) };
                }
                _ => {
                    let mut b = bodies[r.random_range(0..bodies.len())].clone();
                    if r.random::<bool>() {
                        mutate_bytes(&mut r, &mut b, 0);
                    }
                    let _ = std::fs::write(&p, &b);
                }
            }
        }
        match read_submission_limited(&d, &idx, LIMIT) {
            Ok(s) => assert!(s.n_rows() > 0),
            Err(e) => {
                let e = e.to_string();
                assert!(e.starts_with(&d.display().to_string()), "{e}");
            }
        }
    }
}

#[test]
fn fuzz_report_json() {
    let w = work();
    let mut r = rng(5);
    let good = include_str!("data/report_minimal.json").as_bytes().to_vec();
    let p = w.dir.join("report.json");
    std::fs::write(&p, &good).unwrap();
    read_report(&p).expect("the seed report reads");
    for _ in 0..cases() {
        let mut v = good.clone();
        mutate_bytes(&mut r, &mut v, 0);
        std::fs::write(&p, &v).unwrap();
        if let Err(e) = read_report(&p) {
            let e = e.to_string();
            assert!(e.contains(&p.display().to_string()), "names the file: {e}");
        }
    }
}
