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

mod depth;
mod openexr;
mod pfm;
mod png;
mod write;
mod zip;

pub use depth::{
    bad_coc_radii, depth_from_values, radial_to_view_depth, radial_to_view_depth_about, read_coc,
    read_depth, DepthRead, MAX_COC_MAP_PX,
};
pub use openexr::{exr_channel_choice, read_exr_channels, read_exr_placement, ExrChannels};
pub use png::{color_from_srgb8, png8_samples};
pub use write::{
    check_distinct_outputs, encode_png, write_color, write_color_with, write_depth_exr,
    write_exr_layers, write_exr_layers_placed, write_png16,
};
// Each format's internals, for the others.
#[allow(unused_imports)]
use {depth::*, openexr::*, pfm::*, png::*, write::*};

#[allow(unused_imports)]
use std::fs::File;
#[allow(unused_imports)]
use std::io::{BufReader, Read, Seek, Write};
#[allow(unused_imports)]
use std::path::{Path, PathBuf};

#[allow(unused_imports)]
use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, LayerAttributes,
    ReadChannels, ReadLayers, SmallVec, Text, Vec2, WritableImage,
};
#[allow(unused_imports)]
use image::{ColorType, ExtendedColorType, ImageDecoder, ImageEncoder};

use crate::error::shown;
#[allow(unused_imports)]
use crate::image::{check_size, srgb_decode, srgb_encode, ColorImage, GrayImage, Rgba};
pub use crate::output::OutputSet;
use crate::{Error, Result};

/// Compression of written OpenEXR files: the lossless ones, and the lossy ones compositors use
/// for review and playback (B44, DWA), all read by Blender and Nuke.
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
    /// Lossy, fixed rate: each 4x4 block of a half-float channel in 14 bytes (B44, for real-time
    /// playback); float channels are stored as they are, so use it with `--half`.
    B44,
    /// B44 that also stores flat 4x4 blocks in 3 bytes (B44A).
    B44a,
    /// Lossy DCT of the colour over blocks of 32 scanlines (DWAA, level 45, OpenEXR's default);
    /// other channels such as alpha stay lossless.
    Dwaa,
    /// DWAA over blocks of 256 scanlines (DWAB): smaller, slower to read a part of.
    Dwab,
}

impl ExrCompression {
    /// The lossy compressions: what they read back is not what was written.
    pub const LOSSY: [ExrCompression; 4] = [
        ExrCompression::B44,
        ExrCompression::B44a,
        ExrCompression::Dwaa,
        ExrCompression::Dwab,
    ];

    /// Every lossless compression, for benchmarks and tests.
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
            ExrCompression::B44 => "b44",
            ExrCompression::B44a => "b44a",
            ExrCompression::Dwaa => "dwaa",
            ExrCompression::Dwab => "dwab",
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
            ExrCompression::B44 => Compression::B44,
            ExrCompression::B44a => Compression::B44A,
            ExrCompression::Dwaa => Compression::DWAA(None),
            ExrCompression::Dwab => Compression::DWAB(None),
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
/// PFM header), or `None` when it is none of them or cannot be read. A FIFO, a device or a
/// folder is refused here, naming it, before anything waits on it.
fn sniff(path: &Path) -> Result<Option<FileFormat>> {
    let mut f = match open(path) {
        Ok(f) => f,
        Err(e @ Error::Format { .. }) => return Err(e),
        Err(_) => return Ok(None),
    };
    let mut head = [0u8; 4];
    let Ok(n) = f.read(&mut head) else {
        return Ok(None);
    };
    Ok(match &head[..n] {
        [0x89, b'P', b'N', b'G'] => Some(FileFormat::Png),
        [0x76, 0x2f, 0x31, 0x01] => Some(FileFormat::Exr),
        [b'P', b'F' | b'f', c, _] if c.is_ascii_whitespace() => Some(FileFormat::Pfm),
        [0xFF, 0xD8, 0xFF, _] => Some(FileFormat::Jpeg),
        _ => None,
    })
}

/// The format of an input file: from its content when recognised (a PNG named `.exr` is read
/// as the PNG it is), else from its extension.
fn input_format(path: &Path, role: &'static str) -> Result<FileFormat> {
    match sniff(path)? {
        Some(f) => Ok(f),
        None => file_format(path, role),
    }
}

/// Bytes a pixel of a decoded PNG, JPEG or PFM file can take at the peak of a read: the
/// decoder's samples (up to 8 bytes for 16-bit RGBA), their conversion to floats (up to 16),
/// then those floats and the image (RGBA, 16).
const DECODE_BYTES_PER_PIXEL: u64 = 32;

/// [`check_size`] for a size read from a file header: the error names the file. The decoded
/// size is also held against the memory budget ([`crate::budget`]) before any pixel memory is
/// allocated (a small compressed file can claim a huge image): `bytes` is the peak of the read.
fn check_decode(path: &Path, width: usize, height: usize, bytes: u64) -> Result<()> {
    check_header_size(path, width, height)?;
    crate::budget::check(
        bytes,
        &format!("decoding {} ({width}x{height})", shown(&path)),
        "the image's size",
    )
}

/// [`check_size`] for a size read from a file header: the error names the file.
fn check_header_size(path: &Path, width: usize, height: usize) -> Result<()> {
    check_size(width, height).map_err(|e| {
        let reason = match e {
            Error::Invalid { message, .. } => message,
            other => other.to_string(),
        };
        Error::format(path, format!("image size from the header: {reason}"))
    })
}

/// [`check_decode`] for a PNG, JPEG or PFM file of `width` x `height` pixels.
fn check_file_size(path: &Path, width: usize, height: usize) -> Result<()> {
    check_decode(
        path,
        width,
        height,
        (width * height) as u64 * DECODE_BYTES_PER_PIXEL,
    )
}

/// How an image file is read, for [`read_peak_bytes`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadAs {
    /// As colour ([`read_color`]).
    Color,
    /// As depth or a CoC map ([`read_depth`], [`read_coc`]): an OpenEXR file's channels are
    /// all decoded, to choose one.
    Channel,
}

