//! Reading and writing images: OpenEXR, PNG and PFM, chosen by the file extension
//! (case-insensitive).
//!
//! Conventions (see `DESIGN.md`):
//! 1. Pixels in memory are linear light with premultiplied alpha. EXR (premultiplied by its own
//!    convention) and PFM (no alpha) are read and written as they are. PNG stores sRGB-encoded,
//!    straight colour: reading decodes, then multiplies by alpha; writing divides by alpha, then
//!    encodes. Alpha itself is never sRGB-coded. Depth read from a PNG is a plain number.
//! 2. Row 0 is the top of the image. PFM stores its rows bottom to top; they are flipped here.
//! 3. A file's size is checked against [`MAX_PIXELS`](super::MAX_PIXELS) from its header, before
//!    any pixel memory is allocated.
//! 4. Every error names the file; format errors also name the field or channel and what was
//!    expected. Nothing here panics on a bad file.
//! 5. Every write is atomic and goes through [`crate::output`]: the data goes to a staged file
//!    in the target's folder, renamed over the target only when complete (with the other outputs
//!    of an [`OutputSet`]). On any error the staged file is removed, so a failed write leaves
//!    neither partial output nor litter, and errors name the target.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, LayerAttributes,
    ReadChannels, ReadLayers, SmallVec, Text, Vec2, WritableImage,
};
use image::{ColorType, ExtendedColorType, ImageDecoder, ImageEncoder};

use super::{check_size, srgb_decode, srgb_encode, ColorImage, GrayImage, Rgba};
use crate::error::shown;
pub use crate::output::OutputSet;
use crate::{Error, Result};

/// Compression of written OpenEXR files: the lossless ones Blender and Nuke read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ExrCompression {
    /// No compression: the fastest to write, the largest files. The default: measured on a
    /// 1280x720 RGBA f32 frame on 2 cores (benches/image_io.rs), none takes 17 ms, rle 32 ms,
    /// zip 68 ms, zips 71 ms, piz 92 ms, and only none stays within the 30 ms budget.
    #[default]
    None,
    /// Run-length encoding: fast, small only for flat images.
    Rle,
    /// Deflate over single scanlines (ZIPS).
    Zips,
    /// Deflate over blocks of 16 scanlines (ZIP): small files.
    Zip,
    /// Wavelet + Huffman over blocks of 32 scanlines (PIZ): small for noisy, grainy images.
    Piz,
}

impl ExrCompression {
    /// Every compression, for benchmarks and tests.
    pub const ALL: [ExrCompression; 5] = [
        ExrCompression::None,
        ExrCompression::Rle,
        ExrCompression::Zips,
        ExrCompression::Zip,
        ExrCompression::Piz,
    ];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ExrCompression::None => "none",
            ExrCompression::Rle => "rle",
            ExrCompression::Zips => "zips",
            ExrCompression::Zip => "zip",
            ExrCompression::Piz => "piz",
        }
    }

    fn encoding(self) -> Encoding {
        use exr::prelude::{Blocks, Compression, LineOrder};
        let compression = match self {
            ExrCompression::None => Compression::Uncompressed,
            ExrCompression::Rle => Compression::RLE,
            ExrCompression::Zips => Compression::ZIP1,
            ExrCompression::Zip => Compression::ZIP16,
            ExrCompression::Piz => Compression::PIZ,
        };
        Encoding {
            compression,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        }
    }
}

/// How OpenEXR files are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ExrOptions {
    /// Compression (lossless).
    pub compression: ExrCompression,
    /// Store colour as 16-bit half floats instead of 32-bit floats (depth always stays 32-bit).
    pub half: bool,
    /// Where the image lies in its frame. `None`: it is the whole frame, at (0, 0).
    pub placement: Option<Placement>,
}

/// Where an image's pixels lie in its frame, as an OpenEXR file records it: the stored pixels
/// (the data window) start at `data_origin`, and the frame (the display window) starts at
/// `display_origin` and is `display_size` pixels, all in the file's pixel coordinates (x right,
/// y down). Compositors write a data window smaller than the frame (a bounding box) or larger
/// (overscan); pixel (0, 0) of the image read from the file is at `data_origin`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Placement {
    /// The data window's top-left pixel.
    pub data_origin: (i32, i32),
    /// The display window's top-left pixel.
    pub display_origin: (i32, i32),
    /// The display window's width and height in pixels.
    pub display_size: (usize, usize),
}

impl Placement {
    /// A `width` x `height` image that is its whole frame, at (0, 0).
    pub fn full(width: usize, height: usize) -> Self {
        Self {
            data_origin: (0, 0),
            display_origin: (0, 0),
            display_size: (width, height),
        }
    }

    /// The image's top-left pixel relative to the frame's.
    pub fn offset(&self) -> (i64, i64) {
        (
            i64::from(self.data_origin.0) - i64::from(self.display_origin.0),
            i64::from(self.data_origin.1) - i64::from(self.display_origin.1),
        )
    }

    /// Whether a `width` x `height` image so placed is exactly its frame.
    pub fn is_full(&self, width: usize, height: usize) -> bool {
        self.offset() == (0, 0) && self.display_size == (width, height)
    }

    /// The frame's centre pixel as a pixel of the image, clamped into a `width` x `height`
    /// image (the centre of a frame the image does not cover is its nearest pixel).
    pub fn frame_centre_in_image(&self, width: usize, height: usize) -> (usize, usize) {
        let (ox, oy) = self.offset();
        let at = |size: usize, origin: i64, n: usize| {
            (size as i64 / 2 - origin).clamp(0, n as i64 - 1) as usize
        };
        (
            at(self.display_size.0, ox, width),
            at(self.display_size.1, oy, height),
        )
    }
}

/// The placement of the image in an OpenEXR file (its first layer's data window in the display
/// window), read from the header alone; `None` when the file is not OpenEXR by its content.
pub fn read_exr_placement(path: &Path) -> Result<Option<Placement>> {
    if input_format(path, "input image")? != FileFormat::Exr {
        return Ok(None);
    }
    check_exr_windows(path)?;
    let meta = exr::meta::MetaData::read_from_buffered(BufReader::new(open(path)?), false)
        .map_err(|e| exr_read_error(path, e))?;
    let Some(header) = meta.headers.first() else {
        return Err(Error::format(path, "the OpenEXR file has no layers"));
    };
    let display = header.shared_attributes.display_window;
    let data = header.own_attributes.layer_position;
    Ok(Some(Placement {
        data_origin: (data.0, data.1),
        display_origin: (display.position.0, display.position.1),
        display_size: (display.size.0, display.size.1),
    }))
}

