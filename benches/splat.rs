//! `splat` benchmarks at 1280x720 on the built-in `railing` and `lights` scenes, single layer
//! (the pinhole frame at pixel centres), merge none / 2x2 / 4x4: the poster's table. Ids:
//! `splat/total/merge<m>/<scene>/1280x720`; the mean list length per tile and the time of each
//! pass (`splat/build`, `splat/sort`, `splat/blend`, the poster's rows) of one run are printed
//! with each scene and merge.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::methods::registry::{self, MethodSettings, PinholeSettings, SceneOptions};
use defocus::methods::splat::{self, SplatSettings};
use defocus::scene::builtin;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("splat");
    g.sample_size(10);
    for name in ["railing", "lights"] {
        let scene = builtin::load(name).expect("scene");
        let defaults = scene.defaults.clone().expect("camera");
        let camera = defaults.camera;
        let lens = camera.thin_lens().expect("lens");
        let res = format!("{}x{}", lens.width_px, lens.height_px);
        let frame = registry::run_scene(
            &MethodSettings::Pinhole(PinholeSettings::default()),
            &scene,
            &camera,
            &SceneOptions {
                with_depth: true,
                ..SceneOptions::default()
            },
            &mut |_, _| {},
        )
        .expect("pinhole");
        let depth = frame.depth.clone().expect("depth");
        for merge in [1usize, 2, 4] {
            let s = SplatSettings {
                merge,
                aperture: defaults.aperture.clone(),
                ..SplatSettings::default()
            };
            let (out, stats) =
                splat::render_detailed(&frame.image, &depth, &lens, &s).expect("splat");
            let passes: Vec<String> = out
                .timings
                .passes
                .iter()
                .map(|p| format!("{} {:.1} ms", p.name, p.ms))
                .collect();
            eprintln!(
                "splat {name} merge {merge}: {} fragments, mean list length {:.0} per tile; {}",
                stats.fragments,
                stats.mean_list_length,
                passes.join(", ")
            );
            g.bench_function(format!("total/merge{merge}/{name}/{res}"), |b| {
                b.iter(|| splat::render(&frame.image, &depth, &lens, &s).expect("splat"))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
