//! The `FragmentLists` sink: every fragment of every pixel, sorted by depth and capped at the
//! N nearest, in compact arrays (Selgrad et al. 2015, section 4; per-pixel linked lists after
//! Yang et al. 2010, compacted by a prefix sum over the per-pixel counts).
//!
//! Unlike [`super::GBuffer`] there is no depth test: fragments behind an opaque one are kept
//! (up to N), because they are what a blurred foreground reveals. Alpha-masked fragments that
//! fail their cutoff are discarded by the rasterizer as for every sink; blended ones are kept
//! whatever their opacity. Storage as the paper: colour and opacity in half precision
//! (premultiplied here, which makes the merge rules of section 5.1 sums), depth in f32: 12
//! bytes per fragment.
//!
//! Each tile keeps the N nearest fragments of each pixel in N slots as they arrive (a full
//! pixel rejects an opaque fragment behind all N before it is shaded); within a tile fragments
//! arrive in the rasterizer's fixed order (nearest triangles first), so the lists do not depend
//! on the thread count.
//!
//! Rasterized with coverage masks ([`super::BinnedView::with_coverage`]), a fragment's opacity
//! is its surface's opacity times the fraction of the pixel it covers, so an in-focus edge
//! resolves as in an anti-aliased frame. Fragments of one surface in one pixel (the triangles of
//! a mesh meeting inside it: disjoint masks, depths within [`SAME_SURFACE`]) are merged into one
//! as they arrive, with their coverages summed: the merge rule of Selgrad et al. section 5.1
//! for fragments side by side, so that a surface cut by a triangle edge stays opaque.

use half::f16;
use rayon::prelude::*;

use super::setup::count16;
use super::{Fragment, Sink, TileRect, TileSink, COVERAGE_SAMPLES, FULL_COVERAGE};
use crate::image::Rgba;

/// Relative depth difference within which two fragments of one pixel with disjoint coverage
/// masks are taken for one surface (triangles of a mesh meeting inside the pixel) and merged.
/// A surface seen edge-on changes depth by a few tenths of a percent across a pixel; two
/// surfaces this close in depth that do not overlap in the pixel look the same merged anyway.
pub const SAME_SURFACE: f32 = 0.02;

/// A surface held for a pixel while fragments arrive: its depth, its colour premultiplied by
/// opacity times covered fraction, its coverage mask, and whether it is blended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldFragment {
    /// View depth in metres (coverage-weighted mean of the merged fragments).
    pub depth_m: f32,
    /// Linear RGBA premultiplied by opacity times the covered fraction of the pixel.
    pub color: Rgba,
    /// The coverage samples covered.
    pub mask: u16,
    /// From an alpha-blended surface.
    pub blend: bool,
    /// Its mask is a share of the samples, not where its geometry lies ([`Fragment::dithered`]).
    pub dithered: bool,
    /// Seen from its back ([`Fragment::back_facing`]).
    pub back: bool,
    /// The opacity it took in from fragments behind it ([`HeldFragment::absorb`]): its own
    /// surfaces' opacity is `color[3]` less this.
    pub absorbed: f32,
}

impl HeldFragment {
    /// Nothing: at infinite depth, transparent.
    pub const EMPTY: Self = Self {
        depth_m: f32::INFINITY,
        color: [0.0; 4],
        mask: 0,
        blend: false,
        dithered: false,
        back: false,
        absorbed: 0.0,
    };

    /// A rasterized fragment, premultiplied by its opacity and coverage.
    #[inline]
    pub fn of(f: &Fragment) -> Self {
        let a = f.color[3] * f.coverage_fraction();
        Self {
            depth_m: f.depth_m,
            color: [f.color[0] * a, f.color[1] * a, f.color[2] * a, a],
            mask: f.coverage,
            blend: f.blend,
            dithered: f.dithered,
            back: f.back_facing,
            absorbed: 0.0,
        }
    }

    /// True when opaque over the whole pixel: nothing behind it shows through.
    #[inline]
    pub fn covers_pixel(&self) -> bool {
        self.mask == FULL_COVERAGE && !self.blend && self.color[3] >= 1.0
    }

    /// Merges `other` into `self` when they are one surface (see [`SAME_SURFACE`]): the
    /// coverages and colours add up, the depth is their coverage-weighted mean. False (and
    /// nothing changed) otherwise.
    #[inline]
    pub fn merge(&mut self, other: &Self) -> bool {
        if self.blend != other.blend
            || self.dithered != other.dithered
            || self.mask & other.mask != 0
            || (self.depth_m - other.depth_m).abs() > SAME_SURFACE * self.depth_m.min(other.depth_m)
        {
            return false;
        }
        let (na, nb) = (count16(self.mask) as f32, count16(other.mask) as f32);
        self.depth_m = (self.depth_m * na + other.depth_m * nb) / (na + nb);
        for (a, b) in self.color.iter_mut().zip(other.color) {
            *a += b;
        }
        self.mask |= other.mask;
        self.back &= other.back;
        self.absorbed += other.absorbed;
        true
    }

    /// Takes `back`, a fragment behind this one, into it with the over operator (this one in
    /// front, its depth kept): how a full list keeps what it has no slot for (see
    /// [`FragmentLists::merging_overflow`]).
    #[inline]
    pub fn absorb(&mut self, back: &Self) {
        let t = 1.0 - self.color[3].clamp(0.0, 1.0);
        for (a, b) in self.color.iter_mut().zip(back.color) {
            *a += t * b;
        }
        self.absorbed += t * back.color[3];
        self.mask |= back.mask;
        self.blend |= back.blend;
        self.dithered |= back.dithered;
    }

    /// The opacity of its own surfaces, without what it absorbed from behind.
    #[inline]
    pub fn own_alpha(&self) -> f32 {
        (self.color[3] - self.absorbed).max(0.0)
    }

    /// True when its colour's luminance exceeds `threshold` times its opacity: a highlight
    /// (see [`crate::methods::highlights`]).
    #[inline]
    pub(crate) fn is_bright(&self, threshold: f32) -> bool {
        let [r, g, b, a] = self.color;
        a > 0.0 && crate::image::luminance([r, g, b]) > threshold * a
    }

