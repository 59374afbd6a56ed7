//! PNG and JPEG: 8/16-bit sRGB decoding to linear premultiplied colour, and PNG encoding.

use super::*;

/// A colour image from 8-bit sRGB samples (`channels` 1 to 4 per pixel: grey, grey-alpha, RGB,
/// RGBA; alpha straight), decoded as a PNG is: linear light, premultiplied by alpha.
pub fn color_from_srgb8(
    width: usize,
    height: usize,
    channels: usize,
    bytes: &[u8],
) -> Result<ColorImage> {
    if !(1..=4).contains(&channels) || bytes.len() != width * height * channels {
        return Err(Error::Mismatch(format!(
            "{} bytes for a {width}x{height} image of {channels} channels",
            bytes.len()
        )));
    }
    color_from_png(Png {
        width,
        height,
        channels,
        bits: 8,
        samples: bytes.iter().map(|&b| f32::from(b) / 255.0).collect(),
    })
}

// ---------------------------------------------------------------------------------------------
// PNG internals
// ---------------------------------------------------------------------------------------------

/// A decoded PNG: samples normalised to [0, 1], `channels` per pixel, row-major.
pub(super) struct Png {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) channels: usize,
    pub(super) bits: u32,
    pub(super) samples: Vec<f32>,
}

/// A PNG decoding error, with the path.
pub(super) fn png_error(path: &Path, err: image::ImageError) -> Error {
    match err {
        image::ImageError::IoError(e) if e.kind() != std::io::ErrorKind::UnexpectedEof => {
            Error::io(path, e)
        }
        other => Error::format(
            path,
            format!("not a readable PNG file (corrupt or truncated?): {other}"),
        ),
    }
}

/// Decodes a PNG to normalised samples, checking the size from the header first.
/// Reads an 8-bit greyscale or RGB JPEG into the [`Png`] form (samples in [0, 1], sRGB-encoded:
/// [`color_from_png`] decodes them).
pub(super) fn read_jpeg(path: &Path) -> Result<Png> {
    let err = |e: image::ImageError| Error::format(path, format!("not a readable JPEG file: {e}"));
    let decoder =
        image::codecs::jpeg::JpegDecoder::new(BufReader::new(open(path)?)).map_err(err)?;
    let (w, h) = decoder.dimensions();
    let (width, height) = (w as usize, h as usize);
    check_file_size(path, width, height)?;
    let channels = match decoder.color_type() {
        ColorType::L8 => 1,
        ColorType::Rgb8 => 3,
        other => {
            return Err(Error::format(
                path,
                format!("unsupported JPEG pixel type {other:?}: expected greyscale or RGB"),
            ))
        }
    };
    let total = usize::try_from(decoder.total_bytes()).map_err(|_| {
        Error::format(
            path,
            "JPEG image data is too large for this machine's memory",
        )
    })?;
    let mut bytes = vec![0u8; total];
    decoder.read_image(&mut bytes).map_err(err)?;
    Ok(Png {
        width,
        height,
        channels,
        bits: 8,
        samples: bytes.iter().map(|&b| b as f32 / 255.0).collect(),
    })
}

pub(super) fn read_png(path: &Path) -> Result<Png> {
    let decoder = image::codecs::png::PngDecoder::new(BufReader::new(open(path)?))
        .map_err(|e| png_error(path, e))?;
    let (w, h) = decoder.dimensions();
    let (width, height) = (w as usize, h as usize);
    check_file_size(path, width, height)?;
    let color = decoder.color_type();
    let (channels, bits) = match color {
        ColorType::L8 => (1, 8),
        ColorType::La8 => (2, 8),
        ColorType::Rgb8 => (3, 8),
        ColorType::Rgba8 => (4, 8),
        ColorType::L16 => (1, 16),
        ColorType::La16 => (2, 16),
        ColorType::Rgb16 => (3, 16),
        ColorType::Rgba16 => (4, 16),
        other => {
            return Err(Error::format(
                path,
                format!("unsupported PNG pixel type {other:?}: expected 8 or 16 bits per sample"),
            ))
        }
    };
    let total = usize::try_from(decoder.total_bytes()).map_err(|_| {
        Error::format(
            path,
            "PNG image data is too large for this machine's memory",
        )
    })?;
    let mut bytes = vec![0u8; total];
    decoder
        .read_image(&mut bytes)
        .map_err(|e| png_error(path, e))?;
    let samples = if bits == 8 {
        bytes.iter().map(|&b| b as f32 / 255.0).collect()
    } else {
        bytes
            .chunks_exact(2)
            .map(|c| u16::from_ne_bytes([c[0], c[1]]) as f32 / 65535.0)
            .collect()
    };
    Ok(Png {
        width,
        height,
        channels,
        bits,
        samples,
    })
}

