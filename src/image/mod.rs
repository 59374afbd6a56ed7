//! Image types and file I/O.
//!
//! Pixels are linear-light `f32`. [`Rgba`] images hold premultiplied colour with alpha (as
//! EXR does): RGB is the colour seen over black, alpha the coverage. PNG files store straight
//! alpha and are converted when read and written. Row 0 is the top of the image; pixel (i, j) covers
//! [i, i+1) x [j, j+1).

pub mod io;

use std::mem::MaybeUninit;

use rayon::prelude::*;

use crate::{Error, Result};

/// A linear-light RGBA pixel, colour premultiplied by alpha.
pub type Rgba = [f32; 4];

/// Largest image we accept, in pixels (about 1 GiB of RGBA f32): larger inputs are refused with an
/// error instead of exhausting memory.
pub const MAX_PIXELS: usize = 1 << 26;

/// A 2D image stored row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<P> {
    width: usize,
    height: usize,
    data: Vec<P>,
}

/// Colour image (linear RGBA, premultiplied alpha).
pub type ColorImage = Image<Rgba>;
/// Single-channel image, e.g. view-axis depth in metres.
pub type GrayImage = Image<f32>;

/// Checks a requested image size: both sides non-zero and the pixel count below [`MAX_PIXELS`].
pub fn check_size(width: usize, height: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::invalid(
            "image size",
            format!("{width}x{height}: width and height must be at least 1 pixel"),
        ));
    }
    match width.checked_mul(height) {
        Some(n) if n <= MAX_PIXELS => Ok(()),
        _ => Err(Error::invalid(
            "image size",
            format!("{width}x{height} is larger than the limit of {MAX_PIXELS} pixels"),
        )),
    }
}

impl<P: Copy> Image<P> {
    /// An image filled with `value`. Panics only if `width * height` overflows; validate sizes
    /// from users with [`check_size`] first.
    pub fn new(width: usize, height: usize, value: P) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Wraps row-major pixel data. Fails if the length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<P>) -> Result<Self> {
        if data.len() != width * height {
            return Err(Error::Mismatch(format!(
                "{} pixels given for a {width}x{height} image",
                data.len()
            )));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// The `width x height` part whose top-left pixel is `(x0, y0)`. Panics when it does not
    /// lie inside the image.
    pub fn crop(&self, x0: usize, y0: usize, width: usize, height: usize) -> Self {
        assert!(x0 + width <= self.width && y0 + height <= self.height);
        let mut data = Vec::with_capacity(width * height);
        for y in y0..y0 + height {
            let row = y * self.width + x0;
            data.extend_from_slice(&self.data[row..row + width]);
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Pixel at column `x`, row `y`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> P {
        self.data[y * self.width + x]
    }

    /// Mutable pixel at column `x`, row `y`.
    #[inline]
    pub fn get_mut(&mut self, x: usize, y: usize) -> &mut P {
        &mut self.data[y * self.width + x]
    }

    /// Pixel at (x, y) with coordinates clamped to the image.
    #[inline]
    pub fn get_clamped(&self, x: isize, y: isize) -> P {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.get(x, y)
    }

    /// All pixels, row-major.
    pub fn pixels(&self) -> &[P] {
        &self.data
    }

    /// All pixels, row-major, mutable.
    pub fn pixels_mut(&mut self) -> &mut [P] {
        &mut self.data
    }

    /// Row `y`.
    pub fn row(&self, y: usize) -> &[P] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Consumes the image, returning its pixels.
    pub fn into_vec(self) -> Vec<P> {
        self.data
    }

    /// Applies `f` to every pixel, giving a new image.
    pub fn map<Q: Copy>(&self, f: impl Fn(P) -> Q) -> Image<Q> {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&p| f(p)).collect(),
        }
    }

    /// True when both images have the same size.
    pub fn same_size<Q>(&self, other: &Image<Q>) -> bool {
        self.width == other.width && self.height == other.height
    }
}

impl<P: Copy + Send + Sync> Image<P> {
    /// A `width` x `height` image whose rows are written in parallel by `fill(state, y, row)`,
    /// straight into fresh memory, with `state` made by `init` once per worker (scratch rows).
    /// Returns the image and whether any call of `fill` returned true (e.g. bad input seen).
    ///
    /// The memory is not filled with a constant first. For a full-resolution frame that fill
    /// is a whole extra pass of writes: on the 1280x720 benchmark frame, reading colour and depth
    /// and writing one colour image took 1.41 ms after a zero fill and 0.76 ms without.
    ///
    /// Fails as [`check_size`] does.
    ///
    /// # Safety
    /// `fill` must write every element of the row it is given before it returns (it may panic
    /// instead: the panic reaches the caller and no image is made).
    pub(crate) unsafe fn par_from_rows<S>(
        width: usize,
        height: usize,
        init: impl Fn() -> S + Sync + Send,
        fill: impl Fn(&mut S, usize, &mut [MaybeUninit<P>]) -> bool + Sync + Send,
    ) -> Result<(Self, bool)> {
        check_size(width, height)?;
        // SAFETY: the caller's `fill` writes every element of its row, which is the whole band.
        Ok(unsafe { Self::par_from_bands(width, height, 1, init, fill) })
    }

    /// [`Image::par_from_rows`] a band of `band` rows at a time, without its size check (for an
    /// image the size of one that exists): `fill(state, y0, rows)` gets the rows `y0..` of one
    /// band (the last may be shorter), flattened.
    ///
    /// # Safety
    /// `fill` must write every element of the rows it is given before it returns (it may panic
    /// instead: the panic reaches the caller and no image is made).
    pub(crate) unsafe fn par_from_bands<S>(
        width: usize,
        height: usize,
        band: usize,
        init: impl Fn() -> S + Sync + Send,
        fill: impl Fn(&mut S, usize, &mut [MaybeUninit<P>]) -> bool + Sync + Send,
    ) -> (Self, bool) {
        let n = width * height;
        let band = band.max(1);
        let mut data: Vec<P> = Vec::with_capacity(n);
        let flag = data.spare_capacity_mut()[..n]
            .par_chunks_mut((width * band).max(1))
            .enumerate()
            .map_init(init, |state, (b, rows)| fill(state, b * band, rows))
            .reduce(|| false, |a, b| a | b);
        // SAFETY: the bands `par_chunks_mut` handed out cover `0..n`, and the caller's `fill`
        // wrote every element of each before returning (a panic would have left this function
        // before here).
        unsafe { data.set_len(n) };
        let image = Self {
            width,
            height,
            data,
        };
        (image, flag)
    }
}

/// Luminance of a linear colour with Rec. 709 / sRGB primaries.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// sRGB transfer function: linear light to encoded, input clamped to [0, 1].
#[inline]
pub fn srgb_encode(linear: f32) -> f32 {
    let c = linear.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// sRGB transfer function: encoded in [0, 1] to linear light.
#[inline]
pub fn srgb_decode(encoded: f32) -> f32 {
    if encoded <= 0.040_45 {
        encoded / 12.92
    } else {
        ((encoded + 0.055) / 1.055).powf(2.4)
    }
}
