//! Why an object got zero weight: the bits of the `flags` column of a
//! submission. An object with `flags == 0` has a positive weight.
//!
//! | bit | value | name | meaning |
//! |---|---|---|---|
//! | 0 | 1 | `EDGE` | footprint on the border or weight window beyond the image |
//! | 1 | 2 | `SATURATED` | a footprint pixel at or above saturation; metadetection: also, on each version, within 32 px of a saturated detection or of a star of S/N ≥ 500 |
//! | 2 | 4 | `BLENDED` | split from a footprint with another peak within `deblend_flag_px`, another object within `close_pair_px`, or two detections merged (KSB+); metacal: its unsheared version shows a second peak within `close_pair_px` (`metacal::neighbour_peak`) |
//! | 3 | 8 | `CENTROID` | windowed centroid did not converge or moved > `centroid_max_shift_px` (metacal: on its unsheared version, from the detection's position) |
//! | 4 | 16 | `MOMENTS` | weighted flux or trace not positive, or a singular tensor |
//! | 5 | 32 | `SMALL` | r_g (or the PSF-corrected size, `size_cut`) ≤ `size_min_factor` × r_g* (star-like or smaller) |
//! | 6 | 64 | `LARGE` | r_g reached `rg_max_px` |
//! | 7 | 128 | `LOW_SN` | Gaussian-weighted S/N ν < `ksb_min_sn` (KSB+) or the unsheared version's < `min_sn` (metacal) |
//! | 8 | 256 | `PGAMMA` | ½Tr P^γ < `min_pgamma` |
//! | 9 | 512 | `BIG_SHEAR` | |γ̂| ≥ `max_shear` (written as 0 beyond the submission range, `stepsim_contract::MAX_ABS_SHEAR`) |
//! | 10 | 1024 | `NO_PSF` | too few stars for a PSF model on this image |
//! | 11 | 2048 | `SHIFTED` | KSB+: the windowed centroid lies ≥ `ksb_max_peak_shift_px` from the smoothed image's peak (a blend the detection did not split; as the *ellipto* pipeline of STEP1 flags a centroid that moved) |

/// Footprint on the border or window beyond the image.
pub const EDGE: u32 = 1;
/// Saturated pixel in the footprint.
pub const SATURATED: u32 = 2;
/// Deblended or close pair.
pub const BLENDED: u32 = 4;
/// Centroid failed.
pub const CENTROID: u32 = 8;
/// Moments failed.
pub const MOMENTS: u32 = 16;
/// Too small (r_g, or the size `size_cut` names, ≤ size_min_factor × r_g*).
pub const SMALL: u32 = 32;
/// Too large (r_g at rg_max).
pub const LARGE: u32 = 64;
/// Too faint (ν < ksb_min_sn for KSB+; the unsheared version's ν < min_sn for
/// metacal).
pub const LOW_SN: u32 = 128;
/// P^γ too small.
pub const PGAMMA: u32 = 256;
/// |γ̂| too large.
pub const BIG_SHEAR: u32 = 512;
/// No PSF model.
pub const NO_PSF: u32 = 1024;
/// KSB+: centroid shifted from the peak (an unsplit blend).
pub const SHIFTED: u32 = 2048;

/// Flags that disqualify an object from the star sample and the PSF model.
pub const NOT_FOR_PSF: u32 = EDGE | SATURATED | BLENDED | CENTROID | MOMENTS | LARGE;

#[cfg(test)]
mod tests {
    /// Names of the bits, lowest first.
    const NAMES: [&str; 12] = [
        "EDGE",
        "SATURATED",
        "BLENDED",
        "CENTROID",
        "MOMENTS",
        "SMALL",
        "LARGE",
        "LOW_SN",
        "PGAMMA",
        "BIG_SHEAR",
        "NO_PSF",
        "SHIFTED",
    ];

    #[test]
    fn bits_are_distinct_and_named_in_order() {
        let all = [
            super::EDGE,
            super::SATURATED,
            super::BLENDED,
            super::CENTROID,
            super::MOMENTS,
            super::SMALL,
            super::LARGE,
            super::LOW_SN,
            super::PGAMMA,
            super::BIG_SHEAR,
            super::NO_PSF,
            super::SHIFTED,
        ];
        for (i, b) in all.iter().enumerate() {
            assert_eq!(*b, 1 << i, "{}", NAMES[i]);
        }
    }
}
