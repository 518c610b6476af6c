//! A 2-D image in electrons, row-major with x (NAXIS1) fastest.

/// An image: `data[iy * width + ix]` is the pixel whose centre is at array
/// coordinate `(ix, iy)`, i.e. FITS pixel `(ix + 1, iy + 1)`. Values are
/// electrons.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// NAXIS1.
    pub width: usize,
    /// NAXIS2.
    pub height: usize,
    /// Pixel values, `width × height`, row-major.
    pub data: Vec<f32>,
}

impl Image {
    /// A zero image.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// Wraps existing data; `None` if its length is not `width × height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// The value at `(ix, iy)`.
    #[inline]
    pub fn at(&self, ix: usize, iy: usize) -> f32 {
        self.data[iy * self.width + ix]
    }

    /// Mutable value at `(ix, iy)`.
    #[inline]
    pub fn at_mut(&mut self, ix: usize, iy: usize) -> &mut f32 {
        &mut self.data[iy * self.width + ix]
    }

    /// The image multiplied by `factor` (ADU → electrons with the gain).
    pub fn scaled(mut self, factor: f32) -> Self {
        for v in &mut self.data {
            *v *= factor;
        }
        self
    }
}
