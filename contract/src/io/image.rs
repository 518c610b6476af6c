//! Public images read back (SPEC §4, `docs/run-layout.md`): the first
//! non-empty 2-D image of a file, primary HDU or HDU 1 of a tile-compressed
//! file, as ADU. The writer is the simulator's (`stepsim_sim::io::image_fits`).

use super::IoError;
use super::fits::open_fits;
use fitsio::hdu::HduInfo;
use std::path::Path;

/// An image read back from a file.
#[derive(Debug, Clone, PartialEq)]
pub struct FitsImage {
    /// NAXIS1.
    pub width: u32,
    /// NAXIS2.
    pub height: u32,
    /// Pixels (ADU), row-major.
    pub pixels: Vec<f32>,
}

/// Reads the first non-empty 2-D image of a file (primary HDU, or HDU 1 of
/// a tile-compressed file) as ADU.
pub fn read_image_fits(path: &Path) -> Result<FitsImage, IoError> {
    let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
    let mut f = open_fits(path)?;
    let n_hdus = f.num_hdus().map_err(fe)?;
    for i in 0..n_hdus {
        let hdu = f.hdu(i).map_err(fe)?;
        if let HduInfo::ImageInfo { shape, .. } = &hdu.info
            && shape.len() == 2
            && shape[0] > 0
            && shape[1] > 0
        {
            let (height, width) = (shape[0] as u32, shape[1] as u32);
            let pixels: Vec<f32> = hdu.read_image(&mut f).map_err(fe)?;
            return Ok(FitsImage {
                width,
                height,
                pixels,
            });
        }
    }
    Err(IoError::format(path, "no 2-D image in the file"))
}
