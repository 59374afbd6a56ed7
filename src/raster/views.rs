//! The multi-view loop: rasterize a prepared scene through many lens points and sub-pixel
//! offsets and average the views (Haeberli & Akeley's accumulation buffer). `reference` (views
//! over the lens), supersampled `pinhole` (views through the lens centre) and the tests of the
//! layered methods use this one implementation.
//!
//! Each pixel adds the views in sample order, so the sum is bit-identical whatever the number of
//! threads.

use rayon::prelude::*;

use super::{BinnedView, GBuffer, PreparedScene, SetupTriangle, TileRect, TileSink, View};
use crate::image::{ColorImage, Rgba};
use crate::lens::{LensEffects, LensSample, ThinLens};
use crate::timing::Timings;
use crate::Result;

/// The `--timings` labels of the passes of [`accumulate_views`], given by the method that runs
/// it (`reference/setup` or `pinhole/setup`, ...).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewPassLabels {
    /// Per view: projection with the view's shear, clipping, culling (pass `setup`).
    pub setup: &'static str,
    /// Per view: triangles into the tile lists (pass `bin`).
    pub bin: &'static str,
    /// Per view: rasterize into G-buffer tiles and add them to the sum (pass `raster`).
    pub raster: &'static str,
    /// Once: divide the sum by the number of views (pass `resolve`).
    pub resolve: &'static str,
}

/// The view of one lens sample: its lens point, its sub-pixel offset snapped onto the raster
/// grid, and the texture LOD bias of a pixel that is the mean of `views` views.
pub fn sample_view(lens: ThinLens, sample: &LensSample, views: usize) -> View {
    View {
        lens,
        lens_point: sample.lens,
        pixel_offset: super::snap_pixel_offset(sample.pixel_offset),
        lod_bias: -0.5 * (views.max(1) as f32).log2(),
    }
}

/// Renders one view of `prepared` into a G-buffer, timing its passes under `labels`.
pub fn render_view(
    prepared: &PreparedScene,
    view: &View,
    labels: &ViewPassLabels,
    timings: &mut Timings,
) -> Result<GBuffer> {
    let binned = BinnedView::new_timed(prepared, view, labels, timings, 0)?;
    let mut g = GBuffer::new(view.lens.width_px, view.lens.height_px);
    timings.time(labels.raster, || binned.rasterize(prepared, &mut g));
    Ok(g)
}

/// Views set up and binned at a time by [`accumulate_views`]: each tile then rasterizes them
/// one after another while its sum and buffers stay in cache.
const VIEWS_PER_CHUNK: usize = 16;

/// Bytes the set-up and binned triangles of one view of a scene of `triangles` triangles take,
/// about (the upper bound the budget counts): each set-up triangle twice (its chunk's list and
/// the joined list, [`SetupTriangle`]) and its sort key and entry in a tile's list.
pub fn view_bytes(triangles: usize) -> u64 {
    triangles.max(1) as u64 * (2 * std::mem::size_of::<SetupTriangle>() as u64 + 16)
}

/// Views [`accumulate_views`] sets up and bins at a time for a scene of `triangles` triangles
/// under a memory budget of `budget` bytes: as many as `CHUNK_BYTES` and an eighth of the
/// budget hold (at least one, at most `VIEWS_PER_CHUNK`).
pub fn views_per_chunk(triangles: usize, budget: u64) -> usize {
    let room = (CHUNK_BYTES as u64).min(budget / 8);
    ((room / view_bytes(triangles)) as usize).clamp(1, VIEWS_PER_CHUNK)
}

/// Memory the binned views of one chunk may take; scenes with many triangles take fewer views
/// per chunk.
const CHUNK_BYTES: usize = 512 << 20;

