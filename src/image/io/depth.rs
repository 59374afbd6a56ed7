//! Depth and CoC maps: reading, inverse depth, scale and checks, radial to view-axis depth.

use super::*;

/// How to read a depth file: see [`read_depth`].
#[derive(Clone, Debug, PartialEq)]
pub struct DepthRead {
    /// EXR channel to read (a full name such as `ViewLayer.Depth.Z`, or a unique suffix such as
    /// `Z`); `None` searches for a depth channel.
    pub channel: Option<String>,
    /// Factor from the stored values to metres (e.g. the range of a 16-bit PNG). Default 1.
    pub scale: f32,
    /// True when the file holds radial distance from the eye rather than view-axis depth.
    /// [`read_depth`] does not convert (it needs the camera); the caller applies
    /// [`radial_to_view_depth`] when this is set. Default false.
    pub radial: bool,
    /// True when the file holds inverse depth, 1 / depth, with 0 for infinitely far, as Nuke's
    /// ScanlineRender writes its depth channel. [`read_depth`] inverts it (before the scale, so
    /// depth = scale / value). Default false.
    pub inverse: bool,
    /// True when a depth of exactly 0 means "no surface" (far away), as some renderers write
    /// the background; otherwise 0 is an error like any depth that is not positive. Default
    /// false.
    pub zero_is_far: bool,
}

impl Default for DepthRead {
    fn default() -> Self {
        Self {
            channel: None,
            scale: 1.0,
            radial: false,
            inverse: false,
            zero_is_far: false,
        }
    }
}

/// Reads a depth image in metres (stored value times `opts.scale`).
///
/// - `.exr`: the channel `opts.channel` (exact full name, else a unique suffix, see
///   [`ExrChannels::find_by_suffix`]); without it the first of these that matches, ignoring case:
///   `Z`, `depth`, `*.Depth.Z`, `*.Z`, `*.depth`. Several matches of one pattern (e.g. two view
///   layers) are an error listing them.
/// - `.pfm`: the grey channel, or the first (red) channel of a colour file.
/// - `.png`: grey or grey-alpha, 8 or 16 bits, read as value / 255 or value / 65535 (no sRGB
///   decoding; alpha ignored).
///
/// Every depth must be positive: `+inf` (no surface) becomes `f32::MAX` ("far"); NaN, zero and
/// negative values are an error naming the first bad pixel, its value and how many there are.
pub fn read_depth(path: &Path, opts: &DepthRead) -> Result<GrayImage> {
    if !(opts.scale.is_finite() && opts.scale > 0.0) {
        return Err(Error::invalid(
            "depth scale",
            format!(
                "{} for {}: expected a finite number > 0",
                opts.scale,
                shown(&path)
            ),
        ));
    }
    let (width, height, values, what) = match input_format(path, "depth path")? {
        FileFormat::Exr => {
            let channels = read_exr_channels(path)?;
            let (name, samples) = depth_channel(path, &channels, opts.channel.as_deref())?;
            let samples = samples.to_vec();
            (
                channels.width,
                channels.height,
                samples,
                format!("channel '{name}'"),
            )
        }
        FileFormat::Pfm => {
            let pfm = read_pfm(path)?;
            let what = if pfm.channels == 1 {
                "grey PFM"
            } else {
                "PFM red channel"
            };
            let values = pfm.data.iter().step_by(pfm.channels).copied().collect();
            (pfm.width, pfm.height, values, what.to_string())
        }
        FileFormat::Jpeg => {
            return Err(Error::format(
                path,
                "a JPEG cannot hold depth (lossy, 8 bits): expected EXR, PFM or 16-bit PNG",
            ))
        }
        FileFormat::Png => {
            let png = read_png(path)?;
            let values = depth_from_png(path, &png)?;
            (
                png.width,
                png.height,
                values,
                "PNG grey channel".to_string(),
            )
        }
    };
    depth_from_values(path, &what, width, height, values, opts)
}

