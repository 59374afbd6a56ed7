//! PFM: grey and colour floats, either byte order, rows bottom to top.

use super::*;

// ---------------------------------------------------------------------------------------------
// PFM internals
// ---------------------------------------------------------------------------------------------

/// A decoded PFM, rows top to bottom.
pub(super) struct Pfm {
    pub(super) width: usize,
    pub(super) height: usize,
    /// 1 (`Pf`) or 3 (`PF`).
    pub(super) channels: usize,
    pub(super) data: Vec<f32>,
}

/// Reads one whitespace-delimited header token of a PFM file, consuming the single whitespace
/// byte after it. Leading whitespace is skipped.
pub(super) fn pfm_token(
    path: &Path,
    r: &mut impl Read,
    field: &str,
    consumed: &mut u64,
) -> Result<String> {
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

/// A PFM file's header, and the file read up to its pixel data.
pub(super) struct PfmHeader {
    pub(super) width: usize,
    pub(super) height: usize,
    /// 1 (`Pf`) or 3 (`PF`).
    pub(super) channels: usize,
    pub(super) little_endian: bool,
    /// Bytes of pixel data the header asks for (`None` beyond 2^64), and the bytes the file
    /// holds after the header.
    pub(super) expected: Option<u64>,
    pub(super) available: u64,
    pub(super) reader: BufReader<File>,
}

/// Reads a PFM file's header (magic, width, height, scale: byte order from the sign of the
/// scale field, negative meaning little-endian; its magnitude is ignored), and no pixel.
pub(super) fn read_pfm_header(path: &Path) -> Result<PfmHeader> {
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
    Ok(PfmHeader {
        width,
        height,
        channels,
        little_endian: scale < 0.0,
        expected: (width as u64)
            .checked_mul(height as u64)
            .and_then(|n| n.checked_mul(channels as u64 * 4)),
        available: file_len.saturating_sub(consumed),
        reader: r,
    })
}

/// Reads a PFM file (`PF` colour or `Pf` grey, either byte order; see [`read_pfm_header`]).
/// Trailing bytes after the pixel data are ignored.
pub(super) fn read_pfm(path: &Path) -> Result<Pfm> {
    let PfmHeader {
        width,
        height,
        channels,
        little_endian,
        expected,
        available,
        reader: mut r,
    } = read_pfm_header(path)?;
    check_file_size(path, width, height)?;
    // Within the size limit: the byte count fits.
    let expected = expected.unwrap_or(u64::MAX);
    if available < expected {
        return Err(Error::format(
            path,
            format!(
                "truncated PFM: expected {expected} bytes of pixel data for {width}x{height}x{channels} \
                 floats, found {available}"
            ),
        ));
    }
    let expected = expected as usize;
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
pub(super) fn color_from_pfm(pfm: Pfm) -> Result<ColorImage> {
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
pub(super) fn write_pfm(set: &mut OutputSet, path: &Path, img: &ColorImage) -> Result<()> {
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