/// The mean of the views of `samples` (premultiplied linear RGBA). `progress(done, total)` is
/// called as views complete. One sample at the lens centre and the pixel centre gives the plain
/// pinhole image exactly.
///
/// Views are taken in chunks: a chunk's views are set up and binned, then each tile (in
/// parallel) rasterizes every view of the chunk into one G-buffer tile and adds it to the
/// tile's sum, so the sums and tile buffers stay in cache instead of streaming a frame per
/// view. Each pixel still adds the views in sample order, so the mean is bit-identical for any
/// chunk size and thread count.
pub fn accumulate_views(
    prepared: &PreparedScene,
    lens: ThinLens,
    samples: &[LensSample],
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ColorImage> {
    accumulate_views_clipped(prepared, lens, samples, None, labels, timings, progress)
}

/// [`accumulate_views`] where each pixel takes only the views whose lens point reaches it
/// through the lens barrel of `clip` (the cat's eye, [`LensEffects::barrel`]), and is their
/// mean (black where none does). With `clip` `None` or without a barrel, the plain mean.
pub fn accumulate_views_clipped(
    prepared: &PreparedScene,
    lens: ThinLens,
    samples: &[LensSample],
    clip: Option<&LensEffects>,
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ColorImage> {
    let clip = clip.filter(|e| e.has_cats_eye());
    let (w, h) = (lens.width_px, lens.height_px);
    let total = samples.len();
    let budget = crate::budget::budget_bytes()?;
    let chunk = views_per_chunk(prepared.triangle_count(), budget);
    // A chunk also ends where its binned views hold `room` bytes (their triangles may take
    // more tile-list entries than the estimate allows for: large triangles enter many tiles).
    let room = (CHUNK_BYTES as u64).min(budget / 8);
    // Per tile: its rectangle and the sum of its pixels, row-major within the tile; with a
    // clip, also each pixel's count of views that reach it.
    let mut sums: Vec<(TileRect, Vec<Rgba>)> = Vec::new();
    let mut counts: Vec<Vec<u32>> = Vec::new();
    let mut done = 0;
    while done < total {
        let mut binned: Vec<BinnedView> = Vec::new();
        let mut held = 0u64;
        while done + binned.len() < total
            && binned.len() < chunk
            && (binned.is_empty() || held < room)
        {
            let s = &samples[done + binned.len()];
            let view = sample_view(lens, s, total);
            let b = BinnedView::new_timed(prepared, &view, labels, timings, held)?;
            held += b.bytes();
            binned.push(b);
        }
        let views = &samples[done..done + binned.len()];
        let Some(first) = binned.first() else {
            break;
        };
        if sums.is_empty() {
            sums = first
                .tile_rects()
                .into_iter()
                .map(|r| (r, vec![[0.0; 4]; r.width() * r.height()]))
                .collect();
            if clip.is_some() {
                counts = sums.iter().map(|(_, s)| vec![0; s.len()]).collect();
            }
        }
        timings.time(labels.raster, || match clip {
            None => sums
                .par_iter_mut()
                .enumerate()
                .for_each(|(i, (rect, sum))| {
                    let mut tile = GBuffer::tile(*rect);
                    for view in &binned {
                        tile.reset(*rect);
                        view.rasterize_tile(prepared, i, rect, &mut tile);
                        tile.finish();
                        add_tile(sum, tile.color());
                    }
                }),
            Some(effects) => sums
                .par_iter_mut()
                .zip(counts.par_iter_mut())
                .enumerate()
                .for_each(|(i, ((rect, sum), count))| {
                    let mut tile = GBuffer::tile(*rect);
                    for (view, sample) in binned.iter().zip(views) {
                        tile.reset(*rect);
                        view.rasterize_tile(prepared, i, rect, &mut tile);
                        tile.finish();
                        add_tile_clipped(sum, count, tile.color(), rect, &lens, effects, sample);
                    }
                }),
        });
        done += views.len();
        progress(done, total);
    }
    timings.time(labels.resolve, || {
        let inv_n = 1.0 / total.max(1) as f32;
        let mut data = vec![[0.0; 4]; w * h];
        for (t, (rect, sum)) in sums.iter().enumerate() {
            for (row, y) in (rect.y0..rect.y1).enumerate() {
                let dst = &mut data[y * w + rect.x0..][..rect.width()];
                let src = &sum[row * rect.width()..][..rect.width()];
                match counts.get(t) {
                    None => {
                        for (d, s) in dst.iter_mut().zip(src) {
                            *d = s.map(|v| v * inv_n);
                        }
                    }
                    Some(count) => {
                        let n = &count[row * rect.width()..][..rect.width()];
                        for ((d, s), &k) in dst.iter_mut().zip(src).zip(n) {
                            let inv = if k > 0 { 1.0 / k as f32 } else { 0.0 };
                            *d = s.map(|v| v * inv);
                        }
                    }
                }
            }
        }
        ColorImage::from_vec(w, h, data)
    })
}

/// Adds a view's tile to the pixels its lens point reaches through the lens barrel, counting
/// them (the cat's eye of [`accumulate_views_clipped`]).
fn add_tile_clipped(
    sum: &mut [Rgba],
    count: &mut [u32],
    tile: &[Rgba],
    rect: &TileRect,
    lens: &ThinLens,
    effects: &LensEffects,
    sample: &LensSample,
) {
    let width = rect.width();
    for (k, ((s, n), t)) in sum.iter_mut().zip(count.iter_mut()).zip(tile).enumerate() {
        let p = glam::Vec2::new(
            (rect.x0 + k % width) as f32 + 0.5,
            (rect.y0 + k / width) as f32 + 0.5,
        );
        if effects.passes(effects.barrel(lens, p), sample.lens) {
            for c in 0..4 {
                s[c] += t[c];
            }
            *n += 1;
        }
    }
}

/// `sum += tile`, pixel by pixel: the accumulation of `reference`'s views. Compiled for several
/// instruction sets and chosen at run time ([`multiversion`]); additions only, so the same bits
/// in every version. No AVX-512 version (README, "Without AVX-512 where it was slower").
#[multiversion::multiversion(targets("x86_64+avx2", "aarch64+neon"))]
pub(crate) fn add_tile(sum: &mut [Rgba], tile: &[Rgba]) {
    add_tile_baseline(sum, tile);
}

/// [`add_tile`] in the portable baseline build: its twin in tests.
#[inline(always)]
pub(crate) fn add_tile_baseline(sum: &mut [Rgba], tile: &[Rgba]) {
    for (d, s) in sum.as_flattened_mut().iter_mut().zip(tile.as_flattened()) {
        *d += s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatched_tile_sum_is_bit_identical_to_the_baseline() {
        let mut rng = crate::random::SplitMix64::new(3);
        for n in [0usize, 1, 3, 17, 4096] {
            let tile: Vec<Rgba> = (0..n)
                .map(|_| std::array::from_fn(|_| rng.range(-2.0, 30.0)))
                .collect();
            let start: Vec<Rgba> = (0..n)
                .map(|_| std::array::from_fn(|_| rng.range(0.0, 1e4)))
                .collect();
            let (mut a, mut b) = (start.clone(), start);
            add_tile(&mut a, &tile);
            add_tile_baseline(&mut b, &tile);
            assert_eq!(a, b, "{n} pixels");
        }
    }
}