    /// True when nothing behind it shows in the pinhole view, to within [`OPAQUE_ALPHA`]: what
    /// a full list that merges its overflow may reject unshaded behind it.
    #[inline]
    pub(crate) fn hides_behind(&self) -> bool {
        self.mask == FULL_COVERAGE && !self.blend && self.color[3] >= OPAQUE_ALPHA
    }
}

/// Opacity from which a fragment hides what lies behind it in a full list that merges its
/// overflow: sums of coverages in f32 (`0.25 + 0.75 * 1`) may fall short of 1 by a rounding.
const OPAQUE_ALPHA: f32 = 0.999;

/// Largest number of fragments kept per pixel.
pub const MAX_FRAGMENTS_PER_PIXEL: usize = 16;

/// Colour of one stored fragment: linear premultiplied RGBA in half precision.
pub type HalfRgba = [f16; 4];

/// Converts linear premultiplied RGBA to half precision, clamping to the largest finite half
/// (65504) so that HDR values stay finite. The four channels in one conversion (see
/// [`from_half`]), rounded to nearest as one at a time.
#[inline]
pub fn to_half(c: Rgba) -> HalfRgba {
    use half::slice::HalfFloatSliceExt;
    let mut out = [f16::ZERO; 4];
    out.convert_from_f32_slice(&c.map(|v| v.clamp(-65504.0, 65504.0)));
    out
}

/// Converts a stored colour back to f32 (exactly: every half is a float). The four channels
/// in one conversion, which asks whether the CPU has half-float instructions once, not once a
/// channel (with [`to_half`]'s the same way: `grass` at 640x360, `multilayer`, 1.9% fewer
/// instructions in all).
#[inline]
pub fn from_half(c: &HalfRgba) -> Rgba {
    use half::slice::HalfFloatSliceExt;
    let mut out = [0.0; 4];
    c.as_slice().convert_to_f32_slice(&mut out);
    out
}

/// The first (nearest) depth of each of the depth-sorted lists `offsets[i]..offsets[i + 1]`,
/// +inf for an empty list.
pub fn nearest_depths(offsets: &[u32], depth: &[f32]) -> Vec<f32> {
    offsets
        .windows(2)
        .map(|w| {
            if w[0] < w[1] {
                depth[w[0] as usize]
            } else {
                f32::INFINITY
            }
        })
        .collect()
}

/// Per-pixel fragment lists of one view: pixel `i` (row-major) owns the fragments
/// `offsets[i]..offsets[i + 1]`, nearest first.
#[derive(Clone, Debug, PartialEq)]
pub struct FragmentLists {
    width: usize,
    height: usize,
    cap: usize,
    /// Prefix sum of the per-pixel counts; `width * height + 1` entries.
    offsets: Vec<u32>,
    /// View-axis depth in metres of each fragment.
    depth: Vec<f32>,
    /// Linear premultiplied RGBA of each fragment (half precision).
    color: Vec<HalfRgba>,
    /// Finished tiles, waiting for [`FragmentLists::compact`].
    tiles: Vec<(TileRect, FragmentTile)>,
    /// Outside the frame (in a guard band), the depths whose blur can still reach it.
    reach: Option<Reach>,
    /// With coverage masks: the lens whose CoCs tell which surfaces of a pixel no blur can
    /// separate ([`hide_coincident`]).
    coincident: Option<crate::lens::ThinLens>,
    /// See [`FragmentLists::merging_overflow`].
    merge_overflow: bool,
    /// See [`FragmentLists::keeping_bright_overflow`].
    bright_overflow: Option<f32>,
    /// The bright fragments kept apart from a full list: pixel (row-major), depth, colour.
    overflow_highlights: Vec<(usize, f32, Rgba)>,
    /// With bright overflow kept apart: each fragment's own opacity (see
    /// [`FragmentLists::own_alphas`]); empty otherwise.
    own_alpha: Vec<f16>,
}

/// Which fragments of a guard band around a frame can reach the frame once blurred: one at
/// distance `d` pixels from the frame whose CoC radius `C` satisfies `factor |C| + slack_px <
/// d` cannot, whatever the method makes of it, and is not kept (nor shaded). Such fragments
/// are those between a depth in front of the focus and infinity, when even infinity's CoC
/// falls short; so each pixel of the band gets a depth from which fragments are dropped, as if
/// hidden.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// The frame within the lists' pixels: left column, top row, width, height.
    pub frame: (usize, usize, usize, usize),
    /// The lens (for each depth's CoC).
    pub lens: crate::lens::ThinLens,
    /// How far a fragment reaches, in CoC radii.
    pub factor: f32,
    /// And in pixels besides.
    pub slack_px: f32,
    /// Distances to the frame are the larger of their two axes (the test of a fragment's
    /// square bounding box, as `splat`'s tile lists make it) instead of straight lines.
    pub square: bool,
}

impl Reach {
    /// Whether the tile `rect` lies within the frame (where nothing is dropped).
    pub fn holds(&self, rect: &TileRect) -> bool {
        let (x0, y0, w, h) = self.frame;
        rect.x0 >= x0 && rect.y0 >= y0 && rect.x1 <= x0 + w && rect.y1 <= y0 + h
    }

    /// The depth from which the fragments of pixel (`x`, `y`) cannot reach the frame (`+inf`
    /// inside it, and wherever the far field's blur reaches it).
    pub fn depth_limit(&self, x: usize, y: usize) -> f32 {
        let (x0, y0, w, h) = self.frame;
        let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
        let dx = (x0 as f32 - px).max(px - (x0 + w) as f32).max(0.0);
        let dy = (y0 as f32 - py).max(py - (y0 + h) as f32).max(0.0);
        let d = if self.square {
            dx.max(dy)
        } else {
            (dx * dx + dy * dy).sqrt()
        };
        let r = (d - self.slack_px) / self.factor;
        if r <= 0.0 || self.lens.coc_at_infinity_px().abs() >= r {
            return f32::INFINITY;
        }
        // In front of the focus |C| = r at this depth, and is smaller behind it up to
        // infinity.
        self.lens.depth_for_coc_px(-r)
    }
}