/// Depth in metres from stored depth values (`width` x `height`, row-major), as [`read_depth`]
/// converts a file's: inverted when `opts.inverse`, times `opts.scale`, then checked (every
/// depth positive, +inf and, with `opts.zero_is_far`, 0 taken as far). Errors name `source` (a
/// file, or an array's name) and `what` (its channel). `opts.channel` and `opts.radial` are not
/// used here.
pub fn depth_from_values(
    source: &Path,
    what: &str,
    width: usize,
    height: usize,
    mut values: Vec<f32>,
    opts: &DepthRead,
) -> Result<GrayImage> {
    if !(opts.scale.is_finite() && opts.scale > 0.0) {
        return Err(Error::invalid(
            "depth scale",
            format!(
                "{} for {}: expected a finite number > 0",
                opts.scale,
                shown(&source)
            ),
        ));
    }
    if values.len() != width * height {
        return Err(Error::format(
            source,
            format!("{} depth values for a {width}x{height} image", values.len()),
        ));
    }
    if opts.inverse {
        invert_depth(source, what, width, &mut values)?;
    }
    if opts.scale != 1.0 {
        values.iter_mut().for_each(|v| *v *= opts.scale);
    }
    validate_depth(source, what, width, &mut values, opts.zero_is_far)?;
    GrayImage::from_vec(width, height, values)
}

/// The largest CoC radius in pixels a CoC map may hold, far beyond any blur a method renders
/// (each clamps its blur to `--max-coc`, at most 512 px): a larger value is a damaged map or a
/// renderer's "no value" (3.4e38, the largest float), not a blur, and the lens built from the
/// map would overflow.
pub const MAX_COC_MAP_PX: f32 = 1e6;

/// Describes the values of a CoC map (row-major, `width` pixels wide) that are no CoC radius
/// (NaN, infinite, or beyond [`MAX_COC_MAP_PX`] either way): how many, the first pixel and its
/// value, and what was expected; `None` when every value is a radius.
pub fn bad_coc_radii(values: &[f32], width: usize) -> Option<String> {
    let is_bad = |v: &f32| !(v.is_finite() && v.abs() <= MAX_COC_MAP_PX);
    let first = values.iter().position(is_bad)?;
    let bad = values.iter().filter(|v| is_bad(v)).count();
    let v = values[first];
    let value = if v.is_finite() {
        format!("{v:e} px")
    } else {
        format!("{v}")
    };
    let width = width.max(1);
    Some(format!(
        "{bad} pixel(s) are no CoC radius, the first at (x {}, y {}) = {value}; expected finite \
         signed radii in pixels, at most {MAX_COC_MAP_PX:e} in magnitude",
        first % width,
        first / width
    ))
}

/// Reads a map of signed CoC radii in pixels (negative in front of the focal plane), as
/// `blur --coc-out` writes it: from an OpenEXR file, the channel `channel` (a full name or a
/// unique suffix), else the one channel named `CoC` or ending in `.CoC`; from a PFM, the grey
/// (or red) channel. Every value must be a radius ([`bad_coc_radii`]); other formats are
/// refused (a PNG holds no signed values).
pub fn read_coc(path: &Path, channel: Option<&str>) -> Result<GrayImage> {
    let (width, height, values, what) =
        match input_format(path, "CoC path")? {
            FileFormat::Exr => {
                let channels = read_exr_channels(path)?;
                let want = channel.unwrap_or("CoC");
                let found = channels.find_by_suffix(want);
                let [(name, samples)] = found.as_slice() else {
                    return Err(Error::format(
                        path,
                        format!(
                            "expected one CoC channel '{want}' (a full name or a unique suffix); \
                         available channels: {}",
                            channels.name_list()
                        ),
                    ));
                };
                let what = format!("channel '{name}'");
                (channels.width, channels.height, samples.to_vec(), what)
            }
            FileFormat::Pfm => {
                let pfm = read_pfm(path)?;
                let values = pfm.data.iter().step_by(pfm.channels).copied().collect();
                (pfm.width, pfm.height, values, "PFM".to_string())
            }
            FileFormat::Png | FileFormat::Jpeg => return Err(Error::format(
                path,
                "a CoC map holds signed radii in pixels: expected OpenEXR or PFM, not PNG or JPEG",
            )),
        };
    if let Some(why) = bad_coc_radii(&values, width) {
        return Err(Error::format(path, format!("CoC {what}: {why}")));
    }
    GrayImage::from_vec(width, height, values)
}

