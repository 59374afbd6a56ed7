//! `multiview` benchmarks at 1280x720 on the built-in `railing` and `grass` scenes. Ids:
//! `multiview/decompose/<scene>/1280x720` (the depth layers) and
//! `multiview/total/<n>spp/<scene>/1280x720` (decompose, mipmaps, culling windows and tracing with
//! the default settings and n lens samples). Compare with `reference/<scene>/256spp/...`: the
//! layered method's cost stops growing with the scene's triangles.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::methods::multiview::{self, MultiviewSettings};
use defocus::raster::PreparedScene;
use defocus::scene::builtin;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("multiview");
    g.sample_size(10);
    for name in ["railing", "grass"] {
        let scene = builtin::load(name).expect("scene");
        let camera = scene.defaults.clone().expect("camera").camera;
        let lens = camera.thin_lens().expect("lens");
        let res = format!("{}x{}", lens.width_px, lens.height_px);
        let prepared = PreparedScene::new(&scene, &camera.camera_from_world).expect("prepare");
        let s = MultiviewSettings::default();
        g.bench_function(format!("decompose/{name}/{res}"), |b| {
            b.iter(|| multiview::decompose(&prepared, lens, &s).expect("layers"))
        });
        for samples in [16usize, 32] {
            let s = MultiviewSettings {
                samples,
                ..MultiviewSettings::default()
            };
            g.bench_function(format!("total/{samples}spp/{name}/{res}"), |b| {
                b.iter(|| multiview::render(&scene, &camera, &s).expect("render"))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
