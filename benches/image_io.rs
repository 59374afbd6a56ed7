//! Image output benchmarks. Ids: `image/write_exr/<compression>/<w>x<h>` for each lossless EXR
//! compression (f32 RGBA), `image/write_exr_half/<compression>/<w>x<h>` (16-bit), and
//! `image/write_exr/1280x720` for the default. The frame is the anti-aliased pinhole view of the
//! built-in `railing` scene (text, checker, smooth gradients, empty sky): a rendered frame, not
//! noise or a flat colour, so the compressors see what they would in use.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::image::io::{self, ExrCompression, ExrOptions};
use defocus::methods::registry::{self, MethodSettings, PinholeSettings, SceneOptions};
use defocus::scene::builtin;

fn frame() -> defocus::image::ColorImage {
    let scene = builtin::load("railing").expect("railing");
    let camera = scene.defaults.clone().expect("camera").camera;
    let settings = MethodSettings::Pinhole(PinholeSettings {
        samples: 4,
        ..PinholeSettings::default()
    });
    registry::run_scene(
        &settings,
        &scene,
        &camera,
        &SceneOptions::default(),
        &mut |_, _| {},
    )
    .expect("pinhole")
    .image
}

fn bench(c: &mut Criterion) {
    let img = frame();
    let (w, h) = (img.width(), img.height());
    let dir = std::env::temp_dir().join(format!("defocus-bench-io-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("frame.exr");
    let mut g = c.benchmark_group("image");
    g.sample_size(20);
    g.bench_function(format!("write_exr/{w}x{h}"), |b| {
        b.iter(|| io::write_color(&path, &img).expect("write"))
    });
    for half in [false, true] {
        for compression in ExrCompression::ALL {
            let name = if half { "write_exr_half" } else { "write_exr" };
            let options = ExrOptions {
                compression,
                half,
                placement: None,
            };
            g.bench_function(format!("{name}/{}/{w}x{h}", compression.name()), |b| {
                b.iter(|| io::write_color_with(&path, &img, &options).expect("write"))
            });
            let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            eprintln!("{name}/{}: {bytes} bytes", compression.name());
        }
    }
    g.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
