//! FITS binary tables written byte by byte, for tests of the submission
//! readers: column types that `fitsio` cannot write (variable-length `P`/`Q`,
//! complex `C`/`M`) and malformed headers can be made with it. The one copy:
//! the root package's tests reach it as `common::fits_table`, the harness's
//! tests include this file with `#[path]`.
//!
//! Not the contract's `create_fits`: that goes through `fitsio`, which is
//! exactly what cannot write these columns.
#![allow(dead_code)]

/// One column of a hand-written binary table: name, TFORM, and the bytes
/// of each row's field (big-endian, as FITS stores them).
pub struct Col {
    /// TTYPE.
    pub name: &'static str,
    /// TFORM.
    pub tform: String,
    /// Each row's field.
    pub rows: Vec<Vec<u8>>,
}

/// A `D` (f64) column.
pub fn doubles(name: &'static str, v: &[f64]) -> Col {
    Col {
        name,
        tform: "D".into(),
        rows: v.iter().map(|x| x.to_be_bytes().to_vec()).collect(),
    }
}

/// An `nA` text column, n the longest value (at least 8), blank-padded.
pub fn text(name: &'static str, v: &[&str]) -> Col {
    let width = v.iter().map(|s| s.len()).max().unwrap_or(0).max(8);
    Col {
        name,
        tform: format!("{width}A"),
        rows: v
            .iter()
            .map(|s| {
                let mut b = s.as_bytes().to_vec();
                b.resize(width, b' ');
                b
            })
            .collect(),
    }
}

/// A column of any TFORM whose row fields are `width` zero bytes (for
/// variable-length columns: a descriptor of 0 elements).
pub fn zeros(name: &'static str, tform: &str, width: usize, n: usize) -> Col {
    Col {
        name,
        tform: tform.into(),
        rows: vec![vec![0u8; width]; n],
    }
}

/// Appends one 80-character header card.
pub fn card(out: &mut Vec<u8>, s: &str) {
    let mut c = s.as_bytes().to_vec();
    c.resize(80, b' ');
    out.extend(c);
}

/// Pads to the next 2880-byte block with `fill` (blanks after a header,
/// zeros after binary data).
pub fn pad(out: &mut Vec<u8>, fill: u8) {
    while out.len() % 2880 != 0 {
        out.push(fill);
    }
}

/// An empty primary HDU, the start of every table file.
pub fn empty_primary() -> Vec<u8> {
    let mut out = Vec::new();
    for c in [
        "SIMPLE  =                    T",
        "BITPIX  =                    8",
        "NAXIS   =                    0",
        "EXTEND  =                    T",
        "END",
    ] {
        card(&mut out, c);
    }
    pad(&mut out, b' ');
    out
}

/// A FITS file: an empty primary HDU and one BINTABLE extension.
pub fn fits_table(cols: &[Col]) -> Vec<u8> {
    let n = cols.first().map_or(0, |c| c.rows.len());
    let width: usize = cols
        .iter()
        .map(|c| c.rows.first().map_or(0, Vec::len))
        .sum();
    let mut out = empty_primary();
    card(&mut out, "XTENSION= 'BINTABLE'");
    card(&mut out, "BITPIX  =                    8");
    card(&mut out, "NAXIS   =                    2");
    card(&mut out, &format!("NAXIS1  = {width:>20}"));
    card(&mut out, &format!("NAXIS2  = {n:>20}"));
    card(&mut out, "PCOUNT  =                    0");
    card(&mut out, "GCOUNT  =                    1");
    card(&mut out, &format!("TFIELDS = {:>20}", cols.len()));
    for (k, c) in cols.iter().enumerate() {
        card(&mut out, &format!("TTYPE{:<3}= '{}'", k + 1, c.name));
        card(&mut out, &format!("TFORM{:<3}= '{}'", k + 1, c.tform));
    }
    card(&mut out, "END");
    pad(&mut out, b' ');
    for r in 0..n {
        for c in cols {
            out.extend(&c.rows[r]);
        }
    }
    pad(&mut out, 0);
    out
}
