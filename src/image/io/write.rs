//! Writing: every image writer, staged and renamed as one transaction ([`OutputSet`]).

use super::*;

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

/// Writes float32 channels of one size to an uncompressed OpenEXR file (one part), atomically.
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
pub(super) fn write_one(write: impl FnOnce(&mut OutputSet) -> Result<()>) -> Result<()> {
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
                // The header as the `exr` crate infers it for four channels; the blocks are
                // filled straight from our pixels and compressed on our threads.
                let (w, h) = (img.width(), img.height());
                let (attributes, encoding, frame) = exr_frame(w, h, exr);
                let headers = rgba_headers(w, h, attributes, encoding, frame, exr.half);
                self.write(path, |out| {
                    write_rgba_blocks(out, headers, img.pixels(), w)
                        .map_err(|e| exr_write_error(path, e))
                })
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

/// A size check for an image about to be written, naming the output file.
pub(super) fn check_output_size(path: &Path, width: usize, height: usize) -> Result<()> {
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