/// The file formats this module reads and writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FileFormat {
    Exr,
    Png,
    Pfm,
    /// Read only (a photo or a render preview as colour input); never written: lossy.
    Jpeg,
}

/// The format of `path` from its extension, or an error naming the path and the supported ones.
fn file_format(path: &Path, role: &'static str) -> Result<FileFormat> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("exr") => Ok(FileFormat::Exr),
        Some("png") => Ok(FileFormat::Png),
        Some("pfm") => Ok(FileFormat::Pfm),
        Some("jpg" | "jpeg") => Ok(FileFormat::Jpeg),
        other => Err(Error::invalid(
            role,
            format!(
                "{}: {}; expected one of .exr, .png, .pfm",
                shown(&path),
                match other {
                    Some(e) => format!("unsupported extension '.{e}'"),
                    None => "no file extension".to_string(),
                }
            ),
        )),
    }
}

/// The format of an existing file from its first bytes (PNG signature, OpenEXR magic number,
/// PFM header), or `None` when it is none of them or cannot be read.
fn sniff(path: &Path) -> Option<FileFormat> {
    let mut head = [0u8; 4];
    let mut f = File::open(path).ok()?;
    let n = f.read(&mut head).ok()?;
    match &head[..n] {
        [0x89, b'P', b'N', b'G'] => Some(FileFormat::Png),
        [0x76, 0x2f, 0x31, 0x01] => Some(FileFormat::Exr),
        [b'P', b'F' | b'f', c, _] if c.is_ascii_whitespace() => Some(FileFormat::Pfm),
        [0xFF, 0xD8, 0xFF, _] => Some(FileFormat::Jpeg),
        _ => None,
    }
}

/// The format of an input file: from its content when recognised (a PNG named `.exr` is read
/// as the PNG it is), else from its extension.
fn input_format(path: &Path, role: &'static str) -> Result<FileFormat> {
    match sniff(path) {
        Some(f) => Ok(f),
        None => file_format(path, role),
    }
}

/// Bytes a pixel of a decoded image can take at the peak of a read: the image (RGBA, 4 floats)
/// and the decoder's own buffer of the file's samples (up to as many again).
const DECODE_BYTES_PER_PIXEL: u64 = 32;

/// How far into an OpenEXR file its headers are searched for their windows (headers come first
/// and are small; a window past this is left to the decoder).
const EXR_HEADER_SEARCH_BYTES: u64 = 1 << 16;