impl FragmentLists {
    /// Empty lists for a `width x height` view keeping at most `cap` fragments per pixel
    /// (clamped to 1..=[`MAX_FRAGMENTS_PER_PIXEL`]).
    pub fn new(width: usize, height: usize, cap: usize) -> Self {
        Self {
            width,
            height,
            cap: cap.clamp(1, MAX_FRAGMENTS_PER_PIXEL),
            offsets: vec![0; width * height + 1],
            depth: Vec::new(),
            color: Vec::new(),
            tiles: Vec::new(),
            reach: None,
            coincident: None,
            merge_overflow: false,
            bright_overflow: None,
            overflow_highlights: Vec::new(),
            own_alpha: Vec::new(),
        }
    }

    /// Resolves the coverage masks of surfaces that no blur through `lens` can separate, as
    /// the fragments of each pixel are finished (`hide_coincident`).
    pub fn with_coincident_surfaces(mut self, lens: crate::lens::ThinLens) -> Self {
        self.coincident = Some(lens);
        self
    }

    /// A full pixel keeps the fragments it has no slot for instead of dropping them: it holds
    /// one more than it keeps while fragments arrive, the two farthest of any more become one
    /// (the nearer over the farther at the nearer's depth: the overflow rule of multi-layer
    /// alpha blending, Salvi and Vaidyanathan 2014), and when it finishes, those beyond N are
    /// merged into the N-th the same way. The papers keep the N nearest, which is enough when
    /// each fragment covers its pixel; with coverage, an anti-aliased edge in the last slot then
    /// has nothing behind it where a blur reveals it: the label's edge on `traps`' chart, behind
    /// the two sides of a near bar and the pane, showed as a dark line. Only a farthest fragment
    /// that hides everything behind it (opaque over every sample) lets the pixel reject
    /// fragments unshaded.
    pub fn merging_overflow(mut self) -> Self {
        self.merge_overflow = true;
        self
    }

    /// With [`FragmentLists::merging_overflow`]: a fragment brighter than `threshold` (the
    /// luminance of its colour over its opacity, as `--highlight-rays` takes highlights out of
    /// the lists) that a full pixel would merge into a nearer one is kept apart instead, at its
    /// own depth ([`FragmentLists::overflow_highlights`]); only its opacity is merged, so it
    /// still hides what lies behind it. A light seen through more surfaces than the lists hold
    /// (city lights through three panes and a leaf) is then scattered with its own CoC, not the
    /// CoC of the surface it was merged into, whose blur made it a dot.
    pub fn keeping_bright_overflow(mut self, threshold: f32) -> Self {
        self.bright_overflow = Some(threshold);
        self
    }

    /// The bright fragments a full pixel kept apart ([`FragmentLists::keeping_bright_overflow`]):
    /// pixel index (row-major), view-axis depth in metres, premultiplied linear colour (its
    /// coverage included), in the order of the tiles.
    pub fn overflow_highlights(&self) -> &[(usize, f32, Rgba)] {
        &self.overflow_highlights
    }

    /// With bright overflow kept apart ([`FragmentLists::keeping_bright_overflow`]), the
    /// opacity of each fragment's own surfaces, parallel to [`FragmentLists::colors`]: a
    /// fragment that merged the overflow of a full pixel holds in its opacity what lay behind
    /// it (the wall behind four panes), which must not hide a light that lay in front of that.
    /// `None` otherwise (every fragment's opacity is its own).
    pub fn own_alphas(&self) -> Option<&[f16]> {
        (!self.own_alpha.is_empty()).then_some(self.own_alpha.as_slice())
    }

    /// Drops, as it rasterizes, the fragments outside the frame that cannot reach it once
    /// blurred (see [`Reach`]).
    pub fn with_reach(mut self, reach: Reach) -> Self {
        self.reach = Some(reach);
        self
    }

    /// Lists from their parts: pixel `i` (row-major) owns the fragments `offsets[i]..offsets[i +
    /// 1]` of `depth` (view-axis metres) and `color` (premultiplied), nearest first (not
    /// checked). For inputs that do not come from the rasterizer (`multiview`'s layers, read as
    /// lists by [`crate::methods::highlights`]).
    pub fn from_parts(
        width: usize,
        height: usize,
        offsets: Vec<u32>,
        depth: Vec<f32>,
        color: Vec<HalfRgba>,
    ) -> Self {
        debug_assert_eq!(offsets.len(), width * height + 1);
        debug_assert_eq!(depth.len(), color.len());
        Self {
            offsets,
            depth,
            color,
            ..Self::new(width, height, MAX_FRAGMENTS_PER_PIXEL)
        }
    }

