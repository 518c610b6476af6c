//! The header keywords of truth tables, built in one place for `generate`
//! (one table per image) and `stepsim catalog` (one per base field).

use stepsim_contract::io::truth::Keyword;

/// The keywords naming a base field in a truth table's header: `FIELD`
/// and `ROTATED` (the one place they are built: `generate` and `stepsim catalog`
/// both write them).
pub fn field_keywords(field: u32, rotated: bool) -> Vec<Keyword> {
    vec![
        ("FIELD".to_string(), f64::from(field), "base field".into()),
        (
            "ROTATED".to_string(),
            f64::from(u8::from(rotated)),
            "1: 90-degree rotated twin".into(),
        ),
    ]
}

/// The header keywords of a run's truth table: [`field_keywords`], the PSF
/// index and the applied shear.
pub fn truth_keywords(field: u32, rotated: bool, psf: usize, g1: f64, g2: f64) -> Vec<Keyword> {
    let mut k = field_keywords(field, rotated);
    k.push(("PSF_ID".to_string(), psf as f64, "index in psfs".into()));
    k.push(("G1".to_string(), g1, "applied reduced shear".into()));
    k.push(("G2".to_string(), g2, "applied reduced shear".into()));
    k
}
