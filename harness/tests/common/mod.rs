//! Shared by the hostile-input tests: a small image index and FITS tables
//! written byte by byte (the writer is `tests/common/fits_table.rs`, shared
//! with the binary's tests).
#![allow(dead_code)]

use std::path::Path;
#[path = "../../../tests/common/fits_table.rs"]
mod fits_table;
pub use fits_table::*;
use stepsim_contract::run_layout::{DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets};
use stepsim_harness::ImageIndex;

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

/// A gzip member of `data` (real CRC-32 and size), deflated at `level`.
pub fn gzip(data: &[u8], level: u8) -> Vec<u8> {
    let mut v = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3];
    v.extend(miniz_oxide::deflate::compress_to_vec(data, level));
    v.extend(crc32fast::hash(data).to_le_bytes());
    v.extend((data.len() as u32).to_le_bytes());
    v
}