    /// Builds lists directly from per-pixel fragments `(depth_m, premultiplied colour)` in any
    /// order (row-major pixels), sorted and capped as the rasterizer's lists are. For tests and
    /// for inputs that do not come from the rasterizer.
    pub fn from_pixels(
        width: usize,
        height: usize,
        cap: usize,
        pixels: &[Vec<(f32, Rgba)>],
    ) -> Self {
        let mut lists = Self::new(width, height, cap);
        let mut total = 0u32;
        for (i, frags) in pixels.iter().enumerate().take(width * height) {
            let mut frags = frags.clone();
            frags.sort_by(|a, b| a.0.total_cmp(&b.0));
            frags.truncate(lists.cap);
            for (z, c) in frags {
                lists.depth.push(z);
                lists.color.push(to_half(c));
                total += 1;
            }
            lists.offsets[i + 1] = total;
        }
        for i in pixels.len().min(width * height)..width * height {
            lists.offsets[i + 1] = total;
        }
        lists
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The cap N on fragments per pixel.
    pub fn cap(&self) -> usize {
        self.cap
    }

    /// Total number of fragments stored.
    pub fn len(&self) -> usize {
        self.depth.len()
    }

    /// True when no pixel has a fragment.
    pub fn is_empty(&self) -> bool {
        self.depth.is_empty()
    }

    /// Bytes of the compact storage (offsets, depths, colours).
    pub fn bytes(&self) -> usize {
        self.offsets.len() * 4 + self.depth.len() * 4 + self.color.len() * 8
    }

    /// The fragments of pixel `(x, y)`, nearest first: depths in metres and premultiplied
    /// colours.
    pub fn pixel(&self, x: usize, y: usize) -> (&[f32], &[HalfRgba]) {
        let i = y * self.width + x;
        let (a, b) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        (&self.depth[a..b], &self.color[a..b])
    }

    /// The prefix sum of per-pixel counts (`width * height + 1` entries).
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// All depths, pixel after pixel.
    pub fn depths(&self) -> &[f32] {
        &self.depth
    }

    /// All colours, pixel after pixel.
    pub fn colors(&self) -> &[HalfRgba] {
        &self.color
    }

    /// All colours, pixel after pixel, to change (the lists' order and depths stay).
    pub fn colors_mut(&mut self) -> &mut [HalfRgba] {
        &mut self.color
    }

    /// Depth of the nearest fragment of each pixel (+inf where there is none): the pinhole
    /// depth, for outputs that want one.
    pub fn nearest_depth(&self) -> Vec<f32> {
        nearest_depths(&self.offsets, &self.depth)
    }

    /// Moves the finished tiles into the compact arrays: counts per pixel, prefix sum, fill.
    /// Called by the rasterizing code after the last tile. The tiles of a row of tiles (the
    /// same rows of the image) fill one contiguous run of the arrays, so the rows of tiles are
    /// copied side by side, a row to a task.
    pub fn compact(&mut self) {
        let (w, n) = (self.width, self.width * self.height);
        let tiles = std::mem::take(&mut self.tiles);
        // Bands of tiles over the same rows, in row order; tiles in any other order (not the
        // rasterizer's) make one band of the whole image.
        type Band<'a> = (usize, usize, Vec<&'a (TileRect, FragmentTile)>);
        let mut bands: Vec<Band> = Vec::new();
        for t in &tiles {
            match bands.last_mut() {
                Some((y0, y1, band)) if (*y0, *y1) == (t.0.y0, t.0.y1) => band.push(t),
                _ => bands.push((t.0.y0, t.0.y1, vec![t])),
            }
        }
        if !bands.windows(2).all(|b| b[0].1 <= b[1].0) {
            bands = vec![(0, self.height, tiles.iter().collect())];
        }
        // Each band's pixels, and later its fragments, as a slice of its own.
        fn split<T>(
            mut rest: &mut [T],
            ends: impl Iterator<Item = (usize, usize)>,
        ) -> Vec<&mut [T]> {
            let mut at = 0;
            let mut out = Vec::new();
            for (a, b) in ends {
                let (_, tail) = std::mem::take(&mut rest).split_at_mut(a - at);
                let (mine, tail) = tail.split_at_mut(b - a);
                out.push(mine);
                rest = tail;
                at = b;
            }
            out
        }
        let mut counts = vec![0u32; n];
        split(&mut counts, bands.iter().map(|b| (b.0 * w, b.1 * w)))
            .into_par_iter()
            .zip(&bands)
            .for_each(|(counts, (y0, _, band))| {
                for (rect, tile) in band {
                    for (k, &c) in tile.counts.iter().enumerate() {
                        let (tx, ty) = (k % rect.width(), k / rect.width());
                        counts[(rect.y0 - y0 + ty) * w + rect.x0 + tx] = c;
                    }
                }
            });
        self.offsets[0] = 0;
        for (i, &c) in counts.iter().enumerate() {
            self.offsets[i + 1] = self.offsets[i] + c;
        }
        let total = self.offsets[n] as usize;
        self.depth = super::filled_in_parallel(0.0, total);
        self.color = super::filled_in_parallel([f16::ZERO; 4], total);
        let offsets = &self.offsets;
        let runs = || {
            bands
                .iter()
                .map(|b| (offsets[b.0 * w] as usize, offsets[b.1 * w] as usize))
        };
        split(&mut self.depth, runs())
            .into_par_iter()
            .zip(split(&mut self.color, runs()))
            .zip(&bands)
            .for_each(|((depth, color), (y0, _, band))| {
                let base = offsets[y0 * w] as usize;
                for (rect, tile) in band {
                    let mut src = 0usize;
                    for (k, &c) in tile.counts.iter().enumerate() {
                        let (tx, ty) = (k % rect.width(), k / rect.width());
                        let dst = offsets[(rect.y0 + ty) * w + rect.x0 + tx] as usize - base;
                        let c = c as usize;
                        depth[dst..dst + c].copy_from_slice(&tile.out_depth[src..src + c]);
                        color[dst..dst + c].copy_from_slice(&tile.out_color[src..src + c]);
                        src += c;
                    }
                }
            });
        if self.bright_overflow.is_some() && self.merge_overflow {
            let mut own = vec![f16::ZERO; total];
            for (rect, tile) in &tiles {
                let mut src = 0usize;
                for (k, &c) in tile.counts.iter().enumerate() {
                    let (tx, ty) = (k % rect.width(), k / rect.width());
                    let dst = offsets[(rect.y0 + ty) * w + rect.x0 + tx] as usize;
                    let c = c as usize;
                    own[dst..dst + c].copy_from_slice(&tile.out_own[src..src + c]);
                    src += c;
                }
            }
            self.own_alpha = own;
        }
    }
}

/// The largest difference in CoC radius, in pixels, between two surfaces of a pixel that a blur
/// does not separate: seen from any point of the lens their images move apart by at most this
/// much. Measured at 640x360 against `reference` (1024 samples): 0.5 px leaves some of the back
/// faces of `traps`' bars (0.7 px behind their fronts) in the lists, 1 and 2 px give the same
/// images to 0.01 dB, 4 px costs `railing` 0.9 dB (surfaces a blur does show beside each other).
pub const COINCIDENT_COC_PX: f32 = 1.0;

/// How far behind an opaque surface seen from its front, relative to its depth, a surface seen
/// from its back is taken for the far side of the same closed mesh (a double-sided bar's inside
/// behind its outside), which no lens point sees: the same 5% within which `multilayer`'s
/// levels take fragments for one surface. [`COINCIDENT_COC_PX`] alone is a distance in pixels,
/// so it let the back of `traps`' bars (1.7% of their depth behind their fronts: 1.1 px of CoC
/// at 640x360, 2.2 at 1280x720) count as a second surface at the higher resolution, where
/// `splat --layers 4` then blended the bars over themselves (28.2 dB, against 29.97 with them
/// hidden), and at any resolution it took two of four slots when the cap was two.
pub const BACK_SIDE_DEPTH: f32 = 0.05;