/// Linear premultiplied RGBA from a decoded PNG: colour sRGB-decoded, times alpha as stored.
pub(super) fn color_from_png(png: Png) -> Result<ColorImage> {
    let c = png.channels;
    let pixels: Vec<Rgba> = png
        .samples
        .chunks_exact(c)
        .map(|s| {
            let (rgb, a) = match c {
                1 => ([s[0]; 3], 1.0),
                2 => ([s[0]; 3], s[1]),
                3 => ([s[0], s[1], s[2]], 1.0),
                _ => ([s[0], s[1], s[2]], s[3]),
            };
            [
                srgb_decode(rgb[0]) * a,
                srgb_decode(rgb[1]) * a,
                srgb_decode(rgb[2]) * a,
                a,
            ]
        })
        .collect();
    ColorImage::from_vec(png.width, png.height, pixels)
}

/// Depth samples (value / max) from a grey PNG.
pub(super) fn depth_from_png(path: &Path, png: &Png) -> Result<Vec<f32>> {
    if png.channels > 2 {
        return Err(Error::format(
            path,
            format!(
                "depth PNG has {} channels ({}-bit colour): expected a grey image (one channel, \
                 optionally with alpha)",
                png.channels, png.bits
            ),
        ));
    }
    Ok(png.samples.iter().step_by(png.channels).copied().collect())
}

/// 8-bit straight sRGB RGBA samples of `img` (4 bytes a pixel), as [`write_color`] writes PNG.
pub fn png8_samples(img: &ColorImage) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(img.pixels().len() * 4);
    for p in img.pixels() {
        bytes.extend(straight_srgb(*p).map(|v| quantize(v, 255.0) as u8));
    }
    bytes
}

/// Encodes already-quantised PNG samples of `img`'s size to `out`.
pub(super) fn png_encode(
    out: impl Write,
    img: &ColorImage,
    bytes: &[u8],
    color: ExtendedColorType,
) -> std::result::Result<(), image::ImageError> {
    let (w, h) = (img.width() as u32, img.height() as u32);
    image::codecs::png::PngEncoder::new(out).write_image(bytes, w, h, color)
}

/// Stages already-quantised PNG samples of `img`'s size for `path`.
pub(super) fn write_png(
    set: &mut OutputSet,
    path: &Path,
    img: &ColorImage,
    bytes: &[u8],
    color: ExtendedColorType,
) -> Result<()> {
    set.write(path, |out| {
        png_encode(out, img, bytes, color).map_err(|e| match e {
            image::ImageError::IoError(e) => Error::io(path, e),
            other => Error::format(path, format!("could not write PNG: {other}")),
        })
    })
}

/// A premultiplied linear pixel as PNG wants it, each value in [0, 1] (NaN aside): straight
/// sRGB-encoded colour and clamped alpha. Colour is 0 where alpha is 0.
#[inline]
pub(super) fn straight_srgb(p: Rgba) -> [f32; 4] {
    let a = if p[3].is_nan() {
        0.0
    } else {
        p[3].clamp(0.0, 1.0)
    };
    let straight = |c: f32| if a > 0.0 { srgb_encode(c / a) } else { 0.0 };
    [straight(p[0]), straight(p[1]), straight(p[2]), a]
}

/// `v` clamped to [0, 1], scaled by `max` and rounded (NaN becomes 0).
#[inline]
pub(super) fn quantize(v: f32, max: f32) -> f32 {
    if v.is_nan() {
        return 0.0;
    }
    (v.clamp(0.0, 1.0) * max + 0.5).floor()
}
