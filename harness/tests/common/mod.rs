//! Shared by the hostile-input tests: a small image index and FITS tables
//! written byte by byte (so that column types `fitsio` cannot write, such as
//! variable-length `P`/`Q` and complex `C`/`M`, can be tested).
#![allow(dead_code)]

use std::path::Path;
use stepsim_harness::truth_set::ImageIndex;
use stepsim_sim::run_layout::{DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets};

/// Two images `imA`, `imB` of 100 × 80 pixels.
pub fn index() -> ImageIndex {
    let ds = Datasets {
        format: DATASETS_FORMAT.into(),
        width_px: 100,
        height_px: 80,
        pixel_scale_arcsec: 0.2,
        datasets: vec![DatasetEntry {
            part: Default::default(),
            dataset: "dA".into(),
            psf_id: 0,
            psf: "none".into(),
            g1: 0.01,
            g2: 0.0,
            images: ["imA", "imB"]
                .iter()
                .enumerate()
                .map(|(k, i)| DatasetImage {
                    image: (*i).into(),
                    field: k as u32,
                    rotated: false,
                })
                .collect(),
        }],
    };
    ImageIndex::new(&ds, Path::new("datasets.json")).unwrap()
}

/// One column of a hand-written binary table: name, TFORM, and the bytes
/// of each row's field (big-endian, as FITS stores them).
pub struct Col {
    pub name: &'static str,
    pub tform: &'static str,
    pub rows: Vec<Vec<u8>>,
}

pub fn doubles(name: &'static str, v: &[f64]) -> Col {
    Col {
        name,
        tform: "D",
        rows: v.iter().map(|x| x.to_be_bytes().to_vec()).collect(),
    }
}

pub fn text(name: &'static str, v: &[&str]) -> Col {
    Col {
        name,
        tform: "8A",
        rows: v
            .iter()
            .map(|s| {
                let mut b = s.as_bytes().to_vec();
                b.resize(8, b' ');
                b
            })
            .collect(),
    }
}

/// A column of any TFORM whose row fields are `width` zero bytes (for
/// variable-length columns: a descriptor of 0 elements).
pub fn zeros(name: &'static str, tform: &'static str, width: usize, n: usize) -> Col {
    Col {
        name,
        tform,
        rows: vec![vec![0u8; width]; n],
    }
}

fn card(out: &mut Vec<u8>, s: &str) {
    let mut c = s.as_bytes().to_vec();
    c.resize(80, b' ');
    out.extend(c);
}

fn pad(out: &mut Vec<u8>, fill: u8) {
    while out.len() % 2880 != 0 {
        out.push(fill);
    }
}

/// A FITS file: an empty primary HDU and one BINTABLE extension.
pub fn fits_table(cols: &[Col]) -> Vec<u8> {
    let n = cols.first().map_or(0, |c| c.rows.len());
    let width: usize = cols
        .iter()
        .map(|c| c.rows.first().map_or(0, Vec::len))
        .sum();
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

/// A valid three-row table (`imA`, `imB`, `imA`) plus `extra` columns.
pub fn good_table(extra: Vec<Col>) -> Vec<u8> {
    let mut cols = vec![
        text("IMAGE", &["imA", "imB", "imA"]),
        doubles("X", &[1.0, 2.0, 3.0]),
        doubles("Y", &[5.0, 5.0, 5.0]),
        doubles("E1", &[0.1, 0.2, 0.3]),
        doubles("E2", &[0.0, 0.0, 0.0]),
    ];
    cols.extend(extra);
    fits_table(&cols)
}
