//! Rasterizer benchmarks: one pinhole frame of each built-in scene.
//! Ids: `raster/pinhole/<scene>/<w>x<h>`.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::raster::{render_gbuffer, PreparedScene, View};
use defocus::scene::builtin;

fn pinhole_frames(c: &mut Criterion) {
    let mut group = c.benchmark_group("raster");
    group.sample_size(20);
    for &name in builtin::NAMES {
        let scene = builtin::load(name).expect("built-in scene");
        let camera = scene.defaults.clone().expect("defaults").camera;
        let lens = camera.thin_lens().expect("valid camera");
        let prepared = PreparedScene::new(&scene, &camera.camera_from_world).expect("valid scene");
        let id = format!("pinhole/{name}/{}x{}", lens.width_px, lens.height_px);
        group.bench_function(id, |b| {
            b.iter(|| render_gbuffer(&prepared, &View::pinhole(lens)))
        });
    }
    group.finish();
}

criterion_group!(benches, pinhole_frames);
criterion_main!(benches);
