//! The flags that `render`, `blur` and `compare` share, and their parsers: outputs, focus,
//! f-number, pixels, EXR output and timing reports. Parsers return plain values; the jobs check
//! them against each other.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::builder::{PossibleValue, PossibleValuesParser};
use clap::{Args, ValueEnum};

use crate::error::shown;
use crate::frames::Keyed;
use crate::gpu::{Device, GpuContext};
use crate::image::io::{ExrCompression, ExrOptions};
use crate::methods::registry::{self, METHODS};
use crate::options::parse_numbers;
use crate::timing::Timings;

/// How `--timings` reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TimingFormat {
    /// A table on stderr.
    Table,
    /// One JSON object on stdout.
    Json,
}

/// `--device`: where the method runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ValueEnum)]
pub enum DeviceArg {
    /// The CPU.
    Cpu,
    /// A GPU adapter, a software one (lavapipe) included; an error when there is none.
    Gpu,
    /// A hardware GPU when there is one and the method runs there, else the CPU.
    #[default]
    Auto,
}

impl From<DeviceArg> for Device {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Cpu => Device::Cpu,
            DeviceArg::Gpu => Device::Gpu,
            DeviceArg::Auto => Device::Auto,
        }
    }
}

/// The GPU context of a job running method `id` on `device`, shared by its frames, or `None`
/// for the CPU ([`registry::gpu_context`]).
pub fn open_device(device: DeviceArg, id: &str) -> Result<Option<Arc<GpuContext>>> {
    Ok(registry::gpu_context(device.into(), id)
        .context("--device")?
        .map(Arc::new))
}

/// The device a run took, as `--timings` names it: `cpu`, or the adapter's label
/// ([`crate::gpu::AdapterDescription::label`]).
pub fn device_name(gpu: Option<&GpuContext>) -> String {
    gpu.map_or_else(|| "cpu".to_string(), |g| g.description().label())
}

/// `--method`: every id of the library's registry, with its description as help.
pub fn method_parser() -> PossibleValuesParser {
    PossibleValuesParser::new(
        METHODS
            .iter()
            .map(|m| PossibleValue::new(m.id).help(m.description)),
    )
}

/// Extensions of the image outputs.
pub const IMAGE_EXTENSIONS: &[&str] = &["exr", "png", "pfm"];

/// Checks an output path before any work is done: a supported extension and an existing folder.
pub fn check_output(path: &Path, flag: &str, extensions: &[&str]) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if !extensions.contains(&ext.as_str()) {
        bail!(
            "invalid {flag} {}: expected a file ending in .{}",
            shown(&path),
            extensions.join(", .")
        );
    }
    if path.is_dir() {
        bail!(
            "invalid {flag} {}: it is a folder, expected a file name",
            shown(&path)
        );
    }
    // A device, a FIFO or a link to one: refused before the work, not at the write.
    match crate::output::check_target(path) {
        Err(crate::Error::Invalid { message, .. }) => bail!("invalid {flag}: {message}"),
        other => other?,
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            bail!(
                "invalid {flag} {}: folder {} does not exist",
                shown(&path),
                shown(&parent)
            );
        }
    }
    Ok(())
}

/// Checks an input file before anything opens it: a FIFO, a device or a folder is refused,
/// naming `flag` (opening a FIFO to read it would wait for a writer for ever). A file that does
/// not exist, or cannot be inspected, is left to the read, whose error names it.
pub fn check_input(path: &Path, flag: &str) -> Result<()> {
    match std::fs::metadata(path) {
        Ok(meta) if !meta.is_file() => bail!(
            "invalid {flag} {}: it is {}, not a regular file: expected an image file",
            shown(&path),
            crate::input::kind_of(&meta)
        ),
        _ => Ok(()),
    }
}

/// What one run of a method took, once its outputs are written.
#[derive(Clone, Debug)]
pub struct FrameDone {
    /// The method's id.
    pub method: &'static str,
    /// Where it ran: `cpu`, or the GPU adapter's label.
    pub device: String,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Its passes, reading and writing included.
    pub timings: Timings,
    /// Peak bytes of the method's own storage, where it tracks them.
    pub memory_bytes: Option<usize>,
}

/// `--exr-compression`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ExrCompressionArg {
    /// Uncompressed: the fastest (about 17 ms for 1280x720 RGBA f32 here), 3.4x larger than zip.
    None,
    /// Run-length: fast, compresses only flat areas.
    Rle,
    /// Deflate per scanline (Nuke's default).
    Zips,
    /// Deflate per 16 scanlines (Blender's default): the smallest files, about 4x slower.
    Zip,
    /// Wavelet (PIZ): small for grainy images, the slowest here.
    Piz,
    /// Lossy, fixed rate, for playback: half-float channels only (use with --half; float
    /// channels are stored uncompressed).
    B44,
    /// B44 with flat areas stored smaller.
    B44a,
    /// Lossy DCT over 32 scanlines (level 45, OpenEXR's default): small review files; alpha
    /// stays lossless.
    Dwaa,
    /// DWAA over 256 scanlines: smaller still.
    Dwab,
}

