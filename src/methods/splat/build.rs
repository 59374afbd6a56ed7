//! Pass `build`: the splat fragments (the poster's compact 16-byte format), optional merging of
//! 2x2 or 4x4 fragments, and their distribution into the lists of every 16x16 tile their shape
//! overlaps: count per tile, prefix sum, fill, in parallel over chunks of fragments with no
//! locks (each chunk lays out its own entries by tile, then each tile gathers its runs).

use glam::Vec2;
use half::f16;
use rayon::prelude::*;

use crate::image::{ColorImage, GrayImage, Rgba};
use crate::lens::ThinLens;
use crate::raster::{from_half, FragmentLists};

/// Tile side in pixels (the poster's 16x16).
pub const TILE_PX: usize = 16;

/// The poster's compact fragment: 16-bit colour, 16-bit position, 32-bit CoC (16 bytes). The
/// CoC also orders fragments by depth (it grows monotonically with depth).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct SplatFragment {
    /// Premultiplied linear RGBA, half precision, times the number of pixels the fragment
    /// stands for (1, or 4 / 16 when merged).
    pub color: [f16; 4],
    /// Centre in half pixels (x, y): pixel `(i, j)`'s centre is `(2i + 1, 2j + 1)`.
    pub pos_half_px: [u16; 2],
    /// Signed CoC radius in pixels.
    pub coc_px: f32,
}

impl SplatFragment {
    /// Centre in pixels.
    #[inline]
    pub fn centre(&self) -> Vec2 {
        Vec2::new(
            self.pos_half_px[0] as f32 * 0.5,
            self.pos_half_px[1] as f32 * 0.5,
        )
    }

    /// Width in pixels of the soft edge of its footprint: 1, or the block size `merge` for a
    /// merged fragment (merged fragments sit on whole pixels, single ones on pixel centres).
    #[inline]
    pub fn soft_px(&self, merge: usize) -> f32 {
        if self.pos_half_px[0].is_multiple_of(2) {
            merge as f32
        } else {
            1.0
        }
    }

    /// Colour in f32.
    #[inline]
    pub fn rgba(&self) -> Rgba {
        from_half(&self.color)
    }
}

/// Largest image side the 16-bit half-pixel positions address.
pub const MAX_SIDE_PX: usize = 32767;

fn fragment(x2: u32, y2: u32, c: Rgba, coc_px: f32) -> SplatFragment {
    SplatFragment {
        color: crate::raster::to_half(c),
        pos_half_px: [x2 as u16, y2 as u16],
        coc_px,
    }
}

/// The input fragments of every pixel, `(premultiplied colour, CoC)`, nearest first, in one
/// flat array: pixel `i` owns `items[offsets[i]..offsets[i + 1]]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PixelLayers {
    offsets: Vec<u32>,
    items: Vec<(Rgba, f32)>,
}

