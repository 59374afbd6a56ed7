//! OpenEXR: reading colour, channels and windows (data and display), writing RGBA and named
//! layers.

use super::*;

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
/// How far into an OpenEXR file its headers are searched for their windows (headers come first
/// and are small; a window past this is left to the decoder).
pub(super) const EXR_HEADER_SEARCH_BYTES: u64 = 1 << 16;

/// Refuses an OpenEXR file whose data or display window is inverted (a maximum below its
/// minimum), naming the window and its corners, which the decoder would turn into a wrong
/// size. The windows are `box2i` attributes: the name, `box2i`, the size 16, then xMin, yMin,
/// xMax, yMax as little-endian 32-bit integers.
pub(super) fn check_exr_windows(path: &Path) -> Result<()> {
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
    pub(super) fn name_list(&self) -> String {
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
pub(super) fn ends_with_component(name: &str, suffix: &str) -> bool {
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
    check_exr_decode(path, false)?;
    let chunks = exr::block::read(BufReader::new(open(path)?), false)
        .map_err(|e| exr_read_error(path, e))?;
    exr_channels_from(path, chunks)
}

/// [`read_exr_channels`] of chunks already read from `path`.
pub(super) fn exr_channels_from<R: Read + std::io::Seek>(
    path: &Path,
    chunks: exr::block::reader::Reader<R>,
) -> Result<ExrChannels> {
    for header in chunks.headers() {
        check_header_size(path, header.layer_size.0, header.layer_size.1)?;
        if header.deep {
            return Err(Error::format(
                path,
                "deep OpenEXR data is not supported: expected flat (scanline or tiled) images",
            ));
        }
    }
    if let Some(blocks) = ScanlineBlocks::of(&chunks) {
        return blocks.read_channels(path, chunks);
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

// ---------------------------------------------------------------------------------------------
// EXR internals
// ---------------------------------------------------------------------------------------------

/// Checks that an OpenEXR file is whole ([`super::check_whole`]): its headers and offset tables
/// read and point inside the file, and the chunk of each part that its line order puts last in
/// the file reads to its end (every chunk when the order is unspecified).
pub(super) fn check_exr_whole(path: &Path) -> Result<()> {
    use exr::block::reader::ChunksReader;
    use exr::meta::attribute::LineOrder;
    let reader =
        exr::block::read(BufReader::new(open(path)?), true).map_err(|e| exr_read_error(path, e))?;
    // The filter sees each part's blocks in increasing y order.
    let mut seen = vec![0usize; reader.headers().len()];
    let last = reader
        .filter_chunks(true, |meta, _, block| {
            let header = &meta.headers[block.layer];
            let k = seen[block.layer];
            seen[block.layer] += 1;
            match header.line_order {
                LineOrder::Increasing => k + 1 == header.chunk_count,
                LineOrder::Decreasing => k == 0,
                LineOrder::Unspecified => true,
            }
        })
        .map_err(|e| exr_read_error(path, e))?;
    if last.expected_chunk_count() == 0 {
        return Err(Error::format(
            path,
            "not a whole image: the OpenEXR file has no chunks",
        ));
    }
    for chunk in last {
        chunk.map_err(|e| exr_read_error(path, e))?;
    }
    Ok(())
}

/// An OpenEXR reading error, with the path.
pub(super) fn exr_read_error(path: &Path, err: exr::error::Error) -> Error {
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

/// Whether a file of these headers is one part of R, G, B and perhaps A, every channel
/// sampled at every pixel: its colour is decoded straight into the image's pixels.
fn is_plain_rgba(headers: &[exr::meta::header::Header]) -> bool {
    let [header] = headers else {
        return false;
    };
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
    !header.deep && !subsampled && (names == ["B", "G", "R"] || names == ["A", "B", "G", "R"])
}

/// Bytes of the colour image and of the samples a read adds per pixel besides its decoded
/// channels: the image (RGBA, 16) and a plane of ones for a missing alpha, or the chosen
/// depth channel's copy (4).
const EXR_IMAGE_BYTES_PER_PIXEL: u64 = 20;

/// The peak bytes of reading an OpenEXR file, from its headers (no pixel decoded), and its
/// width and height (the first part's data window); every part's size is checked against the
/// size limits. Every compressed chunk is held (the file's size), then:
/// - a plain RGB(A) file read as colour ([`is_plain_rgba`]) is decoded straight into the
///   image: 16 bytes a pixel;
/// - any other read decodes every channel of every part: its samples as stored (2 or 4 bytes)
///   and as floats (4), then the image or the depth chosen from them
///   ([`EXR_IMAGE_BYTES_PER_PIXEL`]).
pub(super) fn exr_read_peak_bytes(path: &Path, color: bool) -> Result<(u64, (usize, usize))> {
    let file = open(path)?;
    let file_bytes = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let meta = exr::meta::MetaData::read_from_buffered(BufReader::new(file), false)
        .map_err(|e| exr_read_error(path, e))?;
    let first = meta
        .headers
        .first()
        .ok_or_else(|| Error::format(path, "the OpenEXR file has no layers"))?;
    let size = first.layer_size;
    let px = |h: &exr::meta::header::Header| (h.layer_size.0 * h.layer_size.1) as u64;
    for h in meta.headers.iter() {
        check_header_size(path, h.layer_size.0, h.layer_size.1)?;
    }
    let samples = if color && is_plain_rgba(&meta.headers) {
        px(first) * 16
    } else {
        let planes: u64 = meta
            .headers
            .iter()
            .map(|h| {
                let per_pixel: u64 = h
                    .channels
                    .list
                    .iter()
                    .map(|c| c.sample_type.bytes_per_sample() as u64 + 4)
                    .sum();
                px(h) * per_pixel
            })
            .sum();
        planes + px(first) * EXR_IMAGE_BYTES_PER_PIXEL
    };
    Ok((file_bytes + samples, (size.0, size.1)))
}

/// Checks an OpenEXR file's sizes from its headers, and the peak of reading it (as colour, or
/// every channel: [`exr_read_peak_bytes`]) against the memory budget, before any chunk is read.
fn check_exr_decode(path: &Path, color: bool) -> Result<()> {
    let (bytes, (w, h)) = exr_read_peak_bytes(path, color)?;
    check_decode(path, w, h, bytes)
}

/// The RGBA image in an EXR file's channels; see [`read_color`] for the rules.
/// Reads the colour of an OpenEXR file. A file of one part whose only channels are R, G, B
/// and perhaps A (the common case: a render's beauty pass) is decoded straight into the
/// image's pixels; any other (named layers, Y, more channels) goes through
/// [`read_exr_channels`] and [`color_from_exr`], which pick the colour layer.
pub(super) fn read_exr_color(path: &Path) -> Result<ColorImage> {
    check_exr_windows(path)?;
    check_exr_decode(path, true)?;
    let chunks = exr::block::read(BufReader::new(open(path)?), false)
        .map_err(|e| exr_read_error(path, e))?;
    if !is_plain_rgba(chunks.headers()) {
        return color_from_exr(path, &exr_channels_from(path, chunks)?);
    }
    for header in chunks.headers() {
        check_header_size(path, header.layer_size.0, header.layer_size.1)?;
    }
    if let Some(blocks) = ScanlineBlocks::of(&chunks) {
        return blocks.read_rgba(path, chunks);
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

/// A file of one flat scanline part, every channel sampled at every pixel: the common file of
/// renderers and compositors, whose blocks this module decodes itself, in parallel, straight into
/// the image (ZIP and ZIPS blocks inflated by libdeflate, [`super::zip`]; the other compressions
/// by the `exr` crate's codecs). Any other file goes through the crate's reader.
struct ScanlineBlocks {
    /// Width and height of the data window.
    width: usize,
    height: usize,
    /// Lines per block of the compression.
    lines: usize,
    /// The channels in the file's order: name, and bytes per sample (2 for f16, 4 for f32 and
    /// u32) with the sample type.
    channels: Vec<(String, exr::meta::attribute::SampleType)>,
}

/// Hands each sample of one channel's line (f16, f32 or u32, little-endian, as the file stores
/// them) to `put(i, value)`, in a loop per sample type.
#[inline(always)]
fn convert_line(
    line: &[u8],
    sample_type: exr::meta::attribute::SampleType,
    mut put: impl FnMut(usize, f32),
) {
    use exr::meta::attribute::SampleType;
    match sample_type {
        SampleType::F16 => {
            for (i, c) in line.chunks_exact(2).enumerate() {
                put(i, half::f16::from_le_bytes([c[0], c[1]]).to_f32());
            }
        }
        SampleType::F32 => {
            for (i, c) in line.chunks_exact(4).enumerate() {
                put(i, f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
            }
        }
        SampleType::U32 => {
            for (i, c) in line.chunks_exact(4).enumerate() {
                put(i, u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32);
            }
        }
    }
}

impl ScanlineBlocks {
    /// The layout of the file `chunks` reads, when it is such a file.
    fn of<R: Read + std::io::Seek>(chunks: &exr::block::reader::Reader<R>) -> Option<Self> {
        use exr::meta::attribute::SampleType;
        use exr::meta::BlockDescription;
        let [header] = chunks.headers() else {
            return None;
        };
        let flat = !header.deep
            && matches!(header.blocks, BlockDescription::ScanLines)
            && header
                .channels
                .list
                .iter()
                .all(|c| c.sampling == Vec2(1, 1));
        if !flat || !cfg!(target_endian = "little") {
            return None;
        }
        let channels = header
            .channels
            .list
            .iter()
            .map(|c| (c.name.to_string(), c.sample_type))
            .collect::<Vec<(String, SampleType)>>();
        Some(Self {
            width: header.layer_size.0,
            height: header.layer_size.1,
            lines: header.compression.scan_lines_per_block(),
            channels,
        })
    }

    /// Bytes of one line of every channel.
    fn line_bytes(&self) -> usize {
        self.channels
            .iter()
            .map(|(_, t)| t.bytes_per_sample() * self.width)
            .sum()
    }

    /// Reads every chunk of the file (in file order, compressed), each in the slot of its block
    /// from the top of the data window; a missing block is an error naming its lines.
    fn chunks<R: Read + std::io::Seek>(
        &self,
        path: &Path,
        chunks: exr::block::reader::Reader<R>,
    ) -> Result<(exr::meta::MetaData, Vec<exr::block::chunk::Chunk>)> {
        let meta = chunks.meta_data().clone();
        let blocks = self.height.div_ceil(self.lines.max(1));
        let mut slots: Vec<Option<exr::block::chunk::Chunk>> = vec![None; blocks];
        let header = &meta.headers[0];
        for chunk in chunks
            .all_chunks(false)
            .map_err(|e| exr_read_error(path, e))?
        {
            let chunk = chunk.map_err(|e| exr_read_error(path, e))?;
            let index = header
                .get_block_data_indices(&chunk.compressed_block)
                .map_err(|e| exr_read_error(path, e))?;
            // A block must start on its block's first line: the decoder sizes each block's
            // lines from its start, and places them in its slot's rows.
            let start = match &chunk.compressed_block {
                exr::block::chunk::CompressedBlock::ScanLine(b) => {
                    i64::from(b.y_coordinate) - i64::from(header.own_attributes.layer_position.1)
                }
                _ => -1,
            };
            if start != (index.tile_index.1 * self.lines) as i64 {
                return Err(Error::format(
                    path,
                    format!(
                        "a block starts at line {start} of the data window: expected a multiple of {} lines",
                        self.lines
                    ),
                ));
            }
            if let Some(slot) = slots.get_mut(index.tile_index.1) {
                *slot = Some(chunk);
            }
        }
        let mut out = Vec::with_capacity(blocks);
        for (b, slot) in slots.into_iter().enumerate() {
            let Some(chunk) = slot else {
                let y = b * self.lines;
                return Err(Error::format(
                    path,
                    format!(
                        "the block of lines {y} to {} of the data window is missing: the file is truncated or damaged",
                        (y + self.lines).min(self.height) - 1
                    ),
                ));
            };
            out.push(chunk);
        }
        Ok((meta, out))
    }

    /// Decodes `chunk` (block `b`) into `bytes`: its lines' samples, little-endian, channel by
    /// channel within each line.
    fn decode(
        &self,
        path: &Path,
        meta: &exr::meta::MetaData,
        chunk: exr::block::chunk::Chunk,
        bytes: &mut Vec<u8>,
    ) -> Result<()> {
        use exr::block::chunk::CompressedBlock;
        use exr::compression::Compression;
        let header = &meta.headers[0];
        let CompressedBlock::ScanLine(block) = &chunk.compressed_block else {
            return Err(Error::format(path, "a block is not a flat scanline block"));
        };
        let y = i64::from(block.y_coordinate) - i64::from(header.own_attributes.layer_position.1);
        let lines = usize::try_from(y)
            .ok()
            .map_or(0, |y| self.lines.min(self.height.saturating_sub(y)));
        let expected = lines * self.line_bytes();
        let zip = matches!(header.compression, Compression::ZIP1 | Compression::ZIP16);
        let raw = block.compressed_pixels_le.len() == expected;
        if zip && !raw {
            bytes.resize(expected, 0);
            return super::zip::decompress(&block.compressed_pixels_le, bytes).map_err(|e| {
                Error::format(path, format!("lines from {y} of the data window: {e}"))
            });
        }
        let data = exr::block::UncompressedBlock::decompress_chunk(chunk, meta, false)
            .map_err(|e| exr_read_error(path, e))?
            .data;
        if data.len() != expected {
            return Err(Error::format(
                path,
                format!(
                    "lines from {y} of the data window: {} bytes decoded, expected {expected}",
                    data.len()
                ),
            ));
        }
        // Native-endian from the crate: little-endian here (`of` checks).
        *bytes = data;
        Ok(())
    }

    /// The colour of an R, G, B (A) file: alpha 1 where there is no A.
    fn read_rgba<R: Read + std::io::Seek>(
        self,
        path: &Path,
        chunks: exr::block::reader::Reader<R>,
    ) -> Result<ColorImage> {
        use rayon::prelude::*;
        let (meta, blocks) = self.chunks(path, chunks)?;
        let (w, h) = (self.width, self.height);
        let has_alpha = self.channels.iter().any(|(n, _)| n == "A");
        let mut pixels = vec![[0.0f32; 4]; w * h];
        pixels
            .par_chunks_mut((self.lines * w).max(1))
            .zip(blocks)
            .try_for_each_init(Vec::new, |bytes, (rows, chunk)| -> Result<()> {
                self.decode(path, &meta, chunk, bytes)?;
                let mut at = 0;
                for row in rows.chunks_mut(w) {
                    for (name, t) in &self.channels {
                        let k = match name.as_str() {
                            "R" => 0,
                            "G" => 1,
                            "B" => 2,
                            _ => 3,
                        };
                        let n = t.bytes_per_sample() * w;
                        convert_line(&bytes[at..at + n], *t, |i, v| row[i][k] = v);
                        at += n;
                    }
                    if !has_alpha {
                        for p in row.iter_mut() {
                            p[3] = 1.0;
                        }
                    }
                }
                Ok(())
            })?;
        ColorImage::from_vec(w, h, pixels)
    }

    /// Every channel as an `f32` plane.
    fn read_channels<R: Read + std::io::Seek>(
        self,
        path: &Path,
        chunks: exr::block::reader::Reader<R>,
    ) -> Result<ExrChannels> {
        use rayon::prelude::*;
        let (meta, blocks) = self.chunks(path, chunks)?;
        let (w, h) = (self.width, self.height);
        // A part's name prefixes its channels, as the crate's reader has it.
        let prefix = match meta.headers[0].own_attributes.layer_name.as_ref() {
            Some(name) if !name.to_string().is_empty() => format!("{name}."),
            _ => String::new(),
        };
        let decoded: Vec<Vec<u8>> = blocks
            .into_par_iter()
            .map(|chunk| {
                let mut bytes = Vec::new();
                self.decode(path, &meta, chunk, &mut bytes).map(|()| bytes)
            })
            .collect::<Result<_>>()?;
        let line_bytes = self.line_bytes();
        // Where channel c starts within a line.
        let starts: Vec<usize> = self
            .channels
            .iter()
            .scan(0, |at, (_, t)| {
                let s = *at;
                *at += t.bytes_per_sample() * w;
                Some(s)
            })
            .collect();
        let channels = self
            .channels
            .par_iter()
            .zip(starts)
            .map(|((name, t), start)| {
                let mut plane = vec![0.0f32; w * h];
                for (rows, bytes) in plane.chunks_mut((self.lines * w).max(1)).zip(&decoded) {
                    let n = t.bytes_per_sample() * w;
                    for (r, row) in rows.chunks_mut(w).enumerate() {
                        let line = &bytes[r * line_bytes + start..][..n];
                        convert_line(line, *t, |i, v| row[i] = v);
                    }
                }
                (format!("{prefix}{name}"), plane)
            })
            .collect();
        Ok(ExrChannels {
            width: w,
            height: h,
            channels,
        })
    }
}

pub(super) fn color_from_exr(path: &Path, ch: &ExrChannels) -> Result<ColorImage> {
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
pub(super) fn color_prefix(path: &Path, ch: &ExrChannels) -> Result<String> {
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
pub(super) fn depth_channel<'a>(
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
pub(super) fn write_exr(
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
    let headers = image.write().infer_meta_data();
    // The channels in the file's order (sorted by name, as the headers list them).
    let planes = &image.layer_data.channel_data.list;
    set.write(path, |out| {
        write_blocks(out, headers, |y, x0, bw, data| {
            let line = y * width + x0..y * width + x0 + bw;
            // Each channel's line sized once, then filled sample by sample in place.
            fn put<const N: usize, T>(data: &mut Vec<u8>, v: &[T], bytes: impl Fn(&T) -> [u8; N]) {
                let start = data.len();
                data.resize(start + N * v.len(), 0);
                for (d, x) in data[start..].chunks_exact_mut(N).zip(v) {
                    d.copy_from_slice(&bytes(x));
                }
            }
            for channel in planes {
                match &channel.sample_data {
                    FlatSamples::F16(v) => put(data, &v[line.clone()], |h| h.to_ne_bytes()),
                    FlatSamples::F32(v) => put(data, &v[line.clone()], |f| f.to_ne_bytes()),
                    FlatSamples::U32(v) => put(data, &v[line.clone()], |u| u.to_ne_bytes()),
                }
            }
        })
        .map_err(|e| exr_write_error(path, e))
    })
}

/// What a one-part scanline EXR of a `width` x `height` image is written with besides its
/// channels: the data window's attributes, the encoding and the image attributes (display
/// window), as `options` says.
pub(super) fn exr_frame(
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
pub(super) fn exr_write_error(path: &Path, e: exr::error::Error) -> Error {
    match e {
        exr::error::Error::Io(e) => Error::io(path, e),
        other => Error::format(path, format!("could not write OpenEXR: {other}")),
    }
}

/// The headers of a one-part scanline EXR of `width` x `height` RGBA pixels, f16 samples with
/// `half` and f32 otherwise, as the `exr` crate infers them for its own writer.
pub(super) fn rgba_headers(
    width: usize,
    height: usize,
    attributes: LayerAttributes,
    encoding: Encoding,
    frame: exr::meta::header::ImageAttributes,
    half: bool,
) -> exr::meta::Headers {
    macro_rules! headers {
        ($zero:expr) => {{
            let zero = $zero;
            let channels = exr::prelude::SpecificChannels::rgba(move |_: Vec2<usize>| {
                (zero, zero, zero, zero)
            });
            let layer = exr::prelude::Layer::new((width, height), attributes, encoding, channels);
            ExrImage::new(frame, layer).write().infer_meta_data()
        }};
    }
    if half {
        headers!(half::f16::ZERO)
    } else {
        headers!(0.0f32)
    }
}

/// Writes the pixels of an RGBA image `width` wide as the blocks of `headers` (one layer with
/// channels R, G, B, A of one sample type), the lines filled straight from the pixels.
pub(super) fn write_rgba_blocks<W: std::io::Write + std::io::Seek>(
    out: W,
    headers: exr::meta::Headers,
    pixels: &[Rgba],
    width: usize,
) -> exr::error::UnitResult {
    use exr::meta::attribute::SampleType;
    // The file's channel order (sorted by name) as indices into our RGBA.
    let order: Vec<(usize, SampleType)> = headers[0]
        .channels
        .list
        .iter()
        .map(|c| {
            let k = match c.name.to_string().as_str() {
                "R" => 0,
                "G" => 1,
                "B" => 2,
                _ => 3,
            };
            (k, c.sample_type)
        })
        .collect();
    write_blocks(out, headers, |y, x0, bw, data| {
        let line = &pixels[y * width + x0..y * width + x0 + bw];
        for &(k, sample_type) in &order {
            // Sized once, then filled sample by sample in place.
            let start = data.len();
            match sample_type {
                SampleType::F16 => {
                    data.resize(start + 2 * bw, 0);
                    for (d, c) in data[start..].chunks_exact_mut(2).zip(line) {
                        d.copy_from_slice(&half::f16::from_f32(c[k]).to_ne_bytes());
                    }
                }
                _ => {
                    data.resize(start + 4 * bw, 0);
                    for (d, c) in data[start..].chunks_exact_mut(4).zip(line) {
                        d.copy_from_slice(&c[k].to_ne_bytes());
                    }
                }
            }
        }
    })
}

/// A block of native-endian samples as a chunk of the file: ZIP and ZIPS scanline blocks by
/// libdeflate ([`super::zip`]) on little-endian machines (where native is the file's order),
/// every other block by the `exr` crate's codecs.
fn compress_block(
    headers: &[exr::meta::header::Header],
    index: exr::block::BlockIndex,
    data: Vec<u8>,
) -> exr::error::Result<exr::block::chunk::Chunk> {
    use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
    use exr::compression::Compression;
    use exr::meta::BlockDescription;
    let header = &headers[index.layer];
    let zip = matches!(header.compression, Compression::ZIP1 | Compression::ZIP16);
    let scanlines = matches!(header.blocks, BlockDescription::ScanLines);
    let expected = header.channels.bytes_per_pixel * index.pixel_size.area();
    if !(zip && scanlines && cfg!(target_endian = "little"))
        || header.deep
        || data.len() != expected
    {
        return exr::block::UncompressedBlock { index, data }.compress_to_chunk(headers);
    }
    let y = i32::try_from(index.pixel_position.1)
        .ok()
        .and_then(|y| y.checked_add(header.own_attributes.layer_position.1))
        .ok_or(exr::error::Error::Invalid("block position".into()))?;
    Ok(Chunk {
        layer_index: index.layer,
        compressed_block: CompressedBlock::ScanLine(CompressedScanLineBlock {
            y_coordinate: y,
            compressed_pixels_le: super::zip::compress(&data).unwrap_or(data),
        }),
    })
}

/// Blocks of a scanline EXR compressed at a time: a bound on the compressed bytes held.
const BLOCKS_PER_BATCH: usize = 64;

/// Writes the one layer of `headers` block by block: `fill(y, x0, width, bytes)` appends line
/// `y`'s samples from column `x0`, `width` of them, of every channel in the file's order
/// (native-endian). Blocks are filled and compressed in parallel by the crate's codecs, a batch
/// at a time, and their chunks written in order: the same bytes as the `exr` crate's own
/// writer, without its per-sample calls or its thread pool.
fn write_blocks<W: std::io::Write + std::io::Seek>(
    out: W,
    headers: exr::meta::Headers,
    fill: impl Fn(usize, usize, usize, &mut Vec<u8>) + Sync,
) -> exr::error::UnitResult {
    use exr::block::chunk::Chunk;
    use exr::block::writer::ChunksWriter;
    use rayon::prelude::*;
    exr::block::write(out, headers, true, |meta, writer| {
        let bytes_per_pixel = meta.headers[0].channels.bytes_per_pixel;
        let blocks: Vec<(usize, exr::block::BlockIndex)> =
            exr::block::enumerate_ordered_header_block_indices(&meta.headers).collect();
        for batch in blocks.chunks(BLOCKS_PER_BATCH) {
            let chunks: Vec<exr::error::Result<Chunk>> = batch
                .par_iter()
                .map(|&(_, index)| {
                    let (x0, y0) = (index.pixel_position.0, index.pixel_position.1);
                    let (bw, bh) = (index.pixel_size.0, index.pixel_size.1);
                    let mut data = Vec::with_capacity(bytes_per_pixel * bw * bh);
                    for y in y0..y0 + bh {
                        fill(y, x0, bw, &mut data);
                    }
                    compress_block(&meta.headers, index, data)
                })
                .collect();
            for (&(i, _), chunk) in batch.iter().zip(chunks) {
                writer.write_chunk(i, chunk?)?;
            }
        }
        Ok(())
    })
}