/// How EXR outputs are written.
#[derive(Debug, Args, Clone)]
#[command(next_help_heading = "EXR output")]
pub struct ExrArgs {
    /// Lossless compression of EXR outputs. Measured on a 1280x720 RGBA f32 `blur` output of
    /// `railing` (2 cores, `io/write` with the fsync, least of 3): none 24 ms / 14.8 MB, rle 40 ms
    /// / 13.5 MB, zips 73 ms / 8.3 MB, zip 72 ms / 7.9 MB (both by libdeflate), piz 166 ms / 7.8 MB;
    /// lossy, with --half: b44 22 ms / 3.2 MB, dwaa 44 ms / 0.44 MB, dwab 48 ms / 0.41 MB (57 and
    /// 62 dB PSNR against the uncompressed file; OpenEXR 3.5 reads them).
    #[arg(long, value_enum, default_value_t = ExrCompressionArg::None)]
    pub exr_compression: ExrCompressionArg,
    /// Write EXR colour as 16-bit half floats (half the size; values above 65504 become inf).
    #[arg(long)]
    pub half: bool,
}

impl ExrArgs {
    /// The library's options.
    pub fn options(&self) -> ExrOptions {
        let compression = match self.exr_compression {
            ExrCompressionArg::None => ExrCompression::None,
            ExrCompressionArg::Rle => ExrCompression::Rle,
            ExrCompressionArg::Zips => ExrCompression::Zips,
            ExrCompressionArg::Zip => ExrCompression::Zip,
            ExrCompressionArg::Piz => ExrCompression::Piz,
            ExrCompressionArg::B44 => ExrCompression::B44,
            ExrCompressionArg::B44a => ExrCompression::B44a,
            ExrCompressionArg::Dwaa => ExrCompression::Dwaa,
            ExrCompressionArg::Dwab => ExrCompression::Dwab,
        };
        ExrOptions {
            compression,
            half: self.half,
            placement: None,
        }
    }
}

/// `--focus`: a distance, `auto`, or keyframed distances (for a sequence).
#[derive(Clone, Debug, PartialEq)]
pub enum Focus {
    /// Focus distance in metres.
    Metres(f32),
    /// The depth at the image centre.
    Auto,
    /// Distances in metres keyed to frames (a rack focus over a sequence).
    Keys(Keyed),
}

/// Parses `--focus`: metres, `auto` or keyframes `FRAME:M,...`.
pub fn parse_focus(s: &str) -> Result<Focus, String> {
    if s.trim() == "auto" {
        return Ok(Focus::Auto);
    }
    if s.contains(':') {
        return Keyed::parse(s, "--focus")
            .map(Focus::Keys)
            .map_err(|e| e.to_string());
    }
    s.trim()
        .parse()
        .map(Focus::Metres)
        .map_err(|_| format!("'{s}': expected a distance in metres or 'auto'"))
}

/// `--fstop`: an f-number, or keyframes `FRAME:N,...` (for a sequence).
pub fn parse_fstop(s: &str) -> Result<Keyed, String> {
    Keyed::parse(s, "--fstop").map_err(|e| e.to_string())
}

/// The one value of a flag that may hold keyframes; keyframes outside a sequence are refused.
pub fn single_value(k: &Keyed, flag: &str) -> anyhow::Result<f32> {
    match k.constant_value() {
        Some(v) => Ok(v),
        None => anyhow::bail!(
            "{flag} has keyframes: they need a frame sequence (a frame pattern such as \
             shot.####.exr and --frames)"
        ),
    }
}

/// Parses `X,Y,Z` (three finite numbers).
pub fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    parse_numbers(s)
        .and_then(|v| <[f32; 3]>::try_from(v).ok())
        .ok_or_else(|| format!("'{s}': expected three numbers X,Y,Z"))
}

/// Parses `X,Y` (two pixel indices).
pub fn parse_pixel(s: &str) -> Result<(usize, usize), String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("'{s}': expected a pixel column and row X,Y"))?;
    match (x.trim().parse(), y.trim().parse()) {
        (Ok(x), Ok(y)) => Ok((x, y)),
        _ => Err(format!(
            "'{s}': expected a pixel column and row X,Y (whole numbers from 0)"
        )),
    }
}