impl PixelLayers {
    /// The fragments of pixel `i` (row-major).
    #[inline]
    pub fn pixel(&self, i: usize) -> &[(Rgba, f32)] {
        &self.items[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Every fragment, pixel after pixel.
    pub fn items_mut(&mut self) -> &mut [(Rgba, f32)] {
        &mut self.items
    }

    /// Number of fragments, over all pixels.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when no pixel has a fragment.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Bytes the layers hold (their allocations).
    pub fn bytes(&self) -> u64 {
        (self.items.capacity() * std::mem::size_of::<(Rgba, f32)>()
            + self.offsets.capacity() * std::mem::size_of::<u32>()) as u64
    }

    /// Empty layers with room for `pixels` pixels and `items` fragments, so that pushing them
    /// allocates once (a growing vector holds up to twice what it needs, and three times while
    /// it moves).
    fn with_capacity(pixels: usize, items: usize) -> Self {
        let mut offsets = Vec::with_capacity(pixels + 1);
        offsets.push(0);
        Self {
            offsets,
            items: Vec::with_capacity(items),
        }
    }

    /// Appends the fragments of the next pixel.
    fn push_pixel(&mut self, items: impl IntoIterator<Item = (Rgba, f32)>) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.items.extend(items);
        self.offsets.push(self.items.len() as u32);
    }
}

/// Fragments of one layer: every pixel of a colour + CoC frame with some opacity.
pub fn from_frame(color: &ColorImage, coc_px: &GrayImage) -> PixelLayers {
    let n = color.pixels().len();
    let items = color.pixels().iter().filter(|c| c[3] > 0.0).count();
    let mut out = PixelLayers::with_capacity(n, items);
    for (&c, &k) in color.pixels().iter().zip(coc_px.pixels()) {
        out.push_pixel((c[3] > 0.0).then_some((c, k)));
    }
    out
}

/// Fragments of fragment lists (multi-layer input), per pixel. Consecutive fragments of a
/// pixel whose CoCs differ by at most `group_px` are one surface seen twice (the front and back
/// faces of a thin double-sided object): they are combined with the over operator first, so a
/// surface is never counted twice.
pub fn from_lists(lists: &FragmentLists, lens: &ThinLens, group_px: f32) -> PixelLayers {
    let w = lists.width();
    let mut out = PixelLayers::with_capacity(w * lists.height(), lists.depths().len());
    let mut merged: Vec<(Rgba, f32)> = Vec::new();
    for i in 0..w * lists.height() {
        let (depths, colors) = lists.pixel(i % w, i / w);
        merged.clear();
        for (&z, c) in depths.iter().zip(colors) {
            let k = lens.coc_px(z);
            let c = from_half(c);
            match merged.last_mut() {
                Some((acc, k0)) if (k - *k0).abs() <= group_px => {
                    let t = 1.0 - acc[3];
                    for (a, v) in acc.iter_mut().zip(c) {
                        *a += t * v;
                    }
                }
                _ => merged.push((c, k)),
            }
        }
        out.push_pixel(merged.iter().copied());
    }
    out
}

/// Turns per-pixel layers into splat fragments, merging `merge` x `merge` blocks (1, 2 or 4)
/// where the blur hides it: every pixel of the block has the same number of layers, and each
/// layer's CoCs are within `group_px` of each other and at least `merge` pixels in radius, so
/// in-focus detail is never merged. A merged fragment sits at the block centre with the mean
/// CoC and the summed colour of the block (it stands for `merge^2` pixels).
pub fn fragments(
    layers: &PixelLayers,
    width: usize,
    height: usize,
    merge: usize,
    group_px: f32,
) -> Vec<SplatFragment> {
    let m = merge.max(1);
    let bw = width.div_ceil(m);
    let bh = height.div_ceil(m);
    let rows: Vec<Vec<SplatFragment>> = (0..bh)
        .into_par_iter()
        .map(|by| {
            let mut out = Vec::new();
            for bx in 0..bw {
                let (x0, y0) = (bx * m, by * m);
                let (x1, y1) = ((x0 + m).min(width), (y0 + m).min(height));
                let full = x1 - x0 == m && y1 - y0 == m;
                let first = layers.pixel(y0 * width + x0);
                let mergeable = m > 1
                    && full
                    && !first.is_empty()
                    && (y0..y1).all(|y| {
                        (x0..x1).all(|x| {
                            let l = layers.pixel(y * width + x);
                            l.len() == first.len()
                                && l.iter().zip(first).all(|(a, b)| {
                                    (a.1 - b.1).abs() <= group_px && a.1.abs() >= m as f32
                                })
                        })
                    });
                if mergeable {
                    for j in 0..first.len() {
                        let mut c = [0.0f32; 4];
                        let mut k = 0.0f32;
                        for y in y0..y1 {
                            for x in x0..x1 {
                                let (v, kk) = layers.pixel(y * width + x)[j];
                                for (a, b) in c.iter_mut().zip(v) {
                                    *a += b;
                                }
                                k += kk;
                            }
                        }
                        k /= (m * m) as f32;
                        // Block centre in half pixels: x0 + m/2 pixels.
                        out.push(fragment((2 * x0 + m) as u32, (2 * y0 + m) as u32, c, k));
                    }
                } else {
                    for y in y0..y1 {
                        for x in x0..x1 {
                            for &(c, k) in layers.pixel(y * width + x) {
                                out.push(fragment((2 * x + 1) as u32, (2 * y + 1) as u32, c, k));
                            }
                        }
                    }
                }
            }
            out
        })
        .collect();
    rows.concat()
}

/// Radius in pixels within which a fragment's shape (with its soft edge `soft_px` wide) can
/// cover a pixel centre: `max(|C|, 0.5) stretch + soft_px`, where `stretch` is the longer
/// axis of an anamorphic aperture (1 for the ideal lens).
#[inline]
pub fn reach_px(coc_px: f32, soft_px: f32, stretch: f32) -> f32 {
    coc_px.abs().max(0.5) * stretch + soft_px
}

/// Tile lists: tile `t` holds the fragment indices `entries[offsets[t]..offsets[t + 1]]` with
/// their sort keys, in order of entry (fragment order) until sorted.
#[derive(Clone, Debug, PartialEq)]
pub struct TileLists {
    /// Tiles per row.
    pub tiles_x: usize,
    /// Rows of tiles.
    pub tiles_y: usize,
    /// Prefix sum of list lengths, `tiles_x * tiles_y + 1` entries.
    pub offsets: Vec<usize>,
    /// (depth key, fragment index) of every list entry.
    pub entries: Vec<(u32, u32)>,
}

impl TileLists {
    /// Mean list length over the tiles.
    pub fn mean_length(&self) -> f64 {
        self.entries.len() as f64 / (self.tiles_x * self.tiles_y).max(1) as f64
    }
}

/// The tiles `[tx0, tx1] x [ty0, ty1]` a fragment's shape overlaps.
#[inline]
fn tile_range(
    f: &SplatFragment,
    merge: usize,
    stretch: f32,
    window: &TileWindow,
) -> (usize, usize, usize, usize) {
    let c = f.centre();
    let r = reach_px(f.coc_px, f.soft_px(merge), stretch);
    let t = TILE_PX as f32;
    let tile = |v: f32| (v / t).floor();
    let (ax, bx, ay, by) = (tile(c.x - r), tile(c.x + r), tile(c.y - r), tile(c.y + r));
    let (wx, wy) = (
        (window.x.0 as f32, window.x.1 as f32),
        (window.y.0 as f32, window.y.1 as f32),
    );
    // Not `!(a <= b)`-style: a NaN reach also lands in the empty range.
    if !(bx >= wx.0 && ax <= wx.1 && by >= wy.0 && ay <= wy.1) {
        return (1, 0, 1, 0);
    }
    (
        ax.max(wx.0) as usize,
        bx.min(wx.1) as usize,
        ay.max(wy.0) as usize,
        by.min(wy.1) as usize,
    )
}

/// The tiles that receive fragments: first and last column and row (inclusive).
#[derive(Clone, Copy, Debug)]
pub struct TileWindow {
    /// First and last tile column.
    pub x: (usize, usize),
    /// First and last tile row.
    pub y: (usize, usize),
}

impl TileWindow {
    /// The tiles of a `width` x `height` frame that hold pixels of the rectangle of `width_px`
    /// x `height_px` pixels at `(x0, y0)` (the whole frame: `(0, 0, width, height)`).
    pub fn of(
        width: usize,
        height: usize,
        (x0, y0, width_px, height_px): (usize, usize, usize, usize),
    ) -> Self {
        let tiles_x = width.div_ceil(TILE_PX).max(1);
        let tiles_y = height.div_ceil(TILE_PX).max(1);
        let last = |p: usize, n: usize, tiles: usize| ((p + n.max(1) - 1) / TILE_PX).min(tiles - 1);
        Self {
            x: ((x0 / TILE_PX).min(tiles_x - 1), last(x0, width_px, tiles_x)),
            y: (
                (y0 / TILE_PX).min(tiles_y - 1),
                last(y0, height_px, tiles_y),
            ),
        }
    }
}

/// How many list entries each chunk of fragments puts into each tile (pass `build`'s count):
/// what [`fill`] lays out, known before any list is allocated.
#[derive(Clone, Debug)]
pub struct TileCounts {
    tiles_x: usize,
    tiles_y: usize,
    /// Fragments per chunk (the last chunk may hold fewer).
    chunk: usize,
    /// Per chunk, per tile: entries.
    counts: Vec<Vec<u32>>,
}

impl TileCounts {
    /// Number of tiles.
    pub fn tiles(&self) -> usize {
        self.tiles_x * self.tiles_y
    }

