//! `hammon` benchmarks on a procedural 1280x720 frame. Ids: `hammon/<pass>/<w>x<h>` for each
//! pass of `methods/hammon` (inputs from the earlier passes, computed once; `downsample` and
//! `composite` compute the blur amounts from depth as `hammon::render` does, and `coc` is the
//! full-resolution CoC image alone, which the render no longer writes), `hammon/total/<w>x<h>`
//! for the whole method, and `memory_floor/<w>x<h>`: read colour and depth once and write one
//! colour image straight into fresh memory (no zero fill first), rows in parallel as the passes
//! are: the least any method reading these inputs can cost. Report `hammon/total` over
//! `memory_floor`.
//!
//! The frame mixes every case: sky (infinite depth) at the top, a far field receding behind the
//! focal plane, an in-focus band, and a near disc in front of it, on a textured colour image
//! with a few bright HDR spots.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::image::{ColorImage, GrayImage};
use defocus::lens::{Camera, ThinLens};
use defocus::methods::hammon::{
    self, blur, coc, composite, downsample, near_coc, Constants, HammonSettings,
};
use rayon::prelude::*;

const W: usize = 1280;
const H: usize = 720;

/// 50 mm at f/1.4 on a 36 mm sensor, focused at 3 m: |C| is 10.6 px at infinity and about
/// 29 px for the near disc at 0.8 m.
fn lens() -> ThinLens {
    Camera {
        width_px: W,
        height_px: H,
        camera_from_world: glam::Affine3A::IDENTITY,
        focal_length_mm: 50.0,
        sensor_width_mm: 36.0,
        fstop: 1.4,
        focus_m: 3.0,
        near_m: 0.05,
        far_m: 1000.0,
        yfov_rad: None,
    }
    .thin_lens()
    .expect("valid camera")
}

/// Procedural colour (premultiplied, opaque) and view-axis depth in metres.
fn inputs() -> (ColorImage, GrayImage) {
    let mut color = Vec::with_capacity(W * H);
    let mut depth = Vec::with_capacity(W * H);
    for y in 0..H {
        for x in 0..W {
            let (u, v) = (x as f32 / W as f32, y as f32 / H as f32);
            let checker = if (x / 16 + y / 16) % 2 == 0 { 0.8 } else { 0.2 };
            let spot = if x % 97 == 40 && y % 89 == 30 {
                20.0
            } else {
                0.0
            };
            color.push([
                checker * u + spot,
                checker * v + spot,
                0.5 * checker + spot,
                1.0,
            ]);
            let (dx, dy) = (x as f32 - 0.25 * W as f32, y as f32 - 0.7 * H as f32);
            let z = if dx * dx + dy * dy < (0.15 * H as f32).powi(2) {
                0.8
            } else if v < 0.2 {
                f32::INFINITY
            } else if v < 0.5 {
                // Far field: from 100 m down to the focal plane.
                3.0 + 97.0 * ((0.5 - v) / 0.3).powi(2)
            } else {
                3.0
            };
            depth.push(z);
        }
    }
    (
        ColorImage::from_vec(W, H, color).expect("size"),
        GrayImage::from_vec(W, H, depth).expect("size"),
    )
}

fn hammon_passes(c: &mut Criterion) {
    let (color, depth) = inputs();
    let lens = lens();
    let settings = HammonSettings::default();
    let k = Constants::new(&settings, &lens, W, H).expect("valid settings");
    let amounts = coc::Amounts::Depth(&depth, &k);
    let shrunk = downsample::downsample(&color, amounts).expect("sizes");
    let blurred = blur::blur(&shrunk, k.kernel()).expect("kernel");
    let medium = near_coc::near_coc(&shrunk, &blurred).expect("sizes");

    let size = format!("{W}x{H}");
    let mut group = c.benchmark_group("hammon");
    group.bench_function(format!("coc/{size}"), |b| {
        b.iter(|| coc::coc(&depth, &k).expect("valid depth"))
    });
    let s = coc::coc(&depth, &k).expect("valid depth");
    group.bench_function(format!("downsample_from_coc/{size}"), |b| {
        b.iter(|| downsample::downsample(&color, &s).expect("sizes"))
    });
    group.bench_function(format!("downsample/{size}"), |b| {
        b.iter(|| downsample::downsample(&color, amounts).expect("sizes"))
    });
    group.bench_function(format!("blur/{size}"), |b| {
        b.iter(|| blur::blur(&shrunk, k.kernel()).expect("kernel"))
    });
    group.bench_function(format!("near_coc/{size}"), |b| {
        b.iter(|| near_coc::near_coc(&shrunk, &blurred).expect("sizes"))
    });
    group.bench_function(format!("composite/{size}"), |b| {
        b.iter(|| composite::composite(&color, amounts, &medium, &blurred, &k).expect("sizes"))
    });
    group.bench_function(format!("total/{size}"), |b| {
        b.iter(|| hammon::render(&color, &depth, &lens, &settings).expect("render"))
    });
    group.finish();

    c.bench_function(&format!("memory_floor/{size}"), |b| {
        b.iter(|| {
            // Written straight into fresh memory, as `composite` writes its output: a zero fill
            // first would be a second pass of writes (1.41 ms against 0.76 ms on the AMD EPYC
            // development machine), which no method needs.
            let mut out: Vec<[f32; 4]> = Vec::with_capacity(W * H);
            out.spare_capacity_mut()
                .par_chunks_mut(W)
                .zip(color.pixels().par_chunks(W))
                .zip(depth.pixels().par_chunks(W))
                .for_each(|((o, c), d)| {
                    for ((o, c), &z) in o.iter_mut().zip(c).zip(d) {
                        o.write(if z > 0.0 { *c } else { [0.0; 4] });
                    }
                });
            // SAFETY: the rows above cover all `W * H` pixels and wrote each one.
            unsafe { out.set_len(W * H) };
            ColorImage::from_vec(W, H, out).expect("size")
        })
    });
}

criterion_group!(benches, hammon_passes);
criterion_main!(benches);
