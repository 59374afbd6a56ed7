//! Tests: image_io. Round trips through every format, Blender-style multilayer EXR, depth reading
//! and validation, and the errors for missing, truncated and corrupt files and failed writes.

use std::path::{Path, PathBuf};

use defocus::image::io::{
    ensure_not_same_file, radial_to_view_depth, radial_to_view_depth_about, read_color, read_depth,
    read_exr_channels, write_color, write_color_with, write_depth_exr, write_exr_layers,
    write_png16, DepthRead, ExrCompression, ExrOptions, Placement,
};
use defocus::image::{srgb_encode, ColorImage, GrayImage};
use defocus::Error;

/// A scratch directory unique to this process and test, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(test: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("defocus-{}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    /// File names in the directory, sorted.
    fn listing(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A deterministic premultiplied colour test image: straight colour in [0, 1], alpha in
/// [0.25, 1].
fn ldr_image(w: usize, h: usize) -> ColorImage {
    let px = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let a = 0.25 + 0.75 * ((x + y) % 4.0) / 3.0;
            [
                a * x / (w - 1).max(1) as f32,
                a * y / (h - 1).max(1) as f32,
                a * (0.5 + 0.5 * (0.7 * x + 0.3 * y).sin()),
                a,
            ]
        })
        .collect();
    ColorImage::from_vec(w, h, px).unwrap()
}

/// Largest difference between the straight, sRGB-encoded colours (and the alphas) of two
/// premultiplied images: what a PNG stores.
fn max_straight_srgb_difference(a: &ColorImage, b: &ColorImage) -> f32 {
    let straight = |p: [f32; 4]| {
        [
            srgb_encode(p[0] / p[3]),
            srgb_encode(p[1] / p[3]),
            srgb_encode(p[2] / p[3]),
            p[3],
        ]
    };
    a.pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| {
            let (p, q) = (straight(*p), straight(*q));
            (0..4).map(move |c| (p[c] - q[c]).abs())
        })
        .fold(0.0, f32::max)
}

/// The error's full message, with its path.
fn message(err: &Error) -> String {
    err.to_string()
}

/// Writes a file, then cuts it to half its length.
fn truncate_to_half(path: &Path) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..bytes.len() / 2]).unwrap();
}

/// A PFM file built by hand: header, then rows bottom to top.
fn pfm_bytes(magic: &str, w: usize, h: usize, scale: &str, rows_top_first: &[Vec<f32>]) -> Vec<u8> {
    let little = scale.starts_with('-');
    let mut bytes = format!("{magic}\n{w} {h}\n{scale}\n").into_bytes();
    for row in rows_top_first.iter().rev() {
        for v in row {
            bytes.extend(if little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            });
        }
    }
    bytes
}

/// Writes a 16- or 8-bit grey PNG with the `image` crate's encoder.
fn write_grey_png(path: &Path, w: u32, h: u32, values: &[u16], sixteen: bool) {
    use image::ImageEncoder;
    let file = std::fs::File::create(path).unwrap();
    let enc = image::codecs::png::PngEncoder::new(std::io::BufWriter::new(file));
    if sixteen {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_ne_bytes()).collect();
        enc.write_image(&bytes, w, h, image::ExtendedColorType::L16)
            .unwrap();
    } else {
        let bytes: Vec<u8> = values.iter().map(|&v| v as u8).collect();
        enc.write_image(&bytes, w, h, image::ExtendedColorType::L8)
            .unwrap();
    }
}

/// Planes of a colour image, for building multilayer EXRs.
fn planes(img: &ColorImage) -> [Vec<f32>; 4] {
    std::array::from_fn(|c| img.pixels().iter().map(|p| p[c]).collect())
}

#[test]
fn exr_colour_round_trip_is_bit_exact_including_hdr_and_negative_values() {
    let dir = TempDir::new("exr_round_trip");
    let mut img = ldr_image(37, 23);
    *img.get_mut(3, 4) = [1.0e4, -0.25, 65_504.5, 0.0];
    *img.get_mut(36, 22) = [1.0e-30, 3.0, f32::MAX, 2.0];
    let path = dir.join("c.exr");
    write_color(&path, &img).unwrap();
    assert_eq!(read_color(&path).unwrap(), img);
    // Upper-case extensions are recognised too.
    let upper = dir.join("C.EXR");
    write_color(&upper, &img).unwrap();
    assert_eq!(read_color(&upper).unwrap(), img);
}