/// Makes the fragments of one pixel (sorted near to far) composite, with the over operator, as
/// their coverage masks do wherever a nearer opaque surface lies within [`COINCIDENT_COC_PX`] of
/// their CoC. Such a pair is one place seen at one time: the two sides of a thin closed mesh at
/// its silhouette (a double-sided cylinder's back faces behind its front ones, on the same
/// samples), ink printed on a board. The over operator treats the farther one's coverage as
/// independent of the nearer one's, so the back of a cylinder at its silhouette would darken the
/// edge a second time (measured: a bar's anti-aliased edge over a white chart at 0.23 instead of
/// 0.47). Instead the farther fragment's opacity becomes its share of the samples those nearer
/// surfaces leave free (`|mask \ U| / |not U|`), which the over operator turns back into exactly
/// the samples it covers; hidden entirely, it is dropped (opacity 0). Surfaces further apart in
/// CoC keep their own coverage: a blur can show one beside the other, and which of their samples
/// overlap then is not known from the pinhole view. Masks from alpha to coverage
/// ([`Fragment::dithered`]) neither hide nor are hidden: their samples are a share, not a place.
pub(crate) fn hide_coincident(slots: &mut [HeldFragment], scale: CocScale) {
    for k in 1..slots.len() {
        let back = slots[k];
        if back.dithered || back.mask == 0 {
            continue;
        }
        let hiding = samples_hiding(&slots[..k], &back, scale);
        if hiding == 0 {
            continue;
        }
        let free = COVERAGE_SAMPLES - count16(hiding);
        let seen = count16(back.mask & !hiding);
        let share = if free == 0 || seen == 0 {
            0.0
        } else {
            (seen * COVERAGE_SAMPLES) as f32 / (free * count16(back.mask)) as f32
        };
        slots[k].color = back.color.map(|v| v * share);
    }
}

/// The samples of `back` covered by the opaque surfaces among `others` that lie in front of it
/// within [`COINCIDENT_COC_PX`] of its CoC (none when `back`'s mask is dithered).
#[inline]
pub(crate) fn samples_hiding(others: &[HeldFragment], back: &HeldFragment, scale: CocScale) -> u16 {
    if back.dithered {
        return 0;
    }
    others
        .iter()
        .filter(|s| may_hide(s, back, scale))
        .fold(0u16, |m, s| m | s.mask)
}

/// Whether `front` can hide `back`'s samples: an opaque surface in front of it that no blur
/// separates from it, within [`COINCIDENT_COC_PX`] of CoC, or seen from its front with `back`
/// seen from its back within [`BACK_SIDE_DEPTH`] behind it (the inside of a closed mesh).
#[inline]
fn may_hide(front: &HeldFragment, back: &HeldFragment, scale: CocScale) -> bool {
    front.depth_m < back.depth_m
        && !front.blend
        && !front.dithered
        && (scale.coincident(front.depth_m, back.depth_m)
            || (back.back
                && !front.back
                && back.depth_m <= front.depth_m * (1.0 + BACK_SIDE_DEPTH)))
}

/// `f_px E`, the lens's scale of CoC against inverse depth (`C = f_px E (1/z_f - 1/z)`, see
/// [`crate::lens::coc_px`]), for telling coincident surfaces apart without a division.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct CocScale(pub f32);

impl CocScale {
    /// The scale of `lens`.
    pub(crate) fn of(lens: &crate::lens::ThinLens) -> Self {
        Self(lens.f_px * lens.lens_radius_m)
    }

    /// Whether depths `a` and `b` (positive) lie within [`COINCIDENT_COC_PX`] of CoC of each
    /// other: `|C(a) - C(b)| = f_px E |a - b| / (a b)`.
    #[inline(always)]
    pub(crate) fn coincident(self, a: f32, b: f32) -> bool {
        self.0 * (a - b).abs() <= COINCIDENT_COC_PX * a * b
    }
}

/// Removes from the first `n` slots the fragments whose every sample is hidden by coincident
/// surfaces in front of them ([`samples_hiding`]): the back of a closed mesh behind its front,
/// which would otherwise take the slots of what a blur reveals. Returns the number left.
#[inline]
fn drop_hidden(slots: &mut [HeldFragment], mut n: usize, scale: CocScale) -> usize {
    let mut k = 0;
    while k < n {
        let s = slots[k];
        if s.mask & !samples_hiding(&slots[..n], &s, scale) == 0 && !s.dithered {
            slots[k] = slots[n - 1];
            slots[n - 1] = HeldFragment::EMPTY;
            n -= 1;
        } else {
            k += 1;
        }
    }
    n
}

/// The slot holding the farthest fragment (the last of equals, so that the earlier fragment
/// wins ties).
#[inline]
fn farthest_slot(slots: &[HeldFragment]) -> usize {
    let mut far = 0;
    for (k, s) in slots.iter().enumerate() {
        if s.depth_m >= slots[far].depth_m {
            far = k;
        }
    }
    far
}

/// Per-tile state of [`FragmentLists`]: N slots per pixel holding the N nearest fragments so
/// far (N + 1 where the overflow is merged), so that an opaque fragment behind all of a full
/// pixel is rejected before it is shaded (the rasterizer's early test), and a nearer one
/// replaces the farthest (or, merging the overflow, the two farthest become one).
#[derive(Clone, Debug, PartialEq)]
pub struct FragmentTile {
    rect: TileRect,
    cap: usize,
    /// Slots per pixel: N, or N + 1 where the overflow is merged (see [`FragmentTile::finish`]).
    work: usize,
    /// Fragments held per pixel of the tile.
    counts: Vec<u32>,
    /// Farthest depth held by each full pixel, raised by [`SAME_SURFACE`] so that a fragment
    /// that may still merge with it is not rejected early (+inf while it has fewer than N).
    farthest: Vec<f32>,
    /// Depth from which each pixel's fragments are dropped: `+inf`, or in a guard band where
    /// they cannot reach the frame ([`Reach`]).
    limit: Vec<f32>,
    /// N slots per pixel.
    slots: Vec<HeldFragment>,
    /// After `finish`: depths, pixel after pixel, nearest first.
    out_depth: Vec<f32>,
    /// After `finish`: colours, pixel after pixel.
    out_color: Vec<HalfRgba>,
    /// See [`FragmentLists::with_coincident_surfaces`].
    coincident: Option<CocScale>,
    /// See [`FragmentLists::merging_overflow`].
    merge_overflow: bool,
    /// See [`FragmentLists::keeping_bright_overflow`].
    bright_overflow: Option<f32>,
    /// The bright fragments kept apart: pixel of the tile, fragment.
    bright: Vec<(usize, HeldFragment)>,
    /// After `finish`, with bright overflow kept apart: each fragment's own opacity.
    out_own: Vec<f16>,
}

