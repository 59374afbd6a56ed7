//! Texture images of scene files: PNG or JPEG bytes to a linear-light image with straight alpha.

use image::{DynamicImage, ImageFormat};

use crate::image::{check_size, srgb_decode, ColorImage, Rgba};
use crate::scene::Texture;

/// How the colour channels of a texture are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) enum Encoding {
    /// sRGB-encoded colour (base colour and emissive textures): decoded to linear light.
    Srgb,
    /// Values used as stored (alpha and other data textures).
    Linear,
}

/// The bytes decoding an encoded PNG or JPEG image takes, from its header alone (no pixel
/// decoded): `(kept, passing)`, what the texture keeps (its levels, [`Texture::bytes_for`]) and
/// what only its decoding holds (the decoder's pixels, and for other than 8-bit samples their
/// conversion to floats), with a label of its size for messages. A size over the limits, or a
/// header that does not read, is an error saying so.
pub(super) fn decoded_bytes(bytes: &[u8]) -> Result<(u64, u64, String), String> {
    use image::ImageDecoder;
    let format = image::guess_format(bytes)
        .map_err(|_| "not a PNG or JPEG image (unrecognised file signature)".to_string())?;
    let name = match format {
        ImageFormat::Png => "PNG",
        ImageFormat::Jpeg => "JPEG",
        other => {
            return Err(format!(
                "{other:?} images are not supported: expected PNG or JPEG"
            ))
        }
    };
    let decoder = image::ImageReader::with_format(std::io::Cursor::new(bytes), format)
        .into_decoder()
        .map_err(|e| format!("could not decode the {name} image (corrupt or truncated?): {e}"))?;
    let (w, h) = decoder.dimensions();
    let (w, h) = (w as usize, h as usize);
    check_size(w, h).map_err(|e| e.to_string())?;
    let color = decoder.color_type();
    let eight_bit = color.bytes_per_pixel() == color.channel_count();
    let per_pixel = color.bytes_per_pixel() as u64 + if eight_bit { 0 } else { 16 };
    Ok((
        Texture::bytes_for(w, h),
        (w * h) as u64 * per_pixel,
        format!("{w}x{h}"),
    ))
}

/// Decodes a PNG or JPEG image to linear RGBA with straight (not premultiplied) alpha. Colour
/// is sRGB-decoded for [`Encoding::Srgb`]; alpha is always linear. Grey images fill R, G and B;
/// images without alpha get alpha 1. Errors say what was wrong, without the file name (the
/// caller knows where the bytes came from).
pub(super) fn decode(bytes: &[u8], encoding: Encoding) -> Result<ColorImage, String> {
    let format = image::guess_format(bytes)
        .map_err(|_| "not a PNG or JPEG image (unrecognised file signature)".to_string())?;
    let name = match format {
        ImageFormat::Png => "PNG",
        ImageFormat::Jpeg => "JPEG",
        other => {
            return Err(format!(
                "{other:?} images are not supported: expected PNG or JPEG"
            ))
        }
    };
    let img = image::load_from_memory_with_format(bytes, format)
        .map_err(|e| format!("could not decode the {name} image (corrupt or truncated?): {e}"))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    check_size(w, h).map_err(|e| e.to_string())?;
    let lut: [f32; 256] = std::array::from_fn(|i| {
        let v = i as f32 / 255.0;
        match encoding {
            Encoding::Srgb => srgb_decode(v),
            Encoding::Linear => v,
        }
    });
    let a8 = |a: u8| a as f32 / 255.0;
    let pixels: Vec<Rgba> = match &img {
        DynamicImage::ImageRgb8(b) => b
            .as_raw()
            .chunks_exact(3)
            .map(|p| {
                [
                    lut[p[0] as usize],
                    lut[p[1] as usize],
                    lut[p[2] as usize],
                    1.0,
                ]
            })
            .collect(),
        DynamicImage::ImageRgba8(b) => b
            .as_raw()
            .chunks_exact(4)
            .map(|p| {
                [
                    lut[p[0] as usize],
                    lut[p[1] as usize],
                    lut[p[2] as usize],
                    a8(p[3]),
                ]
            })
            .collect(),
        DynamicImage::ImageLuma8(b) => b
            .as_raw()
            .iter()
            .map(|&l| {
                let v = lut[l as usize];
                [v, v, v, 1.0]
            })
            .collect(),
        DynamicImage::ImageLumaA8(b) => b
            .as_raw()
            .chunks_exact(2)
            .map(|p| {
                let v = lut[p[0] as usize];
                [v, v, v, a8(p[1])]
            })
            .collect(),
        other => {
            let decode = |v: f32| match encoding {
                Encoding::Srgb => srgb_decode(v.clamp(0.0, 1.0)),
                Encoding::Linear => v,
            };
            other
                .to_rgba32f()
                .as_raw()
                .chunks_exact(4)
                .map(|p| [decode(p[0]), decode(p[1]), decode(p[2]), p[3]])
                .collect()
        }
    };
    ColorImage::from_vec(w, h, pixels).map_err(|e| e.to_string())
}

/// Decodes base64 (standard alphabet, `=` padding optional, ASCII whitespace ignored), as in
/// glTF data URIs.
pub(super) fn base64_decode(text: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 3);
    let mut acc: u32 = 0;
    let mut bits = 0;
    let mut padding = 0;
    for (i, c) in text.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => {
                padding += 1;
                continue;
            }
            b' ' | b'\t' | b'\r' | b'\n' => continue,
            _ => {
                return Err(format!(
                    "invalid base64: character {:?} at position {i}",
                    c as char
                ))
            }
        };
        if padding > 0 {
            return Err(format!(
                "invalid base64: data after '=' padding at position {i}"
            ));
        }
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits >= 6 {
        return Err("invalid base64: truncated (a lone final character)".to_string());
    }
    Ok(out)
}

/// Decodes `%XX` escapes of a relative URI into a file path string.
pub(super) fn percent_decode(uri: &str) -> Result<String, String> {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = bytes
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| {
                    format!(
                        "invalid URI '{uri}': '%' at byte {i} is not followed by two hex digits"
                    )
                })?;
            out.push(hex);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| format!("invalid URI '{uri}': escapes do not form UTF-8"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_every_length() {
        const ALPHABET: &[u8; 64] =
            b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        // A plain encoder written from RFC 4648 section 4, as the naive twin.
        let encode = |data: &[u8]| {
            let mut s = String::new();
            for chunk in data.chunks(3) {
                let b = [
                    chunk[0],
                    *chunk.get(1).unwrap_or(&0),
                    *chunk.get(2).unwrap_or(&0),
                ];
                let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
                for k in 0..4 {
                    if k <= chunk.len() {
                        s.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
                    } else {
                        s.push('=');
                    }
                }
            }
            s
        };
        for len in 0..20 {
            let data: Vec<u8> = (0..len).map(|i| (i * 37 + 11) as u8).collect();
            assert_eq!(base64_decode(&encode(&data)).unwrap(), data, "length {len}");
        }
        assert_eq!(base64_decode("TWFu").unwrap(), b"Man");
        assert!(base64_decode("TW!u").is_err());
        assert!(base64_decode("T").is_err());
        assert!(base64_decode("TQ==TQ").is_err());
    }

    #[test]
    fn percent_escapes_decode_and_bad_ones_are_errors() {
        assert_eq!(percent_decode("my%20tex.png").unwrap(), "my tex.png");
        assert_eq!(percent_decode("plain.png").unwrap(), "plain.png");
        assert!(percent_decode("bad%2").is_err());
        assert!(percent_decode("bad%zz.png").is_err());
    }
}