/// The file the `exr` crate's own writer makes of `img` with the same compression, sample type
/// and windows: one layer of R, G, B, A from a pixel closure.
fn exr_crate_bytes(img: &ColorImage, options: &ExrOptions) -> Vec<u8> {
    use exr::prelude::*;
    let (w, h) = (img.width(), img.height());
    let p = options.placement.unwrap();
    let compression = match options.compression {
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
    let encoding = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let attributes = LayerAttributes {
        layer_position: Vec2(p.data_origin.0, p.data_origin.1),
        ..LayerAttributes::default()
    };
    let frame = ImageAttributes::new(IntegerBounds::new(p.display_origin, p.display_size));
    let px = img.pixels();
    let mut bytes = std::io::Cursor::new(Vec::new());
    if options.half {
        let channels =
            SpecificChannels::rgba(|q: Vec2<usize>| px[q.1 * w + q.0].map(f16::from_f32).into());
        let image = Image::new(frame, Layer::new((w, h), attributes, encoding, channels));
        image.write().to_buffered(&mut bytes).unwrap();
    } else {
        let channels = SpecificChannels::rgba(|q: Vec2<usize>| {
            let c = px[q.1 * w + q.0];
            (c[0], c[1], c[2], c[3])
        });
        let image = Image::new(frame, Layer::new((w, h), attributes, encoding, channels));
        image.write().to_buffered(&mut bytes).unwrap();
    }
    bytes.into_inner()
}

/// Options for a file of `compression` whose data window lies away from its display window.
fn placed(compression: ExrCompression, half: bool) -> ExrOptions {
    ExrOptions {
        compression,
        half,
        placement: Some(Placement {
            data_origin: (-5, 9),
            display_origin: (0, 0),
            display_size: (60, 64),
        }),
    }
}

/// Everything the `exr` crate's own reader decodes from a file's bytes: layers, attributes and
/// samples.
fn exr_crate_decoded(bytes: &[u8]) -> exr::image::FlatImage {
    use exr::prelude::*;
    read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .unwrap()
}

#[test]
fn exr_colour_is_the_exr_crates_own_file_byte_for_byte() {
    // Colour blocks are filled from the pixels and compressed on our threads; the file must be
    // the one the crate's writer makes, for every compression, f32 and f16, with a data window
    // away from the display window and an odd size (partial blocks of 16 and 32 lines). ZIP and
    // ZIPS blocks are deflated by libdeflate instead of the crate's codec: other bytes, so the
    // crate's own reader must decode from them exactly what it decodes from its own file.
    let dir = TempDir::new("exr-crate-bytes");
    let mut img = ldr_image(67, 45);
    for (i, p) in img.pixels_mut().iter_mut().enumerate() {
        // HDR and negative values too.
        p[0] = p[0] * 40.0 - 3.0 + (i % 7) as f32 * 1e-3;
    }
    for compression in ExrCompression::ALL.into_iter().chain(ExrCompression::LOSSY) {
        for half in [false, true] {
            let options = placed(compression, half);
            let path = dir.join("c.exr");
            write_color_with(&path, &img, &options).unwrap();
            let ours = std::fs::read(&path).unwrap();
            let crates = exr_crate_bytes(&img, &options);
            if matches!(compression, ExrCompression::Zip | ExrCompression::Zips) {
                assert!(
                    exr_crate_decoded(&ours) == exr_crate_decoded(&crates),
                    "{compression:?}, half {half}: the crate decodes other samples"
                );
            } else {
                assert!(
                    ours == crates,
                    "{compression:?}, half {half}: the bytes differ from the exr crate's"
                );
            }
        }
    }
}

#[test]
fn exr_reading_decodes_what_the_exr_crate_decodes() {
    // Plain scanline files are decoded block by block on our threads (ZIP and ZIPS by
    // libdeflate): the colour and every channel must be the crate's own decoding of the file it
    // wrote, for every compression, f32 and f16, a data window away from the display window,
    // partial blocks, and a file without alpha.
    use exr::prelude::*;
    let dir = TempDir::new("exr-crate-read");
    let mut img = ldr_image(67, 45);
    for (i, p) in img.pixels_mut().iter_mut().enumerate() {
        p[0] = p[0] * 40.0 - 3.0 + (i % 7) as f32 * 1e-3;
        p[3] = (i % 11) as f32 / 10.0;
    }
    let path = dir.join("c.exr");
    for compression in ExrCompression::ALL.into_iter().chain(ExrCompression::LOSSY) {
        for half in [false, true] {
            let options = placed(compression, half);
            let bytes = exr_crate_bytes(&img, &options);
            std::fs::write(&path, &bytes).unwrap();
            let theirs = exr_crate_decoded(&bytes);
            let layer = &theirs.layer_data[0];
            let plane = |name: &str| -> Vec<f32> {
                let c = layer.channel_data.list.iter();
                let c = c.clone().find(|c| c.name == *name).unwrap();
                c.sample_data.values_as_f32().collect()
            };
            let at = format!("{compression:?}, half {half}");
            let colour = read_color(&path).unwrap();
            let (r, g, b, a) = (plane("R"), plane("G"), plane("B"), plane("A"));
            for (i, p) in colour.pixels().iter().enumerate() {
                assert_eq!(p, &[r[i], g[i], b[i], a[i]], "{at}: pixel {i}");
            }
            let channels = read_exr_channels(&path).unwrap();
            assert_eq!(channels.names(), ["A", "B", "G", "R"], "{at}");
            for name in ["A", "B", "G", "R"] {
                assert_eq!(channels.find(name).unwrap(), plane(name), "{at}: {name}");
            }
        }
    }
    // R, G, B without A: alpha 1.
    let (w, h) = (img.width(), img.height());
    let px = img.pixels();
    let channels = SpecificChannels::rgb(|q: Vec2<usize>| {
        let c = px[q.1 * w + q.0];
        (c[0], c[1], c[2])
    });
    let encoding = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let image = Image::from_layer(Layer::new(
        (w, h),
        LayerAttributes::default(),
        encoding,
        channels,
    ));
    image.write().to_file(&path).unwrap();
    let colour = read_color(&path).unwrap();
    for (p, q) in colour.pixels().iter().zip(px) {
        assert_eq!(p, &[q[0], q[1], q[2], 1.0]);
    }
}

#[test]
fn lossy_exr_compressions_read_back_close_to_what_was_written() {
    // B44 and DWA through `blur`'s writer: a smooth frame comes back within each codec's loss,
    // alpha exactly where the codec keeps it (DWA leaves channels other than colour lossless;
    // B44 compresses half floats only, so float files come back exact).
    let dir = TempDir::new("exr-lossy");
    let (w, h) = (64, 48);
    let px = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            [x, y, 0.5 + 0.4 * (6.0 * x).sin() * y, 0.25 + 0.5 * x]
        })
        .collect();
    let img = ColorImage::from_vec(w, h, px).unwrap();
    let path = dir.join("lossy.exr");
    for compression in ExrCompression::LOSSY {
        for half in [false, true] {
            let options = ExrOptions {
                compression,
                half,
                placement: None,
            };
            write_color_with(&path, &img, &options).unwrap();
            let back = read_color(&path).unwrap();
            let mut worst = [0.0f32; 4];
            for (p, q) in back.pixels().iter().zip(img.pixels()) {
                for k in 0..4 {
                    worst[k] = worst[k].max((p[k] - q[k]).abs());
                }
            }
            let at = format!("{compression:?} half {half}: worst error {worst:?}");
            assert!(worst[..3].iter().all(|&e| e < 0.02), "{at}");
            let exact_alpha = matches!(compression, ExrCompression::Dwaa | ExrCompression::Dwab);
            let alpha_bound = if half { 1e-3 } else { 0.0 };
            if exact_alpha || !half {
                assert!(worst[3] <= alpha_bound, "{at}");
            }
            if !half && matches!(compression, ExrCompression::B44 | ExrCompression::B44a) {
                assert_eq!(back, img, "{at}: float channels are stored as they are");
            }
        }
    }
}