/// Converts radial distance from the eye (what some renderers store as depth) to view-axis depth,
/// in place: z = d / sqrt(1 + ((x+0.5-cx)^2 + (y+0.5-cy)^2) / f_px^2) with the principal point
/// (cx, cy) = (width/2, height/2) and `f_px` the focal length in pixels.
///
/// `f_px` must be finite and positive (it comes from a validated camera); any other value leaves
/// the image unchanged.
pub fn radial_to_view_depth(depth: &mut GrayImage, f_px: f32) {
    let centre = (depth.width() as f64 / 2.0, depth.height() as f64 / 2.0);
    radial_to_view_depth_about(depth, f_px, centre);
}

/// [`radial_to_view_depth`] with the principal point at `centre` (x, y) in the image's pixel
/// coordinates: for an image that is part of a frame (an OpenEXR data window), the frame's
/// centre, which may lie outside the image.
pub fn radial_to_view_depth_about(depth: &mut GrayImage, f_px: f32, centre: (f64, f64)) {
    if !(f_px.is_finite() && f_px > 0.0) {
        return;
    }
    let (w, h) = (depth.width(), depth.height());
    let (cx, cy) = centre;
    let inv_f2 = 1.0 / (f_px as f64 * f_px as f64);
    for y in 0..h {
        let dy = y as f64 + 0.5 - cy;
        for x in 0..w {
            let dx = x as f64 + 0.5 - cx;
            let d = depth.get_mut(x, y);
            *d = (*d as f64 / (1.0 + (dx * dx + dy * dy) * inv_f2).sqrt()) as f32;
        }
    }
}
// ---------------------------------------------------------------------------------------------
// Depth validation and atomic writes
// ---------------------------------------------------------------------------------------------

/// Checks depth values in metres: `+inf` becomes `f32::MAX`; NaN, zero, negative values and
/// `-inf` are an error naming the first such pixel (x, y), its value and their count.
/// Replaces each value by `convert(value)`, or counts it as bad where that is `None`. Returns
/// the count and the first bad pixel `(x, y, value)`, if any.
pub(super) fn convert_values(
    values: &mut [f32],
    width: usize,
    convert: impl Fn(f32) -> Option<f32>,
) -> Option<(usize, usize, usize, f32)> {
    let mut bad = 0usize;
    let mut first = None;
    for (i, v) in values.iter_mut().enumerate() {
        match convert(*v) {
            Some(c) => *v = c,
            None => {
                bad += 1;
                first.get_or_insert((i % width, i / width, *v));
            }
        }
    }
    first.map(|(x, y, v)| (bad, x, y, v))
}

/// Inverse depth (1 / depth, 0 for infinitely far) to depth, in place. NaN, negative and
/// infinite values (an inverse of infinity would be a depth of 0) are an error naming the first.
pub(super) fn invert_depth(
    path: &Path,
    what: &str,
    width: usize,
    values: &mut [f32],
) -> Result<()> {
    let invert = |v: f32| match v {
        0.0 => Some(f32::INFINITY),
        v if v > 0.0 && v.is_finite() => Some(1.0 / v),
        _ => None,
    };
    match convert_values(values, width, invert) {
        None => Ok(()),
        Some((bad, x, y, v)) => Err(Error::format(
            path,
            format!(
                "inverse depth {what}: {bad} pixel(s) are not inverse depths, the first at \
                 (x {x}, y {y}) = {v}; expected 1 / depth >= 0 and finite (0 means far)"
            ),
        )),
    }
}

/// Every depth must be > 0 and finite, or +inf ("far"), which becomes `f32::MAX`, as does 0 when
/// `zero_is_far`; the others are an error naming the first and how many there are.
pub(super) fn validate_depth(
    path: &Path,
    what: &str,
    width: usize,
    values: &mut [f32],
    zero_is_far: bool,
) -> Result<()> {
    let positive = |v: f32| match v {
        f32::INFINITY => Some(f32::MAX),
        0.0 if zero_is_far => Some(f32::MAX),
        v if v > 0.0 && v.is_finite() => Some(v),
        _ => None,
    };
    match convert_values(values, width, positive) {
        None => Ok(()),
        Some((bad, x, y, v)) => Err(Error::format(
            path,
            format!(
                "depth {what}: {bad} pixel(s) are not positive depths, the first at (x {x}, y {y}) \
                 = {v}; expected depth > 0 in metres (+inf means far; if 0 marks the \
                 background, read 0 as far: `blur --zero-depth-is-far`)"
            ),
        )),
    }
}