    /// Entries of every list together.
    pub fn entries(&self) -> u64 {
        self.counts.iter().flatten().map(|&c| u64::from(c)).sum()
    }

    /// Entries of the longest list.
    pub fn longest(&self) -> u64 {
        (0..self.tiles_x * self.tiles_y)
            .map(|t| self.counts.iter().map(|c| u64::from(c[t])).sum::<u64>())
            .max()
            .unwrap_or(0)
    }

    /// Bytes the counts hold.
    pub fn bytes(&self) -> u64 {
        (self.counts.len() * self.tiles_x * self.tiles_y * std::mem::size_of::<u32>()) as u64
    }

    /// Bytes [`fill`] allocates: the entries, the offsets, and while it fills them one run (a
    /// slice, 16 bytes) and one cursor per tile and chunk.
    pub fn fill_bytes(&self) -> u64 {
        let tiles = (self.tiles_x * self.tiles_y) as u64;
        self.entries() * ENTRY_BYTES + (tiles + 1) * 8 + self.counts.len() as u64 * tiles * 24
    }
}

/// Bytes of one tile-list entry: the depth key and the fragment index.
pub const ENTRY_BYTES: u64 = std::mem::size_of::<(u32, u32)>() as u64;

/// Counts the entries `fragments` make in the lists of the tiles of `window` they overlap, per
/// chunk of fragments (in parallel); nothing is allocated per entry.
pub fn count(
    fragments: &[SplatFragment],
    merge: usize,
    stretch: f32,
    width: usize,
    height: usize,
    window: &TileWindow,
) -> TileCounts {
    let tiles_x = width.div_ceil(TILE_PX).max(1);
    let tiles_y = height.div_ceil(TILE_PX).max(1);
    let tiles = tiles_x * tiles_y;
    let chunk = fragments.len().div_ceil(16).max(1024);
    let counts: Vec<Vec<u32>> = fragments
        .par_chunks(chunk)
        .map(|ch| {
            let mut count = vec![0u32; tiles];
            for f in ch.iter() {
                let (x0, x1, y0, y1) = tile_range(f, merge, stretch, window);
                for ty in y0..=y1 {
                    for tx in x0..=x1 {
                        count[ty * tiles_x + tx] += 1;
                    }
                }
            }
            count
        })
        .collect();
    TileCounts {
        tiles_x,
        tiles_y,
        chunk,
        counts,
    }
}

/// Lays out the lists `counts` counted for `fragments` (with the same `merge`, `stretch` and
/// `window`) and fills them, in parallel with no locks: each tile's list is its chunks' runs in
/// chunk order, so every list is in fragment order whatever the thread count.
pub fn fill(
    fragments: &[SplatFragment],
    counts: TileCounts,
    merge: usize,
    stretch: f32,
    window: &TileWindow,
) -> TileLists {
    let TileCounts {
        tiles_x,
        tiles_y,
        chunk,
        counts,
    } = counts;
    let tiles = tiles_x * tiles_y;
    let chunks: Vec<&[SplatFragment]> = fragments.chunks(chunk).collect();
    // Prefix sum over tiles. Each chunk fills its runs in place: the tile lists are cut into
    // one run per tile and chunk.
    let mut offsets = vec![0usize; tiles + 1];
    for t in 0..tiles {
        offsets[t + 1] = offsets[t] + counts.iter().map(|c| c[t] as usize).sum::<usize>();
    }
    let mut entries = vec![(0u32, 0u32); offsets[tiles]];
    let mut runs: Vec<Vec<&mut [(u32, u32)]>> = (0..chunks.len())
        .map(|_| Vec::with_capacity(tiles))
        .collect();
    let mut rest: &mut [(u32, u32)] = &mut entries;
    for t in 0..tiles {
        for (c, count) in counts.iter().enumerate() {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(count[t] as usize);
            runs[c].push(head);
            rest = tail;
        }
    }
    drop(counts);
    chunks
        .par_iter()
        .zip(runs.par_iter_mut())
        .enumerate()
        .for_each(|(c, (ch, runs))| {
            let mut cursor = vec![0usize; tiles];
            let first = c * chunk;
            for (i, f) in ch.iter().enumerate() {
                let (x0, x1, y0, y1) = tile_range(f, merge, stretch, window);
                let k = super::sort::key(f.coc_px);
                for ty in y0..=y1 {
                    for tx in x0..=x1 {
                        let t = ty * tiles_x + tx;
                        runs[t][cursor[t]] = (k, (first + i) as u32);
                        cursor[t] += 1;
                    }
                }
            }
        });
    drop(runs);
    TileLists {
        tiles_x,
        tiles_y,
        offsets,
        entries,
    }
}

/// Distributes `fragments` into the lists of the tiles of `window` they overlap ([`count`],
/// then [`fill`]); a fragment that reaches none of them is left out.
pub fn distribute(
    fragments: &[SplatFragment],
    merge: usize,
    stretch: f32,
    width: usize,
    height: usize,
    window: &TileWindow,
) -> TileLists {
    let counts = count(fragments, merge, stretch, width, height, window);
    fill(fragments, counts, merge, stretch, window)
}