/// Takes `back` into `front` as [`HeldFragment::absorb`] does, but a `back` brighter than
/// `threshold` is kept apart in `bright` (pixel `i`) and only its opacity merged: see
/// [`FragmentLists::keeping_bright_overflow`].
fn absorb_or_keep(
    front: &mut HeldFragment,
    back: &HeldFragment,
    threshold: Option<f32>,
    bright: &mut Vec<(usize, HeldFragment)>,
    i: usize,
) {
    match threshold {
        Some(t) if back.is_bright(t) => {
            bright.push((i, *back));
            front.absorb(&HeldFragment {
                color: [0.0, 0.0, 0.0, back.color[3]],
                ..*back
            });
        }
        _ => front.absorb(back),
    }
}

impl TileSink for FragmentTile {
    #[inline]
    fn occluded(&self, x: u32, y: u32, depth_m: f32) -> bool {
        let i = (y as usize - self.rect.y0) * self.rect.width() + (x as usize - self.rect.x0);
        depth_m >= self.farthest[i]
    }

    #[inline]
    fn occlusion_row(&self, y: u32, xa: u32, xb: u32) -> Option<&[f32]> {
        let start = (y as usize - self.rect.y0) * self.rect.width() + (xa as usize - self.rect.x0);
        self.farthest.get(start..start + (xb - xa) as usize)
    }

    #[inline]
    fn fragment(&mut self, f: &Fragment) {
        let i = (f.y as usize - self.rect.y0) * self.rect.width() + (f.x as usize - self.rect.x0);
        if f.depth_m >= self.farthest[i] {
            return;
        }
        let held = HeldFragment::of(f);
        let slots = &mut self.slots[i * self.work..(i + 1) * self.work];
        let n = self.counts[i] as usize;
        let raise = 1.0 + SAME_SURFACE;
        let merge_overflow = self.merge_overflow;
        // The depth from which a full pixel rejects fragments unshaded: its farthest (raised,
        // so that a fragment that may still merge with it is kept), when it hides what lies
        // behind or the overflow is dropped anyway.
        let reject_from = |slots: &[HeldFragment], limit: f32| {
            let far = farthest_slot(slots);
            if merge_overflow && !slots[far].hides_behind() {
                limit
            } else {
                (slots[far].depth_m * raise).min(limit)
            }
        };
        if let Some(scale) = self.coincident {
            // Hidden at every sample by coincident surfaces in front: it takes no slot.
            if n > 0
                && !held.dithered
                && held.mask & !samples_hiding(&slots[..n], &held, scale) == 0
            {
                return;
            }
        }
        let at = match slots[..n].iter_mut().position(|s| s.merge(&held)) {
            Some(k) => {
                if n == self.work {
                    self.farthest[i] = reject_from(slots, self.limit[i]);
                }
                k
            }
            None if n < self.work => {
                slots[n] = held;
                self.counts[i] += 1;
                if n + 1 == self.work {
                    self.farthest[i] = reject_from(slots, self.limit[i]);
                }
                n
            }
            None if merge_overflow => {
                // Full: the two farthest of the N + 2 become one, the nearer over the farther.
                let far = farthest_slot(slots);
                let (t, bright) = (self.bright_overflow, &mut self.bright);
                let at = if held.depth_m >= slots[far].depth_m {
                    absorb_or_keep(&mut slots[far], &held, t, bright, i);
                    far
                } else {
                    let mut next = None::<usize>;
                    for (k, s) in slots.iter().enumerate() {
                        if k != far && next.is_none_or(|m| s.depth_m >= slots[m].depth_m) {
                            next = Some(k);
                        }
                    }
                    match next {
                        Some(g) if slots[g].depth_m > held.depth_m => {
                            let back = slots[far];
                            absorb_or_keep(&mut slots[g], &back, t, bright, i);
                            slots[far] = held;
                        }
                        _ => {
                            let back = slots[far];
                            slots[far] = held;
                            absorb_or_keep(&mut slots[far], &back, t, bright, i);
                        }
                    }
                    far
                };
                self.farthest[i] = reject_from(slots, self.limit[i]);
                at
            }
            None => {
                // Replace the farthest (the last of equals, so the earlier fragment wins
                // ties), when this one is nearer.
                let far = farthest_slot(slots);
                if f.depth_m >= slots[far].depth_m {
                    return;
                }
                slots[far] = held;
                self.farthest[i] = reject_from(slots, self.limit[i]);
                far
            }
        };
        // An opaque surface that arrived or grew may now hide, at every sample, coincident
        // ones behind it (the back of a closed mesh arriving before its front): their slots are
        // freed for what a blur reveals.
        let front = slots[at];
        let scale = self
            .coincident
            .filter(|_| n > 0 && !front.blend && !front.dithered);
        if let Some(scale) = scale {
            let n = self.counts[i] as usize;
            let behind = |s: &HeldFragment| !s.dithered && may_hide(&front, s, scale);
            if slots[..n].iter().any(behind) {
                let left = drop_hidden(slots, n, scale);
                if left < n {
                    self.counts[i] = left as u32;
                    self.farthest[i] = self.limit[i];
                }
            }
        }
    }

    /// Sorts each pixel's fragments near to far, resolves the coincident ones, and keeps the N
    /// nearest that show; where the overflow is merged, those beyond N are merged into the
    /// N-th, nearer over farther. (The tile holds one slot more than it keeps, so that the
    /// halves of a surface cut by a triangle edge through the pixel, arriving apart, still
    /// meet in one slot before they are merged behind another.)
    fn finish(&mut self) {
        let n = self.rect.width() * self.rect.height();
        for i in 0..n {
            let count = self.counts[i] as usize;
            let slots = &mut self.slots[i * self.work..i * self.work + count];
            // Near to far; stable, so equal depths keep their order.
            slots.sort_by(|a, b| a.depth_m.total_cmp(&b.depth_m));
            if let Some(scale) = self.coincident {
                hide_coincident(slots, scale);
            }
            let mut kept = 0;
            for k in 0..slots.len() {
                if slots[k].color[3] <= 0.0 {
                    continue;
                }
                if kept < self.cap {
                    slots[kept] = slots[k];
                    kept += 1;
                } else {
                    let back = slots[k];
                    absorb_or_keep(
                        &mut slots[kept - 1],
                        &back,
                        self.bright_overflow,
                        &mut self.bright,
                        i,
                    );
                }
            }
            for s in &slots[..kept] {
                self.out_depth.push(s.depth_m);
                self.out_color.push(to_half(s.color));
            }
            if self.bright_overflow.is_some() {
                self.out_own
                    .extend(slots[..kept].iter().map(|s| f16::from_f32(s.own_alpha())));
            }
            self.counts[i] = kept as u32;
        }
        self.slots = Vec::new();
        self.farthest = Vec::new();
        self.limit = Vec::new();
    }
}