#[test]
fn named_exr_channels_are_the_exr_crates_own_file_byte_for_byte() {
    // Planar channels (a multilayer file's names, unsorted on purpose, placed) go through the
    // same block writer as colour: the file must be the crate's own.
    use exr::prelude::*;
    let dir = TempDir::new("exr-crate-layers");
    let (w, h) = (53usize, 37usize);
    let plane = |k: f32| -> Vec<f32> {
        (0..w * h)
            .map(|i| (i as f32 * 0.37 + k).sin() * 9.0)
            .collect()
    };
    let names = [
        "ViewLayer.Combined.R",
        "ViewLayer.Depth.Z",
        "ViewLayer.Combined.A",
    ];
    let planes: Vec<Vec<f32>> = (0..3).map(|k| plane(k as f32)).collect();
    let given: Vec<(&str, &[f32])> = names
        .iter()
        .zip(&planes)
        .map(|(n, p)| (*n, p.as_slice()))
        .collect();
    let placement = Placement {
        data_origin: (3, -2),
        display_origin: (0, 0),
        display_size: (64, 40),
    };
    let path = dir.join("layers.exr");
    defocus::image::io::write_exr_layers_placed(&path, w, h, &given, Some(placement)).unwrap();
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = given
        .iter()
        .map(|(n, p)| AnyChannel::new(Text::from(*n), FlatSamples::F32(p.to_vec())))
        .collect();
    let encoding = Encoding {
        compression: Compression::Uncompressed,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let attributes = LayerAttributes {
        layer_position: Vec2(3, -2),
        ..LayerAttributes::default()
    };
    let frame = ImageAttributes::new(IntegerBounds::new((0, 0), (64, 40)));
    let layer = Layer::new((w, h), attributes, encoding, AnyChannels::sort(list));
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::new(frame, layer)
        .write()
        .to_buffered(&mut bytes)
        .unwrap();
    assert!(
        std::fs::read(&path).unwrap() == bytes.into_inner(),
        "named channels differ"
    );
}

#[test]
fn png_8bit_round_trip_is_within_half_a_code_value_after_srgb_encoding() {
    let dir = TempDir::new("png8_round_trip");
    let img = ldr_image(19, 11);
    let path = dir.join("c.png");
    write_color(&path, &img).unwrap();
    let back = read_color(&path).unwrap();
    assert_eq!((back.width(), back.height()), (19, 11));
    let d = max_straight_srgb_difference(&img, &back);
    assert!(d <= 0.5 / 255.0 + 1e-6, "{d}");
}

#[test]
fn png_16bit_round_trip_is_within_half_a_16bit_step() {
    let dir = TempDir::new("png16_round_trip");
    let img = ldr_image(13, 9);
    let path = dir.join("c16.png");
    write_png16(&path, &img).unwrap();
    let back = read_color(&path).unwrap();
    let d = max_straight_srgb_difference(&img, &back);
    assert!(d <= 0.5 / 65535.0 + 1e-6, "{d}");
}

#[test]
fn png_straight_alpha_is_premultiplied_on_reading() {
    use image::ImageEncoder;
    let dir = TempDir::new("png_premultiply");
    let path = dir.join("rgba.png");
    let file = std::fs::File::create(&path).unwrap();
    image::codecs::png::PngEncoder::new(std::io::BufWriter::new(file))
        .write_image(&[255, 128, 0, 51], 1, 1, image::ExtendedColorType::Rgba8)
        .unwrap();
    let p = read_color(&path).unwrap().get(0, 0);
    let a = 51.0 / 255.0;
    let want = [a, defocus::image::srgb_decode(128.0 / 255.0) * a, 0.0, a];
    for c in 0..4 {
        assert!((p[c] - want[c]).abs() < 1e-6, "{p:?} vs {want:?}");
    }
}

#[test]
fn png_writing_clamps_hdr_colour_and_alpha_and_zeroes_colour_without_alpha() {
    let dir = TempDir::new("png_clamps");
    let img = ColorImage::from_vec(
        2,
        1,
        vec![[4.0, -1.0, 0.5, 7.0], [f32::NAN, 1.0, 0.0, -3.0]],
    )
    .unwrap();
    let path = dir.join("c.png");
    write_color(&path, &img).unwrap();
    let back = read_color(&path).unwrap();
    assert_eq!(back.get(0, 0)[0], 1.0);
    assert_eq!(back.get(0, 0)[1], 0.0);
    assert_eq!(back.get(0, 0)[3], 1.0);
    assert_eq!(back.get(1, 0), [0.0; 4]);
}

#[test]
fn grey_png_reads_as_grey_with_opaque_alpha() {
    let dir = TempDir::new("grey_png");
    let path = dir.join("g.png");
    write_grey_png(&path, 3, 1, &[0, 128, 255], false);
    let img = read_color(&path).unwrap();
    for (p, v) in img.pixels().iter().zip([0.0f32, 128.0 / 255.0, 1.0]) {
        let lin = defocus::image::srgb_decode(v);
        assert_eq!(*p, [lin, lin, lin, 1.0]);
    }
}

#[test]
fn depth_from_16bit_png_is_value_over_65535_times_scale_without_srgb() {
    let dir = TempDir::new("depth_png16");
    let path = dir.join("d.png");
    write_grey_png(&path, 2, 2, &[1, 1000, 32768, 65535], true);
    let opts = DepthRead {
        scale: 100.0,
        ..Default::default()
    };
    let depth = read_depth(&path, &opts).unwrap();
    let expect = [1.0, 1000.0, 32768.0, 65535.0].map(|v: f32| v / 65535.0 * 100.0);
    for (d, e) in depth.pixels().iter().zip(expect) {
        assert!((d - e).abs() <= 1e-5 * e, "{d} vs {e}");
    }
}

#[test]
fn depth_from_8bit_png_is_value_over_255_times_scale() {
    let dir = TempDir::new("depth_png8");
    let path = dir.join("d.png");
    write_grey_png(&path, 3, 1, &[1, 51, 255], false);
    let opts = DepthRead {
        scale: 10.0,
        ..Default::default()
    };
    let depth = read_depth(&path, &opts).unwrap();
    let expect = [10.0 / 255.0, 2.0, 10.0];
    for (d, e) in depth.pixels().iter().zip(expect) {
        assert!((d - e).abs() <= 1e-6 * e, "{d} vs {e}");
    }
}

#[test]
fn depth_png_in_colour_is_refused_with_the_channel_count() {
    let dir = TempDir::new("depth_png_rgb");
    let path = dir.join("d.png");
    write_color(&path, &ldr_image(4, 4)).unwrap();
    let err = read_depth(&path, &DepthRead::default()).unwrap_err();
    let msg = message(&err);
    assert!(msg.contains("d.png") && msg.contains("grey"), "{msg}");
}

#[test]
fn little_endian_colour_pfm_rows_are_flipped_to_top_first() {
    let dir = TempDir::new("pfm_le");
    let path = dir.join("c.pfm");
    let rows = vec![
        vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        vec![-7.0, 8.5, 9.0, 1e6, 0.125, 12.0],
    ];
    std::fs::write(&path, pfm_bytes("PF", 2, 2, "-1.0", &rows)).unwrap();
    let img = read_color(&path).unwrap();
    assert_eq!(img.get(0, 0), [1.0, 2.0, 3.0, 1.0]);
    assert_eq!(img.get(1, 0), [4.0, 5.0, 6.0, 1.0]);
    assert_eq!(img.get(0, 1), [-7.0, 8.5, 9.0, 1.0]);
    assert_eq!(img.get(1, 1), [1e6, 0.125, 12.0, 1.0]);
}

#[test]
fn big_endian_grey_pfm_reads_as_grey_and_as_depth() {
    let dir = TempDir::new("pfm_be");
    let path = dir.join("g.pfm");
    let rows = vec![vec![1.5, 2.5, 3.5], vec![4.5, 5.5, 6.5]];
    std::fs::write(&path, pfm_bytes("Pf", 3, 2, "1.0", &rows)).unwrap();
    let img = read_color(&path).unwrap();
    assert_eq!(img.get(2, 0), [3.5, 3.5, 3.5, 1.0]);
    assert_eq!(img.get(0, 1), [4.5, 4.5, 4.5, 1.0]);
    let depth = read_depth(
        &path,
        &DepthRead {
            scale: 2.0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(depth.pixels(), &[3.0, 5.0, 7.0, 9.0, 11.0, 13.0]);
}

#[test]
fn colour_pfm_round_trip_is_exact_and_drops_alpha() {
    let dir = TempDir::new("pfm_round_trip");
    let mut img = ldr_image(7, 5);
    *img.get_mut(6, 4) = [123.0, -4.0, 0.0, 0.5];
    let path = dir.join("c.pfm");
    write_color(&path, &img).unwrap();
    let back = read_color(&path).unwrap();
    let opaque = img.map(|p| [p[0], p[1], p[2], 1.0]);
    assert_eq!(back, opaque);
}

#[test]
fn multilayer_exr_gives_the_combined_colour_and_the_depth_z_without_a_channel_name() {
    let dir = TempDir::new("multilayer");
    let (w, h) = (6, 4);
    let img = ldr_image(w, h);
    let [r, g, b, a] = planes(&img);
    let z: Vec<f32> = (0..w * h).map(|i| 1.0 + i as f32).collect();
    let noise = vec![0.5f32; w * h];
    let path = dir.join("blender.exr");
    write_exr_layers(
        &path,
        w,
        h,
        &[
            ("ViewLayer.Combined.R", &r),
            ("ViewLayer.Combined.G", &g),
            ("ViewLayer.Combined.B", &b),
            ("ViewLayer.Combined.A", &a),
            ("ViewLayer.DiffCol.R", &noise),
            ("ViewLayer.DiffCol.G", &noise),
            ("ViewLayer.DiffCol.B", &noise),
            ("ViewLayer.Depth.Z", &z),
        ],
    )
    .unwrap();
    assert_eq!(read_color(&path).unwrap(), img);
    let depth = read_depth(&path, &DepthRead::default()).unwrap();
    assert_eq!(depth.pixels(), z.as_slice());

    let all = read_exr_channels(&path).unwrap();
    assert_eq!((all.width, all.height), (w, h));
    assert_eq!(all.find("ViewLayer.Depth.Z"), Some(z.as_slice()));
    assert_eq!(all.find("Z"), None);
    let by_suffix = all.find_by_suffix("depth.z");
    assert_eq!(by_suffix.len(), 1);
    assert_eq!(by_suffix[0].0, "ViewLayer.Depth.Z");
    assert_eq!(all.find_by_suffix("R").len(), 2);
}

#[test]
fn depth_channel_can_be_named_in_full_or_by_a_unique_suffix() {
    let dir = TempDir::new("depth_named");
    let (w, h) = (3, 2);
    let near = vec![0.5f32; w * h];
    let far = vec![9.0f32; w * h];
    let path = dir.join("two.exr");
    write_exr_layers(&path, w, h, &[("A.Depth.Z", &near), ("B.Depth.Z", &far)]).unwrap();
    let pick = |name: &str| {
        let opts = DepthRead {
            channel: Some(name.to_string()),
            ..Default::default()
        };
        read_depth(&path, &opts)
    };
    assert_eq!(pick("B.Depth.Z").unwrap().pixels(), far.as_slice());
    assert_eq!(pick("a.depth.z").unwrap().pixels(), near.as_slice());
    let msg = message(&pick("Mist").unwrap_err());
    assert!(
        msg.contains("'Mist'") && msg.contains("A.Depth.Z, B.Depth.Z"),
        "{msg}"
    );
    // Two view layers and no choice: the error lists both.
    let msg = message(&read_depth(&path, &DepthRead::default()).unwrap_err());
    assert!(
        msg.contains("two.exr") && msg.contains("A.Depth.Z, B.Depth.Z"),
        "{msg}"
    );
}

#[test]
fn plain_rgb_wins_over_layers_and_a_grey_y_channel_reads_as_grey() {
    let dir = TempDir::new("exr_choices");
    let (w, h) = (2, 2);
    let one = vec![1.0f32; 4];
    let two = vec![2.0f32; 4];
    let mixed = dir.join("mixed.exr");
    write_exr_layers(
        &mixed,
        w,
        h,
        &[
            ("R", &one),
            ("G", &one),
            ("B", &one),
            ("L.Combined.R", &two),
            ("L.Combined.G", &two),
            ("L.Combined.B", &two),
        ],
    )
    .unwrap();
    assert_eq!(read_color(&mixed).unwrap().get(1, 1), [1.0, 1.0, 1.0, 1.0]);

    let grey = dir.join("grey.exr");
    let y: Vec<f32> = vec![0.1, 0.2, 0.3, 0.4];
    let alpha = vec![0.5f32; 4];
    write_exr_layers(&grey, w, h, &[("Y", &y), ("A", &alpha)]).unwrap();
    let img = read_color(&grey).unwrap();
    assert_eq!(img.get(1, 1), [0.4, 0.4, 0.4, 0.5]);
}

#[test]
fn depth_exr_round_trip_is_exact_and_plus_infinity_reads_as_far() {
    let dir = TempDir::new("depth_round_trip");
    let mut depth = GrayImage::new(5, 3, 2.0);
    *depth.get_mut(4, 2) = 1e10;
    *depth.get_mut(0, 1) = 0.125;
    let path = dir.join("z.exr");
    write_depth_exr(&path, &depth).unwrap();
    assert_eq!(read_depth(&path, &DepthRead::default()).unwrap(), depth);
    let names = read_exr_channels(&path).unwrap();
    assert_eq!(names.names(), vec!["Z"]);

    *depth.get_mut(1, 1) = f32::INFINITY;
    write_depth_exr(&path, &depth).unwrap();
    let back = read_depth(&path, &DepthRead::default()).unwrap();
    assert_eq!(back.get(1, 1), f32::MAX);
}

#[test]
fn nan_negative_and_zero_depths_are_reported_with_the_first_pixel_and_the_count() {
    let dir = TempDir::new("bad_depth");
    let path = dir.join("bad.exr");
    let mut depth = GrayImage::new(4, 3, 3.0);
    *depth.get_mut(2, 1) = f32::NAN;
    *depth.get_mut(0, 2) = -1.5;
    *depth.get_mut(3, 2) = 0.0;
    write_depth_exr(&path, &depth).unwrap();
    let msg = message(&read_depth(&path, &DepthRead::default()).unwrap_err());
    assert!(msg.contains("bad.exr"), "{msg}");
    assert!(msg.contains("(x 2, y 1)") && msg.contains("NaN"), "{msg}");
    assert!(msg.contains("3 pixel(s)") && msg.contains("'Z'"), "{msg}");

    let mut depth = GrayImage::new(4, 3, 3.0);
    *depth.get_mut(1, 2) = -1.5;
    write_depth_exr(&path, &depth).unwrap();
    let msg = message(&read_depth(&path, &DepthRead::default()).unwrap_err());
    assert!(
        msg.contains("(x 1, y 2) = -1.5") && msg.contains("1 pixel(s)"),
        "{msg}"
    );
}

#[test]
fn depth_scale_must_be_positive_and_finite() {
    let dir = TempDir::new("depth_scale");
    let path = dir.join("z.exr");
    write_depth_exr(&path, &GrayImage::new(2, 2, 1.0)).unwrap();
    for scale in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let opts = DepthRead {
            scale,
            ..Default::default()
        };
        let err = read_depth(&path, &opts).unwrap_err();
        assert!(
            matches!(
                err,
                Error::Invalid {
                    name: "depth scale",
                    ..
                }
            ),
            "{err}"
        );
    }
}

#[test]
fn radial_distance_becomes_view_depth_by_the_pinhole_angle() {
    let (w, h, f_px) = (8, 6, 5.0f32);
    let mut depth = GrayImage::new(w, h, 10.0);
    radial_to_view_depth(&mut depth, f_px);
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f64 + 0.5 - 4.0, y as f64 + 0.5 - 3.0);
            let cos = 1.0 / (1.0 + (dx * dx + dy * dy) / (f_px as f64).powi(2)).sqrt();
            let want = (10.0 * cos) as f32;
            assert!((depth.get(x, y) - want).abs() < 1e-5, "({x}, {y})");
        }
    }
    // Pixels next to the centre (0.5 px off axis) barely change; corners shrink most.
    assert!(depth.get(4, 3) > 9.9 && depth.get(0, 0) < depth.get(1, 1));
}

