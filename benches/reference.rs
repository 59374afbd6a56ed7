//! Reference renderer benchmarks. Ids: `reference/<scene>/<samples>spp/<w>x<h>`.
//!
//! The full 256-sample frame at 1280x720 takes seconds, so criterion runs it 10 times.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::methods::reference::{render, ReferenceSettings};
use defocus::scene::builtin;

fn reference(c: &mut Criterion) {
    let mut group = c.benchmark_group("reference");
    group.sample_size(10);
    for (name, samples) in [("railing", 256usize), ("lights", 64)] {
        let scene = builtin::load(name).expect("built-in scene");
        let defaults = scene.defaults.clone().expect("defaults");
        let camera = defaults.camera;
        let settings = ReferenceSettings {
            samples,
            aperture: defaults.aperture,
            ..ReferenceSettings::default()
        };
        let id = format!(
            "{name}/{samples}spp/{}x{}",
            camera.width_px, camera.height_px
        );
        group.bench_function(id, |b| {
            b.iter(|| render(&scene, &camera, &settings, &mut |_, _| {}).expect("render"))
        });
    }
    group.finish();
}

criterion_group!(benches, reference);
criterion_main!(benches);