/// Refuses an OpenEXR file whose data or display window is inverted (a maximum below its
/// minimum), naming the window and its corners, which the decoder would turn into a wrong
/// size. The windows are `box2i` attributes: the name, `box2i`, the size 16, then xMin, yMin,
/// xMax, yMax as little-endian 32-bit integers.
fn check_exr_windows(path: &Path) -> Result<()> {
    let mut head = Vec::new();
    open(path)?
        .take(EXR_HEADER_SEARCH_BYTES)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    for name in ["dataWindow", "displayWindow"] {
        let key = format!("{name}\0box2i\0");
        let key = key.as_bytes();
        let mut from = 0;
        while let Some(at) = head[from..].windows(key.len()).position(|w| w == key) {
            let start = from + at + key.len();
            from = start;
            let Some(b) = head.get(start..start + 20) else {
                break;
            };
            if b[..4] != 16u32.to_le_bytes() {
                continue;
            }
            let v = |k: usize| {
                i32::from_le_bytes([b[4 + 4 * k], b[5 + 4 * k], b[6 + 4 * k], b[7 + 4 * k]])
            };
            let (x0, y0, x1, y1) = (v(0), v(1), v(2), v(3));
            if x1 < x0 || y1 < y0 {
                return Err(Error::format(
                    path,
                    format!(
                        "{name} from ({x0}, {y0}) to ({x1}, {y1}) is inverted: expected its maximum corner at or after its minimum"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// [`check_size`] for a size read from a file header: the error names the file. The decoded
/// size is also held against the memory budget ([`crate::budget`]) before any pixel memory is
/// allocated (a small compressed file can claim a huge image).
fn check_file_size(path: &Path, width: usize, height: usize) -> Result<()> {
    check_size(width, height).map_err(|e| {
        let reason = match e {
            Error::Invalid { message, .. } => message,
            other => other.to_string(),
        };
        Error::format(path, format!("image size from the header: {reason}"))
    })?;
    crate::budget::check(
        (width * height) as u64 * DECODE_BYTES_PER_PIXEL,
        &format!("decoding {} ({width}x{height})", shown(&path)),
        "the image's size",
    )
}

/// Opens a file for reading; a missing or unreadable file is an [`Error::Io`] naming it.
fn open(path: &Path) -> Result<File> {
    File::open(path).map_err(|e| Error::io(path, e))
}

// ---------------------------------------------------------------------------------------------
// Public reading API
// ---------------------------------------------------------------------------------------------

/// Reads a colour image (linear RGBA, premultiplied alpha; alpha is 1 where the file has none).
///
/// - `.exr`: plain `R`, `G`, `B` (and optional `A`) channels, or those of a layer such as
///   `ViewLayer.Combined.R` (Blender's multilayer files). Plain channels win over layers, and a
///   `Combined` layer over other layers (the first one, alphabetically, if there are several);
///   other layers are used only when there is exactly one. Without RGB, a single `Y` channel is
///   read as grey. Otherwise the error lists the channels found.
/// - `.png`: 8 or 16 bits, grey, grey-alpha, RGB or RGBA (palettes are expanded); colour is
///   sRGB-decoded to linear light (any gAMA or iCCP chunk is ignored) and premultiplied by
///   alpha, which is read as stored.
/// - `.pfm`: colour (`PF`) or grey (`Pf`), either byte order.
pub fn read_color(path: &Path) -> Result<ColorImage> {
    match input_format(path, "input image path")? {
        FileFormat::Exr => read_exr_color(path),
        FileFormat::Png => color_from_png(read_png(path)?),
        FileFormat::Pfm => color_from_pfm(read_pfm(path)?),
        FileFormat::Jpeg => color_from_png(read_jpeg(path)?),
    }
}

/// The width and height in pixels of an image file (for an OpenEXR file, its data window),
/// from its header alone: what a read of it would hold, without decoding the pixels.
pub fn image_size(path: &Path) -> Result<(usize, usize)> {
    let png_err = |e: image::ImageError| Error::format(path, format!("not a readable image: {e}"));
    let (w, h) = match input_format(path, "input image path")? {
        FileFormat::Exr => {
            let meta = exr::meta::MetaData::read_from_buffered(BufReader::new(open(path)?), false)
                .map_err(|e| exr_read_error(path, e))?;
            let header = meta
                .headers
                .first()
                .ok_or_else(|| Error::format(path, "the OpenEXR file has no layers"))?;
            (header.layer_size.0 as u32, header.layer_size.1 as u32)
        }
        FileFormat::Png => image::codecs::png::PngDecoder::new(BufReader::new(open(path)?))
            .map_err(|e| png_error(path, e))?
            .dimensions(),
        FileFormat::Jpeg => image::codecs::jpeg::JpegDecoder::new(BufReader::new(open(path)?))
            .map_err(png_err)?
            .dimensions(),
        FileFormat::Pfm => {
            let mut r = BufReader::new(open(path)?);
            let mut consumed = 0u64;
            pfm_token(path, &mut r, "magic ('PF' or 'Pf')", &mut consumed)?;
            let mut dimension = |field: &str| -> Result<u32> {
                let t = pfm_token(path, &mut r, field, &mut consumed)?;
                t.parse().map_err(|_| {
                    Error::format(
                        path,
                        format!("PFM {field}: expected a whole number of pixels, found '{t}'"),
                    )
                })
            };
            (dimension("width")?, dimension("height")?)
        }
    };
    Ok((w as usize, h as usize))
}

/// Every channel of an OpenEXR file, as `f32` planes of one common size.
#[derive(Clone, Debug, PartialEq)]
pub struct ExrChannels {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// (full name, row-major samples). The full name includes the layer, e.g.
    /// `ViewLayer.Depth.Z`; `f16` and `u32` samples are converted to `f32`.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl ExrChannels {
    /// The samples of the channel whose full name is exactly `name`.
    pub fn find(&self, name: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }

    /// The channels that `name` can refer to: the channel named exactly `name` if there is one;
    /// otherwise every channel whose full name equals `name` or ends with `.name`, ignoring ASCII
    /// case (so `Z` finds `ViewLayer.Depth.Z` and `depth.z` finds `Layer.Depth.Z`). Returned in
    /// file order; more than one result means the name is ambiguous.
    pub fn find_by_suffix(&self, name: &str) -> Vec<(&str, &[f32])> {
        if let Some((n, v)) = self.channels.iter().find(|(n, _)| n == name) {
            return vec![(n.as_str(), v.as_slice())];
        }
        self.channels
            .iter()
            .filter(|(n, _)| ends_with_component(n, name))
            .map(|(n, v)| (n.as_str(), v.as_slice()))
            .collect()
    }

    /// All full channel names, in file order.
    pub fn names(&self) -> Vec<&str> {
        self.channels.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// The channel names as one comma-separated list, for error messages.
    fn name_list(&self) -> String {
        if self.channels.is_empty() {
            "none".to_string()
        } else {
            self.names().join(", ")
        }
    }

    /// The channel named `prefix` + `component`, the component compared ignoring ASCII case.
    fn component(&self, prefix: &str, component: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, _)| {
                n.len() == prefix.len() + component.len()
                    && n.starts_with(prefix)
                    && n[prefix.len()..].eq_ignore_ascii_case(component)
            })
            .map(|(_, v)| v.as_slice())
    }
}

/// True when `name` equals `suffix` or ends with `.suffix`, ignoring ASCII case.
fn ends_with_component(name: &str, suffix: &str) -> bool {
    let (n, s) = (name.as_bytes(), suffix.as_bytes());
    if n.len() < s.len() || !n[n.len() - s.len()..].eq_ignore_ascii_case(s) {
        return false;
    }
    n.len() == s.len() || n[n.len() - s.len() - 1] == b'.'
}

/// Reads every channel of an OpenEXR file, converted to `f32`.
///
/// Only the largest resolution level is read (mip and rip maps are ignored). The image size is the
/// data window of the first layer (part); other layers of the same size are included, with the
/// layer name and a dot prefixed to their channel names, and layers of other sizes are skipped.
/// Subsampled channels (x or y sampling other than 1, as in luminance-chroma files) are skipped.
/// Deep files are refused.
pub fn read_exr_channels(path: &Path) -> Result<ExrChannels> {
    check_exr_windows(path)?;
    let chunks = exr::block::read(BufReader::new(open(path)?), false)
        .map_err(|e| exr_read_error(path, e))?;
    exr_channels_from(path, chunks)
}

/// [`read_exr_channels`] of chunks already read from `path`.
fn exr_channels_from<R: Read + std::io::Seek>(
    path: &Path,
    chunks: exr::block::reader::Reader<R>,
) -> Result<ExrChannels> {
    for header in chunks.headers() {
        check_file_size(path, header.layer_size.0, header.layer_size.1)?;
        if header.deep {
            return Err(Error::format(
                path,
                "deep OpenEXR data is not supported: expected flat (scanline or tiled) images",
            ));
        }
    }
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_chunks(chunks)
        .map_err(|e| exr_read_error(path, e))?;

    let Some(first) = image.layer_data.first() else {
        return Err(Error::format(path, "the OpenEXR file has no layers"));
    };
    let size = first.size;
    let mut channels = Vec::new();
    // The decoded samples are moved out, not copied: at 4K a colour plane set is 133 MB.
    for layer in image.layer_data.into_iter().filter(|l| l.size == size) {
        let prefix = match layer.attributes.layer_name.as_ref().map(|n| n.to_string()) {
            Some(name) if !name.is_empty() => format!("{name}."),
            _ => String::new(),
        };
        for channel in layer.channel_data.list {
            if channel.sampling != Vec2(1, 1) {
                continue;
            }
            let samples: Vec<f32> = match channel.sample_data {
                FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
                FlatSamples::F32(v) => v,
                FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
            };
            if samples.len() != size.0 * size.1 {
                return Err(Error::format(
                    path,
                    format!(
                        "channel '{prefix}{}': expected {} samples for {}x{} pixels, found {}",
                        channel.name,
                        size.0 * size.1,
                        size.0,
                        size.1,
                        samples.len()
                    ),
                ));
            }
            channels.push((format!("{prefix}{}", channel.name), samples));
        }
    }
    Ok(ExrChannels {
        width: size.0,
        height: size.1,
        channels,
    })
}

/// Names the channels [`read_color`] and [`read_depth`] would use in an EXR file, for
/// verbose output: `(colour channels, depth channel)`. Either is an error when no channel fits,
/// listing those available.
pub fn exr_channel_choice(
    path: &Path,
    depth_channel_name: Option<&str>,
) -> Result<(Result<Vec<String>>, Result<String>)> {
    let ch = read_exr_channels(path)?;
    let color = color_prefix(path, &ch).map(|prefix| {
        ["R", "G", "B", "A", "Y"]
            .iter()
            .filter(|c| ch.component(&prefix, c).is_some())
            .map(|c| format!("{prefix}{c}"))
            .collect()
    });
    let depth = depth_channel(path, &ch, depth_channel_name).map(|(name, _)| name.to_string());
    Ok((color, depth))
}

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

/// Reads a map of signed CoC radii in pixels (negative in front of the focal plane), as
/// `blur --coc-out` writes it: from an OpenEXR file, the channel `channel` (a full name or a
/// unique suffix), else the one channel named `CoC` or ending in `.CoC`; from a PFM, the grey
/// (or red) channel. Every value must be finite; other formats are refused (a PNG holds no
/// signed values).
pub fn read_coc(path: &Path, channel: Option<&str>) -> Result<GrayImage> {
    let (width, height, mut values, what) =
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
    let finite = |v: f32| v.is_finite().then_some(v);
    if let Some((bad, x, y, v)) = convert_values(&mut values, width, finite) {
        return Err(Error::format(
            path,
            format!(
                "CoC {what}: {bad} pixel(s) are not finite, the first at (x {x}, y {y}) = {v}; \
                 expected signed radii in pixels"
            ),
        ));
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

/// Refuses an output path that names the same file as an input (which the write would
/// destroy). Paths are compared after canonicalisation (and, on Unix, by device and inode, which
/// also catches hard links); an output that does not exist yet is always fine.
pub fn ensure_not_same_file(input: &Path, output: &Path) -> Result<()> {
    let Ok(out_meta) = std::fs::metadata(output) else {
        return Ok(());
    };
    let same_path = match (input.canonicalize(), output.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    #[cfg(unix)]
    let same_inode = {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(input)
            .map(|m| m.dev() == out_meta.dev() && m.ino() == out_meta.ino())
            .unwrap_or(false)
    };
    #[cfg(not(unix))]
    let same_inode = {
        let _ = out_meta;
        false
    };
    if same_path || same_inode {
        return Err(Error::invalid(
            "output path",
            format!(
                "{} is the input file {}: choose another output path",
                shown(&output),
                shown(&input)
            ),
        ));
    }
    Ok(())
}

/// Fails naming the file, channel, pixel and value of the first NaN or infinite value of a
/// colour image read from `path` (an HDR render can hold them after a bad sample; every method
/// would spread them over their blur).
pub fn check_finite_color(path: &Path, img: &ColorImage) -> Result<()> {
    let w = img.width().max(1);
    if let Some((i, p)) = img
        .pixels()
        .iter()
        .enumerate()
        .find(|(_, p)| p.iter().any(|v| !v.is_finite()))
    {
        let bad = img
            .pixels()
            .iter()
            .filter(|p| p.iter().any(|v| !v.is_finite()))
            .count();
        let k = p.iter().position(|v| !v.is_finite()).unwrap_or(0);
        return Err(Error::format(
            path,
            format!(
                "channel {} at pixel ({}, {}) is {} ({bad} pixel(s) not finite): expected finite colour values (--sanitize replaces them with 0)",
                ["R", "G", "B", "A"][k],
                i % w,
                i / w,
                p[k]
            ),
        ));
    }
    Ok(())
}

/// Replaces every NaN or infinite value of `img` by 0; returns how many pixels had one.
pub fn sanitize_color(img: &mut ColorImage) -> usize {
    let mut n = 0;
    for p in img.pixels_mut() {
        if p.iter().any(|v| !v.is_finite()) {
            n += 1;
            for v in p.iter_mut() {
                if !v.is_finite() {
                    *v = 0.0;
                }
            }
        }
    }
    n
}

// ---------------------------------------------------------------------------------------------
// Public writing API
// ---------------------------------------------------------------------------------------------

/// Writes a colour image, atomically, by extension:
/// - `.exr`: float32 linear `R`, `G`, `B`, `A`, uncompressed (see [`write_color_with`]);
/// - `.png`: 8-bit RGBA with straight alpha: alpha clamped to [0, 1], colour divided by it
///   (0 where alpha is 0), clamped to [0, 1] and sRGB-encoded;
/// - `.pfm`: colour PFM (`PF`, little-endian), alpha dropped.
///
/// A file of its own transaction; [`OutputSet::write_color`] writes one of several.
pub fn write_color(path: &Path, img: &ColorImage) -> Result<()> {
    write_color_with(path, img, &ExrOptions::default())
}

/// [`write_color`] with the EXR compression and sample type of `exr`.
pub fn write_color_with(path: &Path, img: &ColorImage, exr: &ExrOptions) -> Result<()> {
    write_one(|set| set.write_color(path, img, exr))
}

/// Writes a 16-bit RGBA PNG, atomically, converted as [`write_color`] does for 8-bit PNG.
/// The extension is not checked.
pub fn write_png16(path: &Path, img: &ColorImage) -> Result<()> {
    write_one(|set| set.write_png16(path, img))
}

/// Writes a depth image as an OpenEXR file with one float32 channel `Z`, atomically.
pub fn write_depth_exr(path: &Path, depth: &GrayImage) -> Result<()> {
    write_one(|set| set.write_depth_exr(path, depth))
}

/// Writes float32 channels of one size to an OpenEXR file (one part, ZIP), atomically.
///
/// Names are written as given, so `ViewLayer.Combined.R` makes a Blender-style multilayer file.
/// Each channel must hold `width * height` row-major samples; names must be non-empty, unique and
/// Latin-1.
pub fn write_exr_layers(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(&str, &[f32])],
) -> Result<()> {
    write_exr_layers_placed(path, width, height, channels, None)
}

/// [`write_exr_layers`] with the image placed in its frame (`None`: the whole frame).
pub fn write_exr_layers_placed(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(&str, &[f32])],
    placement: Option<Placement>,
) -> Result<()> {
    write_one(|set| set.write_exr_layers(path, width, height, channels, placement))
}

/// The 8-bit PNG that [`write_color`] writes for `img`, as bytes (for a page that embeds it).
pub fn encode_png(img: &ColorImage) -> Result<Vec<u8>> {
    check_size(img.width(), img.height())?;
    let mut bytes = Vec::new();
    png_encode(
        &mut bytes,
        img,
        &png8_samples(img),
        ExtendedColorType::Rgba8,
    )
    .map_err(|e| Error::invalid("PNG image", format!("could not encode it: {e}")))?;
    Ok(bytes)
}

/// One file as a transaction of its own.
fn write_one(write: impl FnOnce(&mut OutputSet) -> Result<()>) -> Result<()> {
    let mut set = OutputSet::new();
    write(&mut set)?;
    set.commit()
}

/// The image writers, for outputs written together (see [`OutputSet`]): each stages its file,
/// and errors name the target path.
impl OutputSet {
    /// Stages a colour image for `path`, by its extension, as [`write_color_with`] writes it.
    pub fn write_color(&mut self, path: &Path, img: &ColorImage, exr: &ExrOptions) -> Result<()> {
        let format = file_format(path, "output image path")?;
        check_output_size(path, img.width(), img.height())?;
        match format {
            FileFormat::Exr => {
                // Straight from our pixels: the encoder asks for each line's samples (no
                // copy of the image into channel planes first).
                let (w, px) = (img.width(), img.pixels());
                let at = move |p: Vec2<usize>| px[p.1 * w + p.0];
                // One layer of the four channels from `sample`, as f32 or f16 samples.
                macro_rules! write_rgba {
                    ($sample:expr) => {{
                        let sample = $sample;
                        let channels =
                            exr::prelude::SpecificChannels::rgba(move |p: Vec2<usize>| {
                                let c = at(p);
                                (sample(c[0]), sample(c[1]), sample(c[2]), sample(c[3]))
                            });
                        let (attributes, encoding, frame) = exr_frame(w, img.height(), exr);
                        let size = (w, img.height());
                        let layer = exr::prelude::Layer::new(size, attributes, encoding, channels);
                        let image = ExrImage::new(frame, layer);
                        self.write(path, |out| {
                            image
                                .write()
                                .to_buffered(out)
                                .map_err(|e| exr_write_error(path, e))
                        })
                    }};
                }
                if exr.half {
                    write_rgba!(half::f16::from_f32)
                } else {
                    write_rgba!(|v: f32| v)
                }
            }
            FileFormat::Png => {
                let bytes = png8_samples(img);
                write_png(self, path, img, &bytes, ExtendedColorType::Rgba8)
            }
            FileFormat::Pfm => write_pfm(self, path, img),
            FileFormat::Jpeg => Err(Error::invalid(
                "output image path",
                format!(
                    "{}: JPEG output is not supported (lossy); expected one of .exr, .png, .pfm",
                    shown(path)
                ),
            )),
        }
    }

    /// Stages a 16-bit RGBA PNG for `path`, as [`write_png16`] writes it.
    pub fn write_png16(&mut self, path: &Path, img: &ColorImage) -> Result<()> {
        check_output_size(path, img.width(), img.height())?;
        let mut bytes = Vec::with_capacity(img.pixels().len() * 8);
        for p in img.pixels() {
            for v in straight_srgb(*p) {
                // PngEncoder takes 16-bit samples in native byte order.
                bytes.extend((quantize(v, 65535.0) as u16).to_ne_bytes());
            }
        }
        write_png(self, path, img, &bytes, ExtendedColorType::Rgba16)
    }

    /// Stages a depth image for `path`, as [`write_depth_exr`] writes it.
    pub fn write_depth_exr(&mut self, path: &Path, depth: &GrayImage) -> Result<()> {
        check_output_size(path, depth.width(), depth.height())?;
        let channels = vec![("Z".to_string(), depth.pixels().to_vec())];
        write_exr(
            self,
            path,
            depth.width(),
            depth.height(),
            channels,
            &ExrOptions {
                half: false,
                ..ExrOptions::default()
            },
        )
    }

    /// Stages named float32 channels for `path`, as [`write_exr_layers_placed`] writes them.
    pub fn write_exr_layers(
        &mut self,
        path: &Path,
        width: usize,
        height: usize,
        channels: &[(&str, &[f32])],
        placement: Option<Placement>,
    ) -> Result<()> {
        check_output_size(path, width, height)?;
        let owned = channels
            .iter()
            .map(|(name, data)| (name.to_string(), data.to_vec()))
            .collect();
        write_exr(
            self,
            path,
            width,
            height,
            owned,
            &ExrOptions {
                half: false,
                placement,
                ..ExrOptions::default()
            },
        )
    }
}

// ---------------------------------------------------------------------------------------------
// EXR internals
// ---------------------------------------------------------------------------------------------

/// An OpenEXR reading error, with the path.
fn exr_read_error(path: &Path, err: exr::error::Error) -> Error {
    match err {
        exr::error::Error::Io(e) if e.kind() != std::io::ErrorKind::UnexpectedEof => {
            Error::io(path, e)
        }
        other => Error::format(
            path,
            format!("not a readable OpenEXR file (corrupt or truncated?): {other}"),
        ),
    }
}

/// The RGBA image in an EXR file's channels; see [`read_color`] for the rules.
/// Reads the colour of an OpenEXR file. A file of one part whose only channels are R, G, B
/// and perhaps A (the common case: a render's beauty pass) is decoded straight into the
/// image's pixels; any other (named layers, Y, more channels) goes through
/// [`read_exr_channels`] and [`color_from_exr`], which pick the colour layer.
fn read_exr_color(path: &Path) -> Result<ColorImage> {
    check_exr_windows(path)?;
    let chunks = exr::block::read(BufReader::new(open(path)?), false)
        .map_err(|e| exr_read_error(path, e))?;
    let plain = match chunks.headers() {
        [header] => {
            let names: Vec<String> = header
                .channels
                .list
                .iter()
                .map(|c| c.name.to_string())
                .collect();
            let subsampled = header
                .channels
                .list
                .iter()
                .any(|c| c.sampling != Vec2(1, 1));
            !header.deep
                && !subsampled
                && (names == ["B", "G", "R"] || names == ["A", "B", "G", "R"])
        }
        _ => false,
    };
    if !plain {
        return color_from_exr(path, &exr_channels_from(path, chunks)?);
    }
    for header in chunks.headers() {
        check_file_size(path, header.layer_size.0, header.layer_size.1)?;
    }
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |size, _| (size.0, vec![[0.0f32; 4]; size.0 * size.1]),
            |(w, pixels): &mut (usize, Vec<Rgba>), p, (r, g, b, a): (f32, f32, f32, f32)| {
                pixels[p.1 * *w + p.0] = [r, g, b, a];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_chunks(chunks)
        .map_err(|e| exr_read_error(path, e))?;
    let size = image.layer_data.size;
    let (_, pixels) = image.layer_data.channel_data.pixels;
    ColorImage::from_vec(size.0, size.1, pixels)
}

fn color_from_exr(path: &Path, ch: &ExrChannels) -> Result<ColorImage> {
    let prefix = color_prefix(path, ch)?;
    let n = ch.width * ch.height;
    let ones = vec![1.0; n];
    let alpha = ch.component(&prefix, "A").unwrap_or(&ones);
    let pixels: Vec<Rgba> = match (
        ch.component(&prefix, "R"),
        ch.component(&prefix, "G"),
        ch.component(&prefix, "B"),
    ) {
        (Some(r), Some(g), Some(b)) => (0..n).map(|i| [r[i], g[i], b[i], alpha[i]]).collect(),
        _ => {
            let y = ch.component(&prefix, "Y").unwrap_or(&ones);
            (0..n).map(|i| [y[i], y[i], y[i], alpha[i]]).collect()
        }
    };
    ColorImage::from_vec(ch.width, ch.height, pixels)
}

/// The prefix (`""` or `"Layer.Pass."`) of the colour channels: R, G, B, or failing that, Y.
fn color_prefix(path: &Path, ch: &ExrChannels) -> Result<String> {
    let prefixes_with = |last: &str| -> Vec<String> {
        ch.channels
            .iter()
            .filter(|(n, _)| ends_with_component(n, last))
            .map(|(n, _)| n[..n.len() - last.len()].to_string())
            .collect()
    };
    let rgb: Vec<String> = prefixes_with("R")
        .into_iter()
        .filter(|p| ch.component(p, "G").is_some() && ch.component(p, "B").is_some())
        .collect();
    if !rgb.is_empty() {
        if rgb.iter().any(|p| p.is_empty()) {
            return Ok(String::new());
        }
        let mut combined: Vec<&String> = rgb
            .iter()
            .filter(|p| {
                p.trim_end_matches('.')
                    .rsplit('.')
                    .next()
                    .is_some_and(|last| last.eq_ignore_ascii_case("combined"))
            })
            .collect();
        combined.sort();
        if let Some(p) = combined.first() {
            return Ok(p.to_string());
        }
        if rgb.len() == 1 {
            return Ok(rgb[0].clone());
        }
        return Err(Error::format(
            path,
            format!(
                "several RGB layers ({}) and none is plain R, G, B or a 'Combined' layer; \
                 expected one colour layer",
                rgb.join(", ")
            ),
        ));
    }
    let grey = prefixes_with("Y");
    match grey.as_slice() {
        [p] => Ok(p.clone()),
        [] => Err(Error::format(
            path,
            format!(
                "no colour channels: expected R, G, B (optionally A), a layer such as \
                 'ViewLayer.Combined.R', or a grey Y channel; found: {}",
                ch.name_list()
            ),
        )),
        _ => Err(Error::format(
            path,
            format!(
                "several grey Y channels ({}) and no RGB: expected one colour layer",
                ch.names()
                    .into_iter()
                    .filter(|n| ends_with_component(n, "Y"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

/// The depth channel of an EXR file: see [`read_depth`] for the search order.
fn depth_channel<'a>(
    path: &Path,
    ch: &'a ExrChannels,
    requested: Option<&str>,
) -> Result<(&'a str, &'a [f32])> {
    let unique = |found: Vec<(&'a str, &'a [f32])>, what: &str| -> Result<_> {
        match found.as_slice() {
            [one] => Ok(Some(*one)),
            [] => Ok(None),
            many => Err(Error::format(
                path,
                format!(
                    "several depth channels match {what} ({}): choose one with the depth channel \
                     option",
                    many.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
                ),
            )),
        }
    };
    if let Some(name) = requested {
        return unique(ch.find_by_suffix(name), &format!("'{name}'"))?.ok_or_else(|| {
            Error::format(
                path,
                format!(
                    "no depth channel '{name}'; available channels: {}",
                    ch.name_list()
                ),
            )
        });
    }
    let exact = |want: &str| -> Vec<(&'a str, &'a [f32])> {
        ch.channels
            .iter()
            .filter(|(n, _)| n.eq_ignore_ascii_case(want))
            .map(|(n, v)| (n.as_str(), v.as_slice()))
            .collect()
    };
    let suffix = |want: &str| -> Vec<(&'a str, &'a [f32])> {
        ch.channels
            .iter()
            .filter(|(n, _)| {
                n.len() > want.len()
                    && n.as_bytes()[n.len() - want.len()..].eq_ignore_ascii_case(want.as_bytes())
            })
            .map(|(n, v)| (n.as_str(), v.as_slice()))
            .collect()
    };
    let candidates = [
        (exact("Z"), "'Z'"),
        (exact("depth"), "'depth'"),
        (suffix(".Depth.Z"), "'*.Depth.Z'"),
        (suffix(".Z"), "'*.Z'"),
        (suffix(".depth"), "'*.depth'"),
    ];
    for (found, what) in candidates {
        if let Some(one) = unique(found, what)? {
            return Ok(one);
        }
    }
    Err(Error::format(
        path,
        format!(
            "no depth channel: expected Z, depth, *.Depth.Z, *.Z or *.depth (or name one with the \
             depth channel option); available channels: {}",
            ch.name_list()
        ),
    ))
}

/// Writes named float channels as a one-part scanline EXR, atomically, compressed as `options`
/// says (blocks are compressed in parallel), as 16-bit halves with `options.half`.
fn write_exr(
    set: &mut OutputSet,
    path: &Path,
    width: usize,
    height: usize,
    channels: Vec<(String, Vec<f32>)>,
    options: &ExrOptions,
) -> Result<()> {
    if channels.is_empty() {
        return Err(Error::invalid(
            "EXR channels",
            format!("{}: at least one channel is needed", shown(&path)),
        ));
    }
    let mut list = SmallVec::new();
    for (i, (name, data)) in channels.into_iter().enumerate() {
        if data.len() != width * height {
            return Err(Error::Mismatch(format!(
                "{}: channel '{name}' has {} samples, expected {} for {width}x{height} pixels",
                shown(&path),
                data.len(),
                width * height
            )));
        }
        let text = Text::new_or_none(&name).filter(|_| !name.is_empty());
        let Some(text) = text else {
            return Err(Error::invalid(
                "EXR channel name",
                format!(
                    "{}: channel {i} is named '{name}': expected a non-empty Latin-1 name",
                    shown(&path)
                ),
            ));
        };
        let samples = if options.half {
            FlatSamples::F16(data.iter().map(|&v| half::f16::from_f32(v)).collect())
        } else {
            FlatSamples::F32(data)
        };
        list.push(AnyChannel::new(text, samples));
    }
    let channels = AnyChannels::sort(list);
    if let Some(pair) = channels.list.windows(2).find(|p| p[0].name == p[1].name) {
        return Err(Error::invalid(
            "EXR channel name",
            format!(
                "{}: channel '{}' is given twice: expected unique names",
                shown(&path),
                pair[0].name
            ),
        ));
    }
    let (attributes, encoding, frame) = exr_frame(width, height, options);
    let layer = exr::prelude::Layer::new((width, height), attributes, encoding, channels);
    let image = ExrImage::new(frame, layer);
    set.write(path, |out| {
        image
            .write()
            .to_buffered(out)
            .map_err(|e| exr_write_error(path, e))
    })
}

/// What a one-part scanline EXR of a `width` x `height` image is written with besides its
/// channels: the data window's attributes, the encoding and the image attributes (display
/// window), as `options` says.
fn exr_frame(
    width: usize,
    height: usize,
    options: &ExrOptions,
) -> (
    LayerAttributes,
    Encoding,
    exr::meta::header::ImageAttributes,
) {
    let placement = options
        .placement
        .unwrap_or_else(|| Placement::full(width, height));
    let (x, y) = placement.data_origin;
    let attributes = LayerAttributes {
        layer_position: Vec2(x, y),
        ..LayerAttributes::default()
    };
    let display =
        exr::meta::attribute::IntegerBounds::new(placement.display_origin, placement.display_size);
    (
        attributes,
        options.compression.encoding(),
        exr::meta::header::ImageAttributes::new(display),
    )
}

/// An error of the EXR encoder while writing `path`.
fn exr_write_error(path: &Path, e: exr::error::Error) -> Error {
    match e {
        exr::error::Error::Io(e) => Error::io(path, e),
        other => Error::format(path, format!("could not write OpenEXR: {other}")),
    }
}

// ---------------------------------------------------------------------------------------------
// PNG internals
// ---------------------------------------------------------------------------------------------

/// A decoded PNG: samples normalised to [0, 1], `channels` per pixel, row-major.
struct Png {
    width: usize,
    height: usize,
    channels: usize,
    bits: u32,
    samples: Vec<f32>,
}

/// A PNG decoding error, with the path.
fn png_error(path: &Path, err: image::ImageError) -> Error {
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
fn read_jpeg(path: &Path) -> Result<Png> {
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

fn read_png(path: &Path) -> Result<Png> {
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
fn color_from_png(png: Png) -> Result<ColorImage> {
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
fn depth_from_png(path: &Path, png: &Png) -> Result<Vec<f32>> {
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
fn png_encode(
    out: impl Write,
    img: &ColorImage,
    bytes: &[u8],
    color: ExtendedColorType,
) -> std::result::Result<(), image::ImageError> {
    let (w, h) = (img.width() as u32, img.height() as u32);
    image::codecs::png::PngEncoder::new(out).write_image(bytes, w, h, color)
}

/// Stages already-quantised PNG samples of `img`'s size for `path`.
fn write_png(
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
fn straight_srgb(p: Rgba) -> [f32; 4] {
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
fn quantize(v: f32, max: f32) -> f32 {
    if v.is_nan() {
        return 0.0;
    }
    (v.clamp(0.0, 1.0) * max + 0.5).floor()
}

// ---------------------------------------------------------------------------------------------
// PFM internals
// ---------------------------------------------------------------------------------------------

/// A decoded PFM, rows top to bottom.
struct Pfm {
    width: usize,
    height: usize,
    /// 1 (`Pf`) or 3 (`PF`).
    channels: usize,
    data: Vec<f32>,
}

/// Reads one whitespace-delimited header token of a PFM file, consuming the single whitespace
/// byte after it. Leading whitespace is skipped.
fn pfm_token(path: &Path, r: &mut impl Read, field: &str, consumed: &mut u64) -> Result<String> {
    let mut token = Vec::new();
    let mut byte = [0u8; 1];
    loop {
        let n = r.read(&mut byte).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            return Err(Error::format(
                path,
                format!("truncated PFM header: the file ends before the {field} field"),
            ));
        }
        *consumed += 1;
        if byte[0].is_ascii_whitespace() {
            if token.is_empty() {
                continue;
            }
            break;
        }
        token.push(byte[0]);
        if token.len() > 32 {
            return Err(Error::format(
                path,
                format!("PFM header field {field} is longer than 32 bytes: not a PFM file?"),
            ));
        }
    }
    Ok(String::from_utf8_lossy(&token).into_owned())
}

/// Reads a PFM file (`PF` colour or `Pf` grey; byte order from the sign of the scale field,
/// negative meaning little-endian; the scale's magnitude is ignored). Trailing bytes after the
/// pixel data are ignored.
fn read_pfm(path: &Path) -> Result<Pfm> {
    let file = open(path)?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut r = BufReader::new(file);
    let mut consumed = 0u64;
    let magic = pfm_token(path, &mut r, "magic ('PF' or 'Pf')", &mut consumed)?;
    let channels = match magic.as_str() {
        "PF" => 3,
        "Pf" => 1,
        other => {
            return Err(Error::format(
                path,
                format!("not a PFM file: expected 'PF' or 'Pf' at the start, found '{other}'"),
            ))
        }
    };
    let mut dimension = |field: &str| -> Result<usize> {
        let t = pfm_token(path, &mut r, field, &mut consumed)?;
        t.parse::<usize>().map_err(|_| {
            Error::format(
                path,
                format!("PFM {field}: expected a whole number of pixels, found '{t}'"),
            )
        })
    };
    let width = dimension("width")?;
    let height = dimension("height")?;
    check_file_size(path, width, height)?;
    let t = pfm_token(path, &mut r, "scale", &mut consumed)?;
    let scale: f32 = t.parse().unwrap_or(f32::NAN);
    if !(scale.is_finite() && scale != 0.0) {
        return Err(Error::format(
            path,
            format!(
                "PFM scale: expected a non-zero number (negative for little-endian), found '{t}'"
            ),
        ));
    }
    let little_endian = scale < 0.0;
    let expected = width * height * channels * 4;
    let available = file_len.saturating_sub(consumed);
    if available < expected as u64 {
        return Err(Error::format(
            path,
            format!(
                "truncated PFM: expected {expected} bytes of pixel data for {width}x{height}x{channels} \
                 floats, found {available}"
            ),
        ));
    }
    let mut bytes = vec![0u8; expected];
    r.read_exact(&mut bytes).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            Error::format(
                path,
                format!("truncated PFM: expected {expected} bytes of pixel data"),
            )
        } else {
            Error::io(path, e)
        }
    })?;
    let row_len = width * channels;
    let mut data = vec![0f32; width * height * channels];
    // Stored rows go bottom to top.
    for (stored_row, src) in bytes.chunks_exact(row_len * 4).enumerate() {
        let dst = &mut data[(height - 1 - stored_row) * row_len..][..row_len];
        for (d, c) in dst.iter_mut().zip(src.chunks_exact(4)) {
            let b = [c[0], c[1], c[2], c[3]];
            *d = if little_endian {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(Pfm {
        width,
        height,
        channels,
        data,
    })
}

/// RGBA (alpha 1) from a PFM; grey files are replicated to R, G, B.
fn color_from_pfm(pfm: Pfm) -> Result<ColorImage> {
    let pixels: Vec<Rgba> = pfm
        .data
        .chunks_exact(pfm.channels)
        .map(|s| match s {
            [r, g, b] => [*r, *g, *b, 1.0],
            _ => [s[0], s[0], s[0], 1.0],
        })
        .collect();
    ColorImage::from_vec(pfm.width, pfm.height, pixels)
}

/// Stages a colour PFM (`PF`, little-endian, rows bottom to top) for `path`.
fn write_pfm(set: &mut OutputSet, path: &Path, img: &ColorImage) -> Result<()> {
    let (w, h) = (img.width(), img.height());
    let mut bytes = Vec::with_capacity(32 + w * h * 12);
    bytes.extend(format!("PF\n{w} {h}\n-1.0\n").into_bytes());
    for y in (0..h).rev() {
        for p in img.row(y) {
            for v in &p[..3] {
                bytes.extend(v.to_le_bytes());
            }
        }
    }
    set.write_bytes(path, &bytes)
}

// ---------------------------------------------------------------------------------------------
// Depth validation and atomic writes
// ---------------------------------------------------------------------------------------------

/// Checks depth values in metres: `+inf` becomes `f32::MAX`; NaN, zero, negative values and
/// `-inf` are an error naming the first such pixel (x, y), its value and their count.
/// Replaces each value by `convert(value)`, or counts it as bad where that is `None`. Returns
/// the count and the first bad pixel `(x, y, value)`, if any.
fn convert_values(
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
fn invert_depth(path: &Path, what: &str, width: usize, values: &mut [f32]) -> Result<()> {
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
fn validate_depth(
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

/// A size check for an image about to be written, naming the output file.
fn check_output_size(path: &Path, width: usize, height: usize) -> Result<()> {
    check_size(width, height).map_err(|e| {
        let reason = match e {
            Error::Invalid { message, .. } => message,
            other => other.to_string(),
        };
        Error::invalid("output image size", format!("{}: {reason}", shown(&path)))
    })
}

/// Fails when two of the named outputs are one file (the same path, however written, or one
/// existing file under two names): the later write would silently replace the earlier.
pub fn check_distinct_outputs(outputs: &[(&str, &Path)]) -> Result<()> {
    let key = |p: &Path| -> PathBuf {
        if let Ok(c) = p.canonicalize() {
            return c;
        }
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let dir = dir.canonicalize().unwrap_or(dir);
        dir.join(p.file_name().unwrap_or_default())
    };
    for (i, (fa, pa)) in outputs.iter().enumerate() {
        for (fb, pb) in &outputs[i + 1..] {
            if key(pa) == key(pb) {
                return Err(Error::invalid(
                    "output path",
                    format!(
                        "{fa} and {fb} both name {}: give each output its own file",
                        shown(&pb)
                    ),
                ));
            }
        }
    }
    Ok(())
}