/// A part of a frame (an OpenEXR data window) is converted about the frame's centre: the same
/// values as the whole frame's conversion, cut at the part's place.
#[test]
fn radial_distance_of_a_part_of_the_frame_turns_about_the_frame_centre() {
    let (w, h, f_px) = (8, 6, 5.0f32);
    let mut whole = GrayImage::new(w, h, 10.0);
    radial_to_view_depth(&mut whole, f_px);
    // The part from (5, 2), 3x4 pixels: the frame's centre (4, 3) is at (-1, 1) in it.
    let mut part = GrayImage::new(3, 4, 10.0);
    radial_to_view_depth_about(&mut part, f_px, (-1.0, 1.0));
    for y in 0..4 {
        for x in 0..3 {
            assert_eq!(part.get(x, y), whole.get(x + 5, y + 2), "({x}, {y})");
        }
    }
}

#[test]
fn cycles_pinhole_exr_gives_colour_and_depth_of_the_calibration_scene() {
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    let path = assets.join("cycles/pinhole.exr");
    let color = read_color(&path).unwrap();
    assert_eq!((color.width(), color.height()), (480, 270));
    assert!(color.pixels().iter().all(|p| p[3] == 1.0));
    // The background wall reads 0.0300003 (README).
    let wall = color.get(2, 268);
    assert!((wall[0] - 0.03).abs() < 1e-4, "{wall:?}");

    let depth = read_depth(&path, &DepthRead::default()).unwrap();
    assert_eq!((depth.width(), depth.height()), (480, 270));
    let count = |z: f32| depth.pixels().iter().filter(|&&d| d == z).count();
    assert_eq!(count(2.0), 62_302);
    assert_eq!(count(20.0), 63_945);
    assert!(count(0.6) > 0);
}