/// The peak bytes that reading the image at `path` as `read` says takes, from its header
/// alone (no pixel is decoded), and its width and height; the size limits are checked (the
/// error names the file). A PNG, JPEG or PFM file takes `DECODE_BYTES_PER_PIXEL` a pixel; an
/// OpenEXR file its compressed chunks (the file's size) and its samples (see
/// `exr_read_peak_bytes`), so a file with many channels counts them all.
pub fn read_peak_bytes(path: &Path, read: ReadAs) -> Result<(u64, (usize, usize))> {
    if input_format(path, "input image path")? == FileFormat::Exr {
        return exr_read_peak_bytes(path, read == ReadAs::Color);
    }
    let (w, h) = image_size(path)?;
    check_header_size(path, w, h)?;
    Ok(((w * h) as u64 * DECODE_BYTES_PER_PIXEL, (w, h)))
}

/// Opens an image file for reading; a missing or unreadable file is an [`Error::Io`] naming
/// it, and anything but a regular file (a FIFO, a device, a folder) is refused before it is
/// read, without blocking ([`crate::input::open_regular`]).
fn open(path: &Path) -> Result<File> {
    crate::input::open_regular(path).map_err(|e| match e {
        crate::input::OpenError::Io(e) => Error::io(path, e),
        crate::input::OpenError::NotRegular(kind) => Error::format(
            path,
            format!("it is {kind}, not a regular file: expected an image file"),
        ),
    })
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

/// Checks that an existing image file is whole, as a finished output must be before a sequence
/// keeps it: its header reads, and the file is as long as the header says. A PNG must end with
/// its `IEND` chunk, a PFM must hold every sample its header gives, and an OpenEXR file's offset
/// tables must point inside it and its last chunk (by the header's line order) must read to its
/// end. Reads the header and at most one chunk of each part, never the whole image. The error
/// names the file and what is missing.
pub fn check_whole(path: &Path) -> Result<()> {
    let short = |what: String| Error::format(path, format!("not a whole image: {what}"));
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    if len == 0 {
        return Err(short("the file is empty".into()));
    }
    match input_format(path, "output path")? {
        FileFormat::Png => {
            image_size(path)?;
            /// A PNG's last chunk: no data, the type `IEND` and its CRC.
            const IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82];
            let mut f = open(path)?;
            let mut tail = [0u8; 12];
            let read = len >= 12
                && f.seek(std::io::SeekFrom::End(-12)).is_ok()
                && f.read_exact(&mut tail).is_ok();
            if !read || tail != IEND {
                return Err(short(format!(
                    "the PNG does not end with its IEND chunk ({len} bytes: truncated?)"
                )));
            }
        }
        FileFormat::Pfm => {
            let h = read_pfm_header(path)?;
            if h.expected.is_none_or(|e| h.available < e) {
                return Err(short(format!(
                    "the PFM header gives {}x{}x{} floats, {} bytes, but {} follow it (truncated?)",
                    h.width,
                    h.height,
                    h.channels,
                    h.expected.map_or("too many".to_string(), |e| e.to_string()),
                    h.available
                )));
            }
        }
        FileFormat::Exr => check_exr_whole(path)?,
        // Never written: not an output a sequence could have finished.
        FileFormat::Jpeg => return Err(short("a JPEG is no output of defocus".into())),
    }
    Ok(())
}

/// Whether `a` and `b` name one existing file: the same path once canonicalised (links and
/// `./` or `../` resolved), or, on Unix, the same device and inode (which also catches hard
/// links). A path that does not exist is the same as nothing.
pub fn same_file(a: &Path, b: &Path) -> bool {
    let (Ok(meta_a), Ok(meta_b)) = (std::fs::metadata(a), std::fs::metadata(b)) else {
        return false;
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if meta_a.dev() == meta_b.dev() && meta_a.ino() == meta_b.ino() {
            return true;
        }
    }
    #[cfg(not(unix))]
    let _ = (meta_a, meta_b);
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// Refuses an output path that names the same file as an input (which the write would
/// destroy), compared by [`same_file`]; an output that does not exist yet is always fine.
pub fn ensure_not_same_file(input: &Path, output: &Path) -> Result<()> {
    if same_file(input, output) {
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
    match non_finite_color(img) {
        Some(why) => Err(Error::format(
            path,
            format!("{why} (--sanitize replaces them with 0)"),
        )),
        None => Ok(()),
    }
}

/// Describes the first NaN or infinite value of a colour image (its channel, pixel and value,
/// and how many pixels have one) and what was expected; `None` when every value is finite.
pub fn non_finite_color(img: &ColorImage) -> Option<String> {
    let w = img.width().max(1);
    let (i, p) = img
        .pixels()
        .iter()
        .enumerate()
        .find(|(_, p)| p.iter().any(|v| !v.is_finite()))?;
    let bad = img
        .pixels()
        .iter()
        .filter(|p| p.iter().any(|v| !v.is_finite()))
        .count();
    let k = p.iter().position(|v| !v.is_finite()).unwrap_or(0);
    Some(format!(
        "channel {} at pixel ({}, {}) is {} ({bad} pixel(s) not finite): expected finite colour values",
        ["R", "G", "B", "A"][k],
        i % w,
        i / w,
        p[k]
    ))
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