impl Sink for FragmentLists {
    type Tile = FragmentTile;

    fn begin_tile(&self, rect: TileRect) -> FragmentTile {
        let n = rect.width() * rect.height();
        let limit: Vec<f32> = match &self.reach {
            Some(reach) if !reach.holds(&rect) => (0..n)
                .map(|k| reach.depth_limit(rect.x0 + k % rect.width(), rect.y0 + k / rect.width()))
                .collect(),
            _ => vec![f32::INFINITY; n],
        };
        FragmentTile {
            rect,
            cap: self.cap,
            work: self.cap + usize::from(self.merge_overflow),
            counts: vec![0; n],
            farthest: limit.clone(),
            limit,
            slots: vec![HeldFragment::EMPTY; n * (self.cap + usize::from(self.merge_overflow))],
            out_depth: Vec::new(),
            out_color: Vec::new(),
            coincident: self.coincident.as_ref().map(CocScale::of),
            merge_overflow: self.merge_overflow,
            bright_overflow: self.bright_overflow.filter(|_| self.merge_overflow),
            bright: Vec::new(),
            out_own: Vec::new(),
        }
    }

    fn end_tile(&mut self, rect: TileRect, mut tile: FragmentTile) {
        let w = self.width;
        for (k, f) in std::mem::take(&mut tile.bright) {
            let (tx, ty) = (k % rect.width(), k / rect.width());
            let pixel = (rect.y0 + ty) * w + rect.x0 + tx;
            self.overflow_highlights.push((pixel, f.depth_m, f.color));
        }
        self.tiles.push((rect, tile));
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::lens::ThinLens;

    #[test]
    fn half_colours_convert_as_one_channel_at_a_time() {
        // Halfway cases round to even, subnormals, the largest half, HDR beyond it (clamped),
        // negatives: the four-channel conversions against the scalar ones.
        let values = [
            0.0,
            1.0,
            1.0 + 1.0 / 2048.0,
            1.0 + 3.0 / 2048.0,
            3.0e-6,
            6.0e-8,
            0.333_333,
            65504.0,
            65520.0,
            1.0e9,
            -2.5,
            -1.0e9,
        ];
        for c in values.chunks(4) {
            let c = [c[0], c[1], c[2], c[3]];
            let h = to_half(c);
            let one = c.map(|v| f16::from_f32(v.clamp(-65504.0, 65504.0)));
            assert_eq!(h.map(f16::to_bits), one.map(f16::to_bits), "{c:?}");
            assert_eq!(from_half(&h), one.map(f16::to_f32), "{c:?}");
        }
        assert_eq!(to_half([1.0e9; 4])[0].to_f32(), 65504.0);
    }

    /// `C(z) = 10 (1/2 - 1/z)` pixels: in focus at 2 m, 5 px at infinity.
    pub(in crate::raster) fn reach() -> Reach {
        Reach {
            frame: (40, 40, 100, 60),
            lens: ThinLens {
                width_px: 180,
                height_px: 140,
                f_px: 1000.0,
                lens_radius_m: 0.01,
                focus_m: 2.0,
                near_m: 0.01,
                far_m: 1e4,
            },
            factor: 2.0,
            slack_px: 1.0,
            square: false,
        }
    }

    #[test]
    fn reach_limit_is_where_the_blur_stops_reaching_the_frame() {
        let r = reach();
        // Inside the frame, and near it where even infinity's 5 px reach: everything is kept.
        assert_eq!(r.depth_limit(90, 70), f32::INFINITY);
        // 4.5 px out: 2 x 5 + 1 reach it.
        assert_eq!(r.depth_limit(35, 70), f32::INFINITY);
        // 31.5 px left of the frame: only CoCs of (31.5 - 1) / 2 = 15.25 px or more reach it,
        // which lie in front of 1 / (1/2 + 1.525) m.
        let z = r.depth_limit(8, 70);
        assert!((z - 1.0 / 2.025).abs() < 1e-5, "{z}");
        assert!((r.lens.coc_px(z) + 15.25).abs() < 1e-3);
        assert!(2.0 * r.lens.coc_px(z * 0.99).abs() + 1.0 > 31.5);
        // The same distance diagonally off a corner gives the same depth.
        let d = 31.5 / 2f32.sqrt();
        let (x, y) = ((40.0 - d - 0.5) as usize, (40.0 - d - 0.5) as usize);
        let z_corner = r.depth_limit(x, y);
        assert!(
            z_corner.is_finite() && z_corner > z * 0.9,
            "{z_corner} vs {z}"
        );
    }

    /// A tile of the guard band left of [`reach`]'s frame, holding pixel (8, 70).
    pub(in crate::raster) const BAND_TILE: TileRect = TileRect {
        x0: 0,
        y0: 64,
        x1: 16,
        y1: 72,
    };

    /// `tile` (of [`BAND_TILE`]) drops at pixel (8, 70) the fragments at or behind `limit`, as
    /// if hidden, and keeps nearer ones.
    pub(in crate::raster) fn assert_drops_from(tile: &impl TileSink, limit: f32) {
        assert!(tile.occluded(8, 70, limit));
        assert!(tile.occluded(8, 70, 50.0));
        assert!(!tile.occluded(8, 70, limit * 0.99));
    }

    /// A fragment at or behind the limit is dropped as if hidden, nearer ones are kept.
    #[test]
    fn a_tile_drops_what_cannot_reach_the_frame() {
        let r = reach();
        let lists = FragmentLists::new(180, 140, 4).with_reach(r);
        assert_drops_from(&lists.begin_tile(BAND_TILE), r.depth_limit(8, 70));
    }

    /// The fragments of pixel (0, 0) of a one-pixel list of `cap` slots fed `frags` in
    /// order (with or without merging the overflow), as `(depth, premultiplied colour)`.
    fn one_pixel(cap: usize, merge: bool, frags: &[Fragment]) -> Vec<(f32, Rgba)> {
        let mut lists = FragmentLists::new(1, 1, cap);
        if merge {
            lists = lists.merging_overflow();
        }
        let rect = TileRect {
            x0: 0,
            y0: 0,
            x1: 1,
            y1: 1,
        };
        let mut tile = lists.begin_tile(rect);
        for f in frags {
            if !tile.occluded(0, 0, f.depth_m) {
                tile.fragment(f);
            }
        }
        tile.finish();
        lists.end_tile(rect, tile);
        lists.compact();
        let (d, c) = lists.pixel(0, 0);
        d.iter().zip(c).map(|(&z, c)| (z, from_half(c))).collect()
    }

    /// Front-to-back over of premultiplied colours.
    fn over_all(list: &[(f32, Rgba)]) -> Rgba {
        let mut out = [0.0f32; 4];
        for (_, c) in list {
            let t = 1.0 - out[3];
            for k in 0..4 {
                out[k] += t * c[k];
            }
        }
        out
    }

    /// Lists built by several tiles, rows of tiles copied side by side, read back pixel by
    /// pixel: each pixel its own fragments, nearest first, whichever tile (a partial one at the
    /// right and bottom edges) held them; tiles in another order than the rasterizer's give the
    /// same lists.
    #[test]
    fn compacted_lists_hold_each_pixels_fragments() {
        let (w, h) = (150usize, 70usize);
        // Pixel, then its fragments' depths.
        let pixels: [((usize, usize), &[f32]); 5] = [
            ((3, 5), &[1.0, 4.0]),
            ((70, 10), &[2.5]),
            ((149, 69), &[0.5, 3.0, 6.0]),
            ((64, 64), &[2.0]),
            ((10, 66), &[1.5, 1.75]),
        ];
        let rects = crate::raster::tile_grid(w, h);
        for reversed in [false, true] {
            let mut lists = FragmentLists::new(w, h, 4);
            let mut order = rects.clone();
            if reversed {
                order.reverse();
            }
            for rect in order {
                let mut tile = lists.begin_tile(rect);
                for &((x, y), depths) in &pixels {
                    if !((rect.x0..rect.x1).contains(&x) && (rect.y0..rect.y1).contains(&y)) {
                        continue;
                    }
                    // Farthest first: the list sorts them.
                    for &z in depths.iter().rev() {
                        tile.fragment(&Fragment {
                            x: x as u32,
                            y: y as u32,
                            depth_m: z,
                            color: [z / 8.0, 0.5, 0.25, 0.5],
                            blend: true,
                            coverage: FULL_COVERAGE,
                            dithered: false,
                            back_facing: false,
                        });
                    }
                }
                tile.finish();
                lists.end_tile(rect, tile);
            }
            lists.compact();
            let total: usize = pixels.iter().map(|p| p.1.len()).sum();
            assert_eq!(lists.depths().len(), total, "reversed {reversed}");
            for &((x, y), depths) in &pixels {
                let (d, c) = lists.pixel(x, y);
                assert_eq!(d, depths, "({x}, {y}), reversed {reversed}");
                for (c, &z) in c.iter().zip(depths) {
                    assert_eq!(c[0], to_half([z / 8.0 * 0.5; 4])[0], "({x}, {y})");
                }
            }
            assert_eq!(lists.pixel(4, 5).0.len(), 0);
        }
    }

    /// A full list keeps, merged, what it has no slot for: behind an opaque near surface and an
    /// anti-aliased edge (half the samples), the surface behind the edge still fills the other
    /// half, in whichever order the fragments arrive. The papers' nearest-N list drops it.
    #[test]
    fn a_full_list_merges_its_overflow_into_its_farthest_fragments() {
        let frag = |depth_m: f32, rgb: [f32; 3], coverage: u16| Fragment {
            x: 0,
            y: 0,
            depth_m,
            color: [rgb[0], rgb[1], rgb[2], 1.0],
            blend: false,
            coverage,
            dithered: false,
            back_facing: false,
        };
        let near = frag(1.0, [0.1, 0.1, 0.1], FULL_COVERAGE);
        let edge = frag(2.0, [1.0, 0.0, 0.0], 0x00ff);
        let behind = frag(3.0, [0.0, 0.0, 1.0], FULL_COVERAGE);
        let all = [
            (1.0, [0.1, 0.1, 0.1, 1.0]),
            (2.0, [0.5, 0.0, 0.0, 0.5]),
            (3.0, [0.0, 0.0, 1.0, 1.0]),
        ];
        let truth = over_all(&all[1..]);
        for order in [
            [near, edge, behind],
            [near, behind, edge],
            [behind, edge, near],
        ] {
            let kept = one_pixel(2, true, &order);
            assert_eq!(kept.len(), 2);
            assert!((kept[0].0 - 1.0).abs() < 1e-6 && (kept[1].0 - 2.0).abs() < 1e-6);
            // What a blur that moves the near surface aside reveals: the edge over what lies
            // behind it.
            for k in 0..4 {
                assert!(
                    (kept[1].1[k] - truth[k]).abs() < 2e-3,
                    "{kept:?} vs {truth:?}"
                );
            }
        }
        // Nearest N: the red edge is left over nothing.
        let kept = one_pixel(2, false, &[near, edge, behind]);
        assert!((kept[1].1[3] - 0.5).abs() < 2e-3 && kept[1].1[2].abs() < 2e-3);
        // Each surface cut in two by a triangle edge through the pixel, the halves arriving
        // apart: they still meet in one slot before the farthest is merged behind.
        let half = |f: Fragment, m: u16| Fragment { coverage: m, ..f };
        let cut = [
            half(near, 0x0f0f),
            half(edge, 0x000f),
            half(behind, 0x0f0f),
            half(near, 0xf0f0),
            half(edge, 0x00f0),
            half(behind, 0xf0f0),
        ];
        let kept = one_pixel(2, true, &cut);
        assert_eq!(kept.len(), 2);
        for k in 0..4 {
            assert!(
                (kept[1].1[k] - truth[k]).abs() < 2e-3,
                "{kept:?} vs {truth:?}"
            );
        }
    }
}