#[test]
fn missing_file_error_names_the_path() {
    let dir = TempDir::new("missing");
    for name in ["nope.exr", "nope.png", "nope.pfm"] {
        let path = dir.join(name);
        let err = read_color(&path).unwrap_err();
        assert!(matches!(err, Error::Io { .. }), "{err}");
        assert!(message(&err).contains(name), "{err}");
        let err = read_depth(&path, &DepthRead::default()).unwrap_err();
        assert!(message(&err).contains(name), "{err}");
    }
}

#[test]
fn truncated_exr_png_and_pfm_are_format_errors_naming_the_file() {
    let dir = TempDir::new("truncated");
    let img = ldr_image(64, 48);
    for name in ["cut.exr", "cut.png", "cut.pfm"] {
        let path = dir.join(name);
        write_color(&path, &img).unwrap();
        truncate_to_half(&path);
        let err = read_color(&path).unwrap_err();
        assert!(matches!(err, Error::Format { .. }), "{name}: {err}");
        assert!(message(&err).contains(name), "{err}");
    }
    let msg = message(&read_color(&dir.join("cut.pfm")).unwrap_err());
    let expected = 64 * 48 * 3 * 4;
    assert!(
        msg.contains(&format!("expected {expected} bytes of pixel data")),
        "{msg}"
    );
    // A depth EXR cut short is reported the same way.
    let z = dir.join("cut_z.exr");
    write_depth_exr(&z, &GrayImage::new(64, 48, 1.0)).unwrap();
    truncate_to_half(&z);
    let err = read_depth(&z, &DepthRead::default()).unwrap_err();
    assert!(message(&err).contains("cut_z.exr"), "{err}");
}

