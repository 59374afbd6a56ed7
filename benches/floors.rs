//! The machine's floors, for the README's roofline table: what the fastest possible pass would
//! take on this machine. Ids:
//! - `floor/copy/64MiB`: read and write 64 MiB of floats, rows in parallel (all cores): the
//!   memory bandwidth a streaming pass cannot beat (bytes moved = 2 x 64 MiB per iteration);
//! - `floor/muladd/2x64Mflop`: 64 M multiply-adds (128 M floating-point operations) on data in
//!   L1, in independent vector lanes on all cores, with the widest instructions this machine has
//!   (run-time dispatch, as the filters use): the arithmetic rate a compute-bound pass cannot
//!   beat.

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use criterion::{criterion_group, criterion_main, Criterion};
use rayon::prelude::*;

const COPY_FLOATS: usize = 16 << 20;
/// Multiply-adds per iteration: 64 lanes x 1024 rounds x 1024 chunks = 64 M.
const LANES: usize = 64;
const ROUNDS: usize = 1024;
const CHUNKS: usize = 1024;

#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn muladd(acc: &mut [f32; LANES], a: f32, b: f32) {
    for _ in 0..ROUNDS {
        for v in acc.iter_mut() {
            *v = *v * a + b;
        }
    }
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("floor");
    g.sample_size(20);
    let src = vec![1.0f32; COPY_FLOATS];
    let mut dst = vec![0.0f32; COPY_FLOATS];
    g.bench_function("copy/64MiB", |b| {
        b.iter(|| {
            dst.par_chunks_mut(1 << 16)
                .zip(src.par_chunks(1 << 16))
                .for_each(|(d, s)| d.copy_from_slice(s));
        })
    });
    g.bench_function("muladd/2x64Mflop", |b| {
        b.iter(|| {
            (0..CHUNKS)
                .into_par_iter()
                .map(|i| {
                    let mut acc = [i as f32 * 1e-3; LANES];
                    muladd(&mut acc, 0.999_9, 1e-4);
                    acc.iter().sum::<f32>()
                })
                .sum::<f32>()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
