//! `multilayer` benchmarks at 1280x720 on the built-in `railing` and `grass` scenes: the grid of
//! the paper's Tables 1 and 3. Ids:
//! - `multilayer/collect/N<n>/<scene>/1280x720`: the fragment lists with N per pixel;
//!   `multilayer/collect/N4/sample-lookups/<scene>/1280x720`: the same with minified textures
//!   looked up at every covered sample (`--texture-lookups sample`, `multiview`'s default);
//! - `multilayer/filter/<m>-<s>/N<n>/<trunc|full>/<scene>/1280x720`: the Y-map of m mip and s
//!   stack steps, with or without list truncation;
//! - `multilayer/accumulate/<m>-<s>/N<n>/<scene>/1280x720`;
//! - `multilayer/total/auto/N4/<scene>/1280x720`: the default settings (bokeh in the aperture's
//!   shape), end to end; `multilayer/total/box/N4/<scene>/1280x720`: the same with the paper's
//!   box bokeh (`--ml-bokeh box`).
//!
//! Each pass runs on the previous pass's output, computed once.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::methods::multilayer::{
    self, accumulate, collect, Bokeh, Borders, FilterSteps, MultilayerSettings,
};
use defocus::raster::{LayeredInput, PreparedScene};
use defocus::scene::builtin;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("multilayer");
    g.sample_size(10);
    for name in ["railing", "grass"] {
        let scene = builtin::load(name).expect("scene");
        let camera = scene.defaults.clone().expect("camera").camera;
        let lens = camera.thin_lens().expect("lens");
        let res = format!("{}x{}", lens.width_px, lens.height_px);
        let prepared = PreparedScene::new(&scene, &camera.camera_from_world).expect("prepare");
        let borders = Borders::new(lens);
        for n in [4usize, 16] {
            let base = MultilayerSettings {
                fragments: n,
                ..MultilayerSettings::default()
            };
            g.bench_function(format!("collect/N{n}/{name}/{res}"), |b| {
                b.iter(|| collect(&prepared, lens, 0, &base))
            });
            if n == 4 {
                // Minified textures looked up at every covered sample (`multiview`'s input).
                let sampled = MultilayerSettings {
                    input: LayeredInput::SAMPLE_SHADED,
                    ..base.clone()
                };
                g.bench_function(format!("collect/N{n}/sample-lookups/{name}/{res}"), |b| {
                    b.iter(|| collect(&prepared, lens, 0, &sampled))
                });
            }
            let lists = collect(&prepared, lens, 0, &base).expect("within the budget");
            for (mip, stack) in [(1usize, 3usize), (2, 2), (4, 0)] {
                for truncation in [true, false] {
                    let s = MultilayerSettings {
                        filter_steps: FilterSteps::Fixed { mip, stack },
                        truncation,
                        ..base.clone()
                    };
                    let t = if truncation { "trunc" } else { "full" };
                    g.bench_function(format!("filter/{mip}-{stack}/N{n}/{t}/{name}/{res}"), |b| {
                        b.iter(|| multilayer::filter(&lists, &borders, &s))
                    });
                    if truncation {
                        let (levels, _) = multilayer::filter(&lists, &borders, &s);
                        g.bench_function(
                            format!("accumulate/{mip}-{stack}/N{n}/{name}/{res}"),
                            |b| {
                                b.iter(|| {
                                    accumulate(
                                        &levels,
                                        &borders,
                                        s.epsilon,
                                        lens.width_px,
                                        lens.height_px,
                                    )
                                })
                            },
                        );
                    }
                }
            }
        }
        let s = MultilayerSettings {
            aperture: scene.defaults.clone().expect("defaults").aperture,
            ..MultilayerSettings::default()
        };
        g.bench_function(format!("total/auto/N4/{name}/{res}"), |b| {
            b.iter(|| multilayer::render(&scene, &camera, &s).expect("render"))
        });
        let boxed = MultilayerSettings {
            bokeh: Bokeh::Box,
            ..s.clone()
        };
        g.bench_function(format!("total/box/N4/{name}/{res}"), |b| {
            b.iter(|| multilayer::render(&scene, &camera, &boxed).expect("render"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