#[test]
fn random_bytes_named_exr_png_or_pfm_are_format_errors() {
    let dir = TempDir::new("random_bytes");
    // A fixed xorshift sequence: the same "random" file every run.
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let bytes: Vec<u8> = (0..4096)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 24) as u8
        })
        .collect();
    for name in ["noise.exr", "noise.png", "noise.pfm"] {
        let path = dir.join(name);
        std::fs::write(&path, &bytes).unwrap();
        let err = read_color(&path).unwrap_err();
        assert!(matches!(err, Error::Format { .. }), "{name}: {err}");
        assert!(message(&err).contains(name), "{err}");
    }
    // An empty file too.
    let empty = dir.join("empty.exr");
    std::fs::write(&empty, b"").unwrap();
    assert!(read_color(&empty).is_err());
}

#[test]
fn exr_without_colour_channels_lists_the_channels_it_has() {
    let dir = TempDir::new("no_rgb");
    let path = dir.join("zonly.exr");
    let v = vec![1.0f32; 6];
    write_exr_layers(&path, 3, 2, &[("Z", &v), ("Mist", &v), ("N.X", &v)]).unwrap();
    let msg = message(&read_color(&path).unwrap_err());
    assert!(msg.contains("zonly.exr"), "{msg}");
    for name in ["Mist", "N.X", "Z"] {
        assert!(msg.contains(name), "{msg}");
    }
    // And a file without depth lists its channels for read_depth.
    let rgb = dir.join("rgb.exr");
    write_color(&rgb, &ldr_image(3, 2)).unwrap();
    let msg = message(&read_depth(&rgb, &DepthRead::default()).unwrap_err());
    assert!(
        msg.contains("rgb.exr") && msg.contains("A, B, G, R"),
        "{msg}"
    );
}

#[test]
fn pfm_header_larger_than_the_pixel_limit_is_refused_before_reading_pixels() {
    let dir = TempDir::new("huge_pfm");
    let path = dir.join("huge.pfm");
    std::fs::write(&path, b"PF\n100000 100000\n-1.0\n\0\0\0\0").unwrap();
    let msg = message(&read_color(&path).unwrap_err());
    assert!(
        msg.contains("huge.pfm") && msg.contains("100000x100000"),
        "{msg}"
    );
    let zero = dir.join("zero.pfm");
    std::fs::write(&zero, b"Pf\n0 5\n-1.0\n").unwrap();
    let msg = message(&read_color(&zero).unwrap_err());
    assert!(msg.contains("zero.pfm") && msg.contains("0x5"), "{msg}");
    let bad = dir.join("bad.pfm");
    std::fs::write(&bad, b"PF\n4 four\n-1.0\n").unwrap();
    let msg = message(&read_color(&bad).unwrap_err());
    assert!(
        msg.contains("bad.pfm") && msg.contains("height") && msg.contains("'four'"),
        "{msg}"
    );
}

#[test]
fn unknown_extension_is_refused_naming_the_path_and_the_supported_formats() {
    let dir = TempDir::new("unknown_ext");
    let path = dir.join("out.jpg");
    let msg = message(&write_color(&path, &ldr_image(2, 2)).unwrap_err());
    assert!(
        msg.contains("out.jpg") && msg.contains(".exr, .png, .pfm"),
        "{msg}"
    );
    assert!(dir.listing().is_empty());
    let msg = message(&read_color(&dir.join("in")).unwrap_err());
    assert!(msg.contains("no file extension"), "{msg}");
}

#[test]
fn writing_into_a_missing_directory_fails_and_leaves_no_file() {
    let dir = TempDir::new("missing_dir");
    let path = dir.join("not/here/out.exr");
    let err = write_color(&path, &ldr_image(2, 2)).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err}");
    assert!(message(&err).contains("out.exr"), "{err}");
    assert!(dir.listing().is_empty());
}

#[test]
fn a_failed_write_leaves_no_file_and_no_temporary_file() {
    let dir = TempDir::new("failed_write");
    // The target is a directory: the data is written, then the rename fails.
    let target = dir.join("taken.png");
    std::fs::create_dir(&target).unwrap();
    assert!(write_color(&target, &ldr_image(4, 4)).is_err());
    assert!(target.is_dir());
    assert_eq!(dir.listing(), vec!["taken.png".to_string()]);
    // Bad channel data fails before anything is created.
    let exr = dir.join("bad.exr");
    let short = vec![1.0f32; 3];
    let err = write_exr_layers(&exr, 2, 2, &[("R", &short)]).unwrap_err();
    assert!(message(&err).contains("'R'"), "{err}");
    let err = write_exr_layers(&exr, 2, 2, &[("Z", &[1.0; 4]), ("Z", &[2.0; 4])]).unwrap_err();
    assert!(message(&err).contains("twice"), "{err}");
    // An empty image is refused.
    let empty = ColorImage::new(0, 3, [0.0; 4]);
    assert!(write_color(&dir.join("empty.png"), &empty).is_err());
    assert_eq!(dir.listing(), vec!["taken.png".to_string()]);
}

#[test]
fn writing_over_an_existing_file_replaces_it_whole() {
    let dir = TempDir::new("overwrite");
    let path = dir.join("c.exr");
    write_color(&path, &ldr_image(8, 8)).unwrap();
    let second = ldr_image(3, 5);
    write_color(&path, &second).unwrap();
    assert_eq!(read_color(&path).unwrap(), second);
    assert_eq!(dir.listing(), vec!["c.exr".to_string()]);
}

#[test]
fn output_naming_the_input_file_is_refused() {
    let dir = TempDir::new("same_file");
    let input = dir.join("in.exr");
    write_color(&input, &ldr_image(2, 2)).unwrap();
    let same = dir.0.join(".").join("in.exr");
    let err = ensure_not_same_file(&input, &same).unwrap_err();
    assert!(message(&err).contains("in.exr"), "{err}");
    assert!(ensure_not_same_file(&input, &dir.join("out.exr")).is_ok());
    write_color(&dir.join("other.exr"), &ldr_image(2, 2)).unwrap();
    assert!(ensure_not_same_file(&input, &dir.join("other.exr")).is_ok());
}

#[test]
fn jpeg_colour_is_read_and_srgb_decoded_and_refused_as_depth_or_output() {
    let dir = TempDir::new("jpeg");
    let path = dir.join("photo.jpg");
    // A flat mid-grey JPEG: lossless enough at full quality for a flat image.
    let img = image::RgbImage::from_pixel(16, 8, image::Rgb([128, 128, 128]));
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 100)
        .encode_image(&img)
        .unwrap();
    std::fs::write(&path, &bytes).unwrap();
    let c = defocus::image::io::read_color(&path).unwrap();
    assert_eq!((c.width(), c.height()), (16, 8));
    // sRGB 128/255 is linear 0.2158.
    for p in c.pixels() {
        assert!((p[0] - 0.2158).abs() < 0.01 && p[3] == 1.0, "{p:?}");
    }
    let e = defocus::image::io::read_depth(&path, &Default::default()).unwrap_err();
    assert!(e.to_string().contains("JPEG"), "{e}");
    let e = defocus::image::io::write_color(&dir.join("out.jpg"), &c).unwrap_err();
    assert!(e.to_string().contains("JPEG"), "{e}");
}

/// A data window's place in its display window: the offset, whether it is the whole frame, and
/// the frame's centre as a pixel of the image (clamped into it when the image does not reach it).
#[test]
fn placement_gives_the_offset_and_the_frame_centre_in_image_pixels() {
    let p = Placement {
        data_origin: (106, 54),
        display_origin: (100, 50),
        display_size: (48, 32),
    };
    assert_eq!(p.offset(), (6, 4));
    assert!(!p.is_full(48, 32));
    // The frame's centre pixel (24, 16) is the image's (18, 12).
    assert_eq!(p.frame_centre_in_image(36, 24), (18, 12));
    // An image in the frame's top-left 10x10 corner: its nearest pixel to the centre.
    assert_eq!(p.frame_centre_in_image(10, 10), (9, 9));
    let full = Placement::full(48, 32);
    assert!(full.is_full(48, 32) && !full.is_full(48, 31));
    assert_eq!(full.frame_centre_in_image(48, 32), (24, 16));
    // Overscan: the image starts 8 pixels before the frame.
    let over = Placement {
        data_origin: (-8, -8),
        display_origin: (0, 0),
        display_size: (48, 32),
    };
    assert_eq!(over.offset(), (-8, -8));
    assert_eq!(over.frame_centre_in_image(64, 48), (32, 24));
}

/// Inverse depth (Nuke's ScanlineRender: 1 / depth, 0 for infinitely far) is inverted before
/// the scale; NaN, negative and infinite inverse depths are refused with the first pixel.
#[test]
fn inverse_depth_is_inverted_before_the_scale_and_zero_is_far() {
    let dir = TempDir::new("inverse");
    let path = dir.join("inv.exr");
    write_exr_layers(&path, 4, 1, &[("Z", &[0.5, 0.0, 0.25, 2.0])]).unwrap();
    for (scale, expect) in [
        (1.0, [2.0, f32::MAX, 4.0, 0.5]),
        (10.0, [20.0, f32::MAX, 40.0, 5.0]),
    ] {
        let opts = DepthRead {
            scale,
            inverse: true,
            ..Default::default()
        };
        let depth = read_depth(&path, &opts).unwrap();
        assert_eq!(depth.pixels(), &expect, "scale {scale}");
    }
    for (bad, name) in [(-1.0, "-1"), (f32::NAN, "NaN"), (f32::INFINITY, "inf")] {
        write_exr_layers(&path, 3, 1, &[("Z", &[0.5, bad, bad])]).unwrap();
        let opts = DepthRead {
            inverse: true,
            ..Default::default()
        };
        let err = read_depth(&path, &opts).unwrap_err().to_string();
        assert!(
            err.contains("inv.exr")
                && err.contains("inverse depth")
                && err.contains("2 pixel(s)")
                && err.contains("(x 1, y 0)")
                && err.contains(name),
            "{err}"
        );
    }
}

/// Some renderers write 0 for "no surface": refused by default with a hint, read as far when
/// asked; negative depth stays an error either way.
#[test]
fn zero_depth_is_refused_with_a_hint_or_read_as_far_when_asked() {
    let dir = TempDir::new("zerofar");
    let path = dir.join("z.exr");
    write_exr_layers(&path, 3, 1, &[("Z", &[2.0, 0.0, 5.0])]).unwrap();
    let err = read_depth(&path, &DepthRead::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("(x 1, y 0)") && err.contains("--zero-depth-is-far"),
        "{err}"
    );
    let far = DepthRead {
        zero_is_far: true,
        ..Default::default()
    };
    assert_eq!(
        read_depth(&path, &far).unwrap().pixels(),
        &[2.0, f32::MAX, 5.0]
    );
    write_exr_layers(&path, 3, 1, &[("Z", &[2.0, 0.0, -5.0])]).unwrap();
    let err = read_depth(&path, &far).unwrap_err().to_string();
    assert!(
        err.contains("(x 2, y 0)") && err.contains("1 pixel(s)"),
        "{err}"
    );
}

/// An EXR whose display or data window is inverted (its maximum corner before its minimum) is
/// refused naming the window and its corners, not read at a made-up size.
#[test]
fn an_inverted_exr_window_is_refused_naming_it() {
    let dir = TempDir::new("exr-inverted");
    let good = dir.join("good.exr");
    write_color(&good, &ColorImage::new(6, 4, [0.5, 0.5, 0.5, 1.0])).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    for name in ["displayWindow", "dataWindow"] {
        let key = format!("{name}\0box2i\0");
        let at = bytes
            .windows(key.len())
            .position(|w| w == key.as_bytes())
            .expect("the window attribute")
            + key.len()
            + 4;
        let mut bad = bytes.clone();
        // xMin 4, yMin 4, xMax 1, yMax 1.
        for (k, v) in [4i32, 4, 1, 1].into_iter().enumerate() {
            bad[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        let path = dir.join(&format!("{name}.exr"));
        std::fs::write(&path, &bad).unwrap();
        let e = read_color(&path).unwrap_err().to_string();
        assert!(
            e.contains(&format!("{name}.exr"))
                && e.contains(name)
                && e.contains("(4, 4) to (1, 1)"),
            "{e}"
        );
    }
}

#[test]
fn exr_block_off_its_boundary_is_a_format_error() {
    // A ZIP file (16 lines a block) whose second block claims to start at line 17: the block
    // decoder sizes and places blocks by their start, so it must refuse it, naming the file.
    let dir = TempDir::new("exr-misaligned");
    let img = ldr_image(5, 40);
    let path = dir.join("m.exr");
    let options = ExrOptions {
        compression: ExrCompression::Zip,
        half: false,
        placement: None,
    };
    write_color_with(&path, &img, &options).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let u64_at = |b: &[u8], p: usize| u64::from_le_bytes(b[p..p + 8].try_into().unwrap());
    // The offset table of 3 blocks ends where its first entry points.
    let table = (0..bytes.len() - 24)
        .find(|&p| u64_at(&bytes, p) == (p + 24) as u64)
        .expect("offset table");
    let second = u64_at(&bytes, table + 8) as usize;
    assert_eq!(
        i32::from_le_bytes(bytes[second..second + 4].try_into().unwrap()),
        16
    );
    bytes[second..second + 4].copy_from_slice(&17i32.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let err = read_color(&path).unwrap_err().to_string();
    assert!(err.contains("m.exr") && err.contains("line 17"), "{err}");
}
