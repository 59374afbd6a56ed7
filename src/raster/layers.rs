//! The `DepthLayers` sink (Lee, Eisemann, Seidel 2009, sections 4.1-4.2): the scene cut into
//! layers uniform in signed CoC, each with its own depth buffer, so every layer keeps the
//! nearest surface within its depth interval, including surfaces hidden in the pinhole view.
//!
//! Layer `l` holds the depths whose CoC lies in `[C_near + l delta, C_near + (l + 1) delta)`
//! (eq. 4 with the signed CoC of [`crate::lens::coc_px`]: `C` grows monotonically with depth).
//! A fragment goes to the layer of its own depth, with the manual depth test of the paper's
//! copy pass; on the CPU the rasterizer knows every fragment's depth, so the paper's GPU
//! work-around (triangles sent to the layer of their farthest vertex, then a copy pass moving
//! pixels to the layer of their depth) is not needed: this is the exact decomposition the paper
//! approximates. Neighbouring layers overlap by a fraction of `delta` (10% by default, as the
//! paper): a fragment that close to a boundary is also written to the layer on the other side.
//!
//! Layers see through (not in the paper, which has no transparency): each layer keeps, per
//! pixel, its three nearest surfaces (fragments of one surface merged as in
//! [`super::FragmentLists`]; more merged into the farthest, nearer over farther, as a full
//! fragment list merges its overflow) and stores them composited front to back as
//! premultiplied colour, its alpha the coverage a ray meets there; the height field is the
//! nearest one's CoC.
//! A blended pane, or an edge covering part of a pixel, then shows what lies behind it within
//! the layer, and the trace goes on behind it into the next layers with the rest of its weight.
//! Only surfaces that cover their pixel opaquely are also written to the overlapping
//! neighbour layer: a partly transparent one written twice would be met twice by one ray.
//!
//! A surface hidden in the pinhole view behind a nearer one of the same layer, more than
//! [`CONTINUITY_PX`] of CoC behind it, is also written to the next layer (not in the paper):
//! a ray that passes behind the nearer surface (the trace takes a step onto a surface that far
//! nearer for its side, not its top) finds it there instead of what lies behind both. Without
//! it, a layer 4 px of CoC deep showed an in-focus chart's next layer (a dark wall) through the
//! blurred edge of an alpha-cut sprig 2.8 px of CoC in front of the chart in the same layer,
//! and the sprig came out dark-rimmed and sharp.

use half::f16;
use rayon::prelude::*;

use super::fragments::CocScale;
use super::{to_half, Fragment, HalfRgba, HeldFragment, Reach, Sink, TileRect, TileSink};
use crate::lens::ThinLens;

/// Neighbouring surfaces whose CoCs differ by at most this many pixels are one continuous
/// surface: a ray of `multiview`'s trace stepping from one onto the other meets it; one
/// stepping onto a surface farther in front comes in from its side and passes behind it, and a
/// surface hidden that far behind another of its layer is written to the next layer for it.
pub const CONTINUITY_PX: f32 = 2.0;

/// How depths are cut into layers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerSpacing {
    /// The thin lens.
    pub lens: ThinLens,
    /// Signed CoC in pixels where layer 0 starts (the nearest geometry).
    pub coc_near_px: f32,
    /// Layer thickness in pixels of CoC (the paper's delta).
    pub delta_px: f32,
    /// Number of layers.
    pub layers: usize,
    /// Overlap of neighbouring layers, as a fraction of `delta_px` (0.1 in the paper).
    pub overlap: f32,
}

impl LayerSpacing {
    /// Eq. 4: the layer of a signed CoC, clamped to the layers.
    #[inline]
    pub fn layer_of_coc(&self, coc_px: f32) -> usize {
        // `floor`, then clamped at 0: the same as the truncation, which saturates below 0 (and
        // takes NaN to 0) and is one instruction where `floor` is a library call.
        let l = (coc_px - self.coc_near_px) / self.delta_px;
        (l as usize).min(self.layers - 1)
    }

    /// The CoC interval `[C_l, C_l+1)` of layer `l`.
    #[inline]
    pub fn bounds(&self, l: usize) -> (f32, f32) {
        let a = self.coc_near_px + l as f32 * self.delta_px;
        (a, a + self.delta_px)
    }

    /// The layers a fragment of CoC `c` is written to: its own, and a neighbour when within the
    /// overlap of the boundary (at most two).
    #[inline]
    pub fn targets(&self, c: f32) -> (usize, Option<usize>) {
        let l = self.layer_of_coc(c);
        let (a, b) = self.bounds(l);
        let margin = self.overlap * self.delta_px;
        let other = if l > 0 && c - a < margin {
            Some(l - 1)
        } else if l + 1 < self.layers && b - c < margin {
            Some(l + 1)
        } else {
            None
        };
        (l, other)
    }
}

/// Per-layer images of one view: the signed CoC of the stored surface (+inf where empty) and
/// its premultiplied colour (half precision).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthLayers {
    /// How depths are cut.
    pub spacing: LayerSpacing,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `layers` images of `width * height` signed CoCs, layer after layer.
    pub coc_px: Vec<f32>,
    /// `layers` images of colours, layer after layer.
    pub color: Vec<HalfRgba>,
    /// Tiles' scratch buffers, handed back as each tile finishes (see [`LayersTile`]).
    pool: Pool,
    /// Per layer, whether a tile wrote a surface to it ([`DepthLayers::filled`]).
    written: Vec<bool>,
    /// Which surfaces of a guard band can be read from the frame ([`DepthLayers::with_reach`]).
    reach: Option<Reach>,
    /// Surfaces hidden far behind another of their layer go to the next layer too (see the
    /// module; [`DepthLayers::seeing_behind`]). Default on.
    see_behind: bool,
}

/// Scratch buffers of [`LayersTile`]s, shared by the tiles of a pass. Scratch, not content:
/// any two pools compare equal.
#[derive(Clone, Debug, Default)]
struct Pool(std::sync::Arc<std::sync::Mutex<Vec<Vec<[HeldFragment; SURFACES]>>>>);

impl PartialEq for Pool {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Pool {
    /// A buffer handed back earlier, or an empty one.
    fn take(&self) -> Vec<[HeldFragment; SURFACES]> {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default()
    }

    /// Hands a buffer back.
    fn give(&self, buffer: Vec<[HeldFragment; SURFACES]>) {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(buffer);
    }
}

impl DepthLayers {
    /// Empty layers.
    pub fn new(spacing: LayerSpacing, width: usize, height: usize) -> Self {
        let n = width * height * spacing.layers;
        Self {
            spacing,
            width,
            height,
            coc_px: super::filled_in_parallel(f32::INFINITY, n),
            color: super::filled_in_parallel([f16::ZERO; 4], n),
            pool: Pool::default(),
            written: vec![false; spacing.layers],
            reach: None,
            see_behind: true,
        }
    }

    /// Layers for the rasterizer to fill ([`BinnedView::rasterize`](super::BinnedView::rasterize)):
    /// the same as [`DepthLayers::new`] once every tile of the frame has ended, as each tile's
    /// pixels are then written in every layer. Until then the planes hold zeros, taken from the
    /// allocator untouched, so that a plane's memory is written once, not filled and then
    /// written again, and the colour of a pixel no surface reaches is never written at all.
    pub fn for_raster(spacing: LayerSpacing, width: usize, height: usize) -> Self {
        let n = width * height * spacing.layers;
        Self {
            spacing,
            width,
            height,
            coc_px: vec![0.0; n],
            color: zeroed_halves(n),
            pool: Pool::default(),
            written: vec![false; spacing.layers],
            reach: None,
            see_behind: true,
        }
    }

    /// Drops, as if hidden and before they are shaded, the fragments of a guard band that
    /// nothing in the frame reads (`reach`: its frame and how far a surface can be read from,
    /// in CoC radii and pixels).
    pub fn with_reach(mut self, reach: Reach) -> Self {
        self.reach = Some(reach);
        self
    }

    /// Whether a surface hidden in the pinhole view more than [`CONTINUITY_PX`] of CoC behind
    /// another of its layer is written to the next layer too (true, the default), or dropped
    /// as hidden (false: the layers of the paper, made see-through).
    pub fn seeing_behind(mut self, on: bool) -> Self {
        self.see_behind = on;
        self
    }

    /// Index of pixel `(x, y)` of layer `l`.
    #[inline]
    pub fn index(&self, l: usize, x: usize, y: usize) -> usize {
        (l * self.height + y) * self.width + x
    }

    /// Whether the rasterizer wrote a surface to layer `l` (known as the tiles end, instead of
    /// a scan of every plane: tens of megabytes at 1280x720).
    pub fn filled(&self, l: usize) -> bool {
        self.written[l]
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.coc_px.len() * 4 + self.color.len() * 8
    }
}

/// Surfaces a layer's pixel keeps apart while fragments arrive (more are merged into the
/// farthest): two panes over a board, each cut by a triangle edge through the pixel, resolve
/// exactly whatever order their halves arrive in.
const SURFACES: usize = 3;

/// Per-tile state of [`DepthLayers`].
///
/// Per layer and pixel (a slot) the `SURFACES` nearest surfaces. Most slots stay empty (a
/// pixel meets a few surfaces among tens of layers), so the slots live in a scratch buffer that
/// is neither cleared nor allocated per tile: a bit per slot says which hold something (the
/// others are [`HeldFragment::EMPTY`]), and when the tile finishes, its used slots are kept in a
/// short list and the buffer goes back to the pass's pool for the next tile. (A fresh buffer per
/// tile, then 48 bytes a slot, cleared by the kernel and then filled, took 40% of `decompose`,
/// and all tiles' buffers were held until the pass ended.)
#[derive(Debug)]
pub struct LayersTile {
    rect: TileRect,
    spacing: LayerSpacing,
    /// Slots, layer after layer; valid where `used` is set.
    held: Vec<[HeldFragment; SURFACES]>,
    /// Per pixel of a tile in the guard band, the depth from which its fragments cannot be read
    /// from the frame ([`Reach::depth_limit`]); empty elsewhere.
    limit: Vec<f32>,
    used: Vec<u64>,
    /// After [`TileSink::finish`]: the slots that hold a surface, in slot order, with the
    /// signed CoC of the nearer surface and the two composited.
    kept: Vec<(u32, f32, HalfRgba)>,
    pool: Pool,
    /// The lens's CoC scale, for the surfaces of a layer no blur separates.
    scale: CocScale,
    /// [`DepthLayers::seeing_behind`].
    see_behind: bool,
    /// The lens's `1 / z_f` and `1 / (f_px E)`, for the depth of a CoC.
    inv_focus: f32,
    inv_k: f32,
}

impl LayersTile {
    #[inline]
    fn slot(&self, l: usize, i: usize) -> usize {
        l * self.rect.width() * self.rect.height() + i
    }

    /// Whether a fragment at `depth_m` in pixel `i` of the tile lies beyond the frame's reach.
    #[inline(always)]
    fn unread(&self, i: usize, depth_m: f32) -> bool {
        self.limit.get(i).is_some_and(|&z| depth_m >= z)
    }

    #[inline]
    fn is_used(&self, s: usize) -> bool {
        self.used[s / 64] & (1 << (s % 64)) != 0
    }

    /// Whether an opaque fragment at `z` (CoC `c`) in layer `l` is hidden by what the layer
    /// holds: behind an opaque surface, and not so far behind it that it goes to the next layer
    /// too ([`LayersTile::seen_behind_from`]).
    #[inline]
    fn hidden(&self, l: usize, i: usize, z: f32, c: f32) -> bool {
        let s = self.slot(l, i);
        if !self.is_used(s) {
            return false;
        }
        // The farthest opaque surface at or in front of it; the limit only where there is
        // one (most calls find none).
        let mut farthest = f32::NEG_INFINITY;
        for h in &self.held[s] {
            if h.hides_behind() && z >= h.depth_m {
                farthest = farthest.max(h.depth_m);
            }
        }
        farthest > f32::NEG_INFINITY && farthest >= self.seen_behind_from(l, c)
    }

    /// The depth nearer than which a surface in front of one of CoC `c` in layer `l` lets it be
    /// seen behind it, so that it is written to the next layer when hidden: more than
    /// [`CONTINUITY_PX`] of CoC nearer, where seeing behind is on and there is a next layer;
    /// else 0 (no surface is nearer). One depth per hidden surface, so that the test of each
    /// surface in front is a comparison.
    #[inline]
    fn seen_behind_from(&self, l: usize, c: f32) -> f32 {
        if self.see_behind && l + 1 < self.spacing.layers {
            // `ThinLens::depth_for_coc_px` with its two constant quotients kept.
            let inv_z = self.inv_focus - (c - CONTINUITY_PX) * self.inv_k;
            if inv_z > 0.0 {
                1.0 / inv_z
            } else {
                f32::INFINITY
            }
        } else {
            0.0
        }
    }

    /// Slot `s` of layer `l` takes `f`: merged into its surface, or in depth order among the
    /// [`SURFACES`] nearest, the overflow merged into the farthest, nearer over farther (the
    /// slot is resolved to its surfaces composited front to back anyway, so all that is lost is
    /// their order; dropping the farthest left two panes, or two partly covering edges, over
    /// nothing). Held sorted near to far.
    #[inline]
    fn write(&mut self, l: usize, i: usize, f: &HeldFragment) {
        let s = self.slot(l, i);
        if !self.is_used(s) {
            self.used[s / 64] |= 1 << (s % 64);
            self.held[s] = [HeldFragment::EMPTY; SURFACES];
        }
        let held = &mut self.held[s];
        if let Some(mut k) = held.iter_mut().position(|h| h.merge(f)) {
            // A merged depth is a coverage-weighted mean: keep the order.
            while k > 0 && held[k].depth_m < held[k - 1].depth_m {
                held.swap(k, k - 1);
                k -= 1;
            }
            while k + 1 < SURFACES && held[k + 1].depth_m < held[k].depth_m {
                held.swap(k, k + 1);
                k += 1;
            }
            return;
        }
        match held.iter().position(|h| f.depth_m < h.depth_m) {
            Some(p) => {
                let last = held[SURFACES - 1];
                held.copy_within(p..SURFACES - 1, p + 1);
                held[p] = *f;
                if last.depth_m.is_finite() {
                    held[SURFACES - 1].absorb(&last);
                }
            }
            None => held[SURFACES - 1].absorb(f),
        }
        // The back of a thin closed mesh behind its front, hidden at every sample, is not a
        // surface of the layer (see `fragments::hide_coincident`). Only surfaces behind an
        // opaque one can be.
        if !held[0].depth_m.is_finite()
            || !held[..SURFACES - 1]
                .iter()
                .any(|h| h.depth_m.is_finite() && !h.blend && !h.dithered)
        {
            return;
        }
        let mut k = 1;
        while k < SURFACES {
            let h = held[k];
            let hidden = h.depth_m.is_finite()
                && !h.dithered
                && h.mask & !super::fragments::samples_hiding(&held[..k], &h, self.scale) == 0;
            if hidden {
                held.copy_within(k + 1.., k);
                held[SURFACES - 1] = HeldFragment::EMPTY;
            } else {
                k += 1;
            }
        }
    }
}

impl LayersTile {
    /// Resolves the coverage masks of slot `s`'s `surfaces` (`fragments::hide_coincident`)
    /// together with the surfaces of the same pixel in the layer in front, which a ray meets
    /// just before them: a layer boundary may fall between the front and the back of a thin
    /// closed mesh (a small double-sided light 0.3% of its depth deep), and the back, hidden at
    /// every sample, was a second surface a ray met behind the first (the light's rim twice as
    /// bright). Surfaces hidden entirely are taken out, so that a slot's height field is a
    /// surface that shows.
    fn hide_coincident_across(
        &self,
        s: usize,
        area: usize,
        surfaces: &mut [HeldFragment; SURFACES],
    ) {
        let front_layer = s.checked_sub(area).filter(|&p| self.is_used(p));
        let Some(p) = front_layer else {
            super::fragments::hide_coincident(surfaces, self.scale);
            return;
        };
        let mut all = [HeldFragment::EMPTY; 2 * SURFACES];
        all[..SURFACES].copy_from_slice(&self.held[p]);
        all[SURFACES..].copy_from_slice(surfaces);
        // Near to far; stable, so the layer in front comes first among equals.
        all.sort_by(|a, b| a.depth_m.total_cmp(&b.depth_m));
        let finite = all.iter().take_while(|h| h.depth_m.is_finite()).count();
        let mut resolved = all;
        super::fragments::hide_coincident(&mut resolved[..finite], self.scale);
        // This slot's surfaces, in their order, with what the resolution left of them.
        let mut kept = [HeldFragment::EMPTY; SURFACES];
        let mut n = 0;
        for h in surfaces.iter().filter(|h| h.depth_m.is_finite()) {
            let at = (0..finite).find(|&k| all[k] == *h).unwrap_or(0);
            let r = resolved[at];
            if r.color[3] > 0.0 && n < SURFACES {
                kept[n] = r;
                n += 1;
            }
        }
        *surfaces = kept;
    }
}

impl TileSink for LayersTile {
    #[inline]
    fn occluded(&self, x: u32, y: u32, depth_m: f32) -> bool {
        let i = (y as usize - self.rect.y0) * self.rect.width() + (x as usize - self.rect.x0);
        if self.unread(i, depth_m) {
            return true;
        }
        let c = self.spacing.lens.coc_px(depth_m);
        let (l, other) = self.spacing.targets(c);
        self.hidden(l, i, depth_m, c) && other.is_none_or(|o| self.hidden(o, i, depth_m, c))
    }

    #[inline]
    fn fragment(&mut self, f: &Fragment) {
        let held = HeldFragment::of(f);
        if held.color[3] <= 0.0 {
            return;
        }
        let i = (f.y as usize - self.rect.y0) * self.rect.width() + (f.x as usize - self.rect.x0);
        if self.unread(i, f.depth_m) {
            return;
        }
        let (l, other) = self.spacing.targets(self.spacing.lens.coc_px(f.depth_m));
        self.write(l, i, &held);
        if let Some(o) = other.filter(|_| held.covers_pixel()) {
            self.write(o, i, &held);
        }
    }

    /// Resolves each used slot (still in parallel with other tiles): the surfaces no blur
    /// separates by their masks, then the nearer surface over the farther, premultiplied.
    fn finish(&mut self) {
        let lens = self.spacing.lens;
        let area = self.rect.width() * self.rect.height();
        // Slot by slot in order. A slot's hidden surface goes to the same pixel of the next
        // layer, a later slot: the words of `used` are read again as they may gain bits.
        for w in 0..self.used.len() {
            let mut done = 0u64;
            loop {
                let bits = self.used[w] & !done;
                if bits == 0 {
                    break;
                }
                let b = bits.trailing_zeros();
                done |= 1 << b;
                let s = w * 64 + b as usize;
                let mut surfaces = self.held[s];
                self.hide_coincident_across(s, area, &mut surfaces);
                let [front, behind @ ..] = &mut surfaces;
                if front.depth_m.is_finite() {
                    let (l, i) = (s / area, s % area);
                    // The nearest surface far enough behind the front for a ray to pass
                    // behind the front and reach it, with what lies behind it, to the next
                    // layer as well.
                    if let Some(k) = behind.iter().position(|h| {
                        h.depth_m.is_finite()
                            && front.depth_m < self.seen_behind_from(l, lens.coc_px(h.depth_m))
                    }) {
                        let mut hidden = behind[k];
                        for h in behind[k + 1..].iter().filter(|h| h.depth_m.is_finite()) {
                            hidden.absorb(h);
                        }
                        self.write(l + 1, i, &hidden);
                    }
                    // Front to back, premultiplied.
                    for h in behind.iter().filter(|h| h.depth_m.is_finite()) {
                        front.absorb(h);
                    }
                    self.kept
                        .push((s as u32, lens.coc_px(front.depth_m), to_half(front.color)));
                }
            }
        }
        self.pool.give(std::mem::take(&mut self.held));
    }
}

impl Sink for DepthLayers {
    type Tile = LayersTile;

    fn begin_tile(&self, rect: TileRect) -> LayersTile {
        let n = rect.width() * rect.height() * self.spacing.layers;
        let mut held = self.pool.take();
        // Only grown, never cleared: a slot is written before it is read (`used`).
        if held.len() < n {
            held.resize(n, [HeldFragment::EMPTY; SURFACES]);
        }
        let limit = match &self.reach {
            Some(reach) if !reach.holds(&rect) => (0..rect.width() * rect.height())
                .map(|k| reach.depth_limit(rect.x0 + k % rect.width(), rect.y0 + k / rect.width()))
                .collect(),
            _ => Vec::new(),
        };
        LayersTile {
            rect,
            spacing: self.spacing,
            held,
            limit,
            used: vec![0; n.div_ceil(64)],
            kept: Vec::new(),
            pool: self.pool.clone(),
            scale: CocScale::of(&self.spacing.lens),
            see_behind: self.see_behind,
            inv_focus: 1.0 / self.spacing.lens.focus_m,
            inv_k: 1.0 / (self.spacing.lens.f_px * self.spacing.lens.lens_radius_m),
        }
    }

    fn end_tile(&mut self, rect: TileRect, tile: LayersTile) {
        self.keep(&[(rect, tile)]);
    }

    fn end_tiles(&mut self, tiles: Vec<(TileRect, LayersTile)>) {
        self.keep(&tiles);
        // The pass is over: its scratch buffers go.
        self.pool
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }
}

impl DepthLayers {
    /// Copies the tiles' kept surfaces into the layers, a layer to a task (a tile's list is in
    /// slot order, so layer after layer).
    fn keep(&mut self, tiles: &[(TileRect, LayersTile)]) {
        let (w, plane) = (self.width, self.width * self.height);
        if plane == 0 {
            // No pixels, so no surfaces (and no chunks to cut).
            return;
        }
        self.coc_px
            .par_chunks_mut(plane)
            .zip(self.color.par_chunks_mut(plane))
            .zip(self.written.par_iter_mut())
            .enumerate()
            .for_each(|(l, ((coc_px, color), written))| {
                for (rect, tile) in tiles {
                    let (tw, n) = (rect.width(), rect.width() * rect.height());
                    // The tile's pixels hold no surface, then its kept ones ([`for_raster`]'s
                    // planes are set here). Colours stay as they are: zero.
                    for y in rect.y0..rect.y1 {
                        coc_px[y * w + rect.x0..y * w + rect.x1].fill(f32::INFINITY);
                    }
                    let kept = &tile.kept;
                    let start = kept.partition_point(|k| (k.0 as usize) < l * n);
                    let end = kept.partition_point(|k| (k.0 as usize) < (l + 1) * n);
                    // Slots come in order: the row is followed, not divided out.
                    let (mut y, mut row) = (rect.y0, 0);
                    for &(s, coc, c) in &kept[start..end] {
                        let i = s as usize - l * n;
                        while i >= row + tw {
                            (y, row) = (y + 1, row + tw);
                        }
                        let d = y * w + rect.x0 + i - row;
                        coc_px[d] = coc;
                        color[d] = c;
                    }
                    *written |= start < end;
                }
            });
    }
}

/// `n` colours of zero, taken zeroed from the allocator: their pages are not touched until
/// written.
fn zeroed_halves(n: usize) -> Vec<HalfRgba> {
    let layout = std::alloc::Layout::array::<HalfRgba>(n).expect("the layers' budget bounds n");
    if layout.size() == 0 {
        return Vec::new();
    }
    // SAFETY: the layout has a non-zero size; the block is `n` colours of all-zero bits, which
    // are `f16` zeros, and is handed to a `Vec` with the layout it was allocated with.
    unsafe {
        let p = std::alloc::alloc_zeroed(layout).cast::<HalfRgba>();
        if p.is_null() {
            std::alloc::handle_alloc_error(layout);
        }
        Vec::from_raw_parts(p, n, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Surfaces written by several tiles land in their own layer and pixel (the copy runs a
    /// layer to a task), the layers no tile wrote stay empty and say so, and a stack of no
    /// pixels takes its tiles back without a fault.
    #[test]
    fn tiles_copy_their_surfaces_to_their_layers_and_pixels() {
        tiles_copy_their_surfaces_into(DepthLayers::new);
    }

    /// The same with the planes the tiles set themselves: every pixel no surface reaches holds
    /// none once the tiles have ended.
    #[test]
    fn layers_for_the_rasterizer_are_set_in_full_by_their_tiles() {
        tiles_copy_their_surfaces_into(DepthLayers::for_raster);
    }

    fn tiles_copy_their_surfaces_into(make: fn(LayerSpacing, usize, usize) -> DepthLayers) {
        use crate::raster::fragments::tests::reach;
        use crate::raster::FULL_COVERAGE;
        let lens = reach().lens;
        let spacing = LayerSpacing {
            lens,
            coc_near_px: -10.0,
            delta_px: 4.0,
            layers: 6,
            overlap: 0.0,
        };
        let (w, h) = (150, 70);
        let mut layers = make(spacing, w, h);
        // One opaque surface per pixel, at a depth and in a colour of its own, in 3x2 tiles.
        let surfaces = [
            (3, 5, 1.2f32),
            (70, 10, 2.0),
            (140, 65, 9.0),
            (64, 64, 2.0),
            (10, 66, 1.5),
        ];
        let rects = crate::raster::tile_grid(w, h);
        let tiles = rects
            .iter()
            .map(|&rect| {
                let mut tile = layers.begin_tile(rect);
                for (k, &(x, y, z)) in surfaces.iter().enumerate() {
                    if (rect.x0..rect.x1).contains(&x) && (rect.y0..rect.y1).contains(&y) {
                        tile.fragment(&Fragment {
                            x: x as u32,
                            y: y as u32,
                            depth_m: z,
                            color: [0.1 * k as f32, 0.5, 0.25, 1.0],
                            blend: false,
                            coverage: FULL_COVERAGE,
                            dithered: false,
                            back_facing: false,
                        });
                    }
                }
                tile.finish();
                (rect, tile)
            })
            .collect();
        layers.end_tiles(tiles);
        let mut written = [false; 6];
        for (k, &(x, y, z)) in surfaces.iter().enumerate() {
            let c = lens.coc_px(z);
            let l = spacing.layer_of_coc(c);
            written[l] = true;
            let i = layers.index(l, x, y);
            assert_eq!(layers.coc_px[i], c, "surface {k}");
            assert_eq!(
                layers.color[i][0],
                to_half([0.1 * k as f32; 4])[0],
                "surface {k}"
            );
        }
        let stored = layers.coc_px.iter().filter(|c| c.is_finite()).count();
        assert_eq!(stored, surfaces.len());
        let coloured = layers.color.iter().filter(|c| c[1] != f16::ZERO).count();
        assert_eq!(coloured, surfaces.len());
        for (l, &w) in written.iter().enumerate() {
            assert_eq!(layers.filled(l), w, "layer {l}");
        }
        assert!(written.iter().any(|&w| !w), "an empty layer is checked too");
        let mut none = make(spacing, 0, 0);
        none.end_tiles(Vec::new());
        assert!(!none.filled(0));
    }

    /// An opaque surface hides, in the pinhole view, a surface of its layer 2.8 px of CoC behind
    /// it: that one is shaded and written to the next layer too, where a ray that passes behind
    /// the front finds it. One 1.3 px behind a front (within [`CONTINUITY_PX`]) stays hidden,
    /// as before.
    #[test]
    fn a_surface_hidden_far_behind_another_of_its_layer_goes_to_the_next_layer_too() {
        use crate::raster::fragments::tests::reach;
        use crate::raster::FULL_COVERAGE;
        let lens = reach().lens;
        let spacing = LayerSpacing {
            lens,
            coc_near_px: -2.92,
            delta_px: 4.0,
            layers: 3,
            overlap: 0.0,
        };
        let (w, h) = (16, 16);
        let mut layers = DepthLayers::for_raster(spacing, w, h);
        let rect = TileRect {
            x0: 0,
            y0: 0,
            x1: w,
            y1: h,
        };
        let fragment = |x: u32, c: f32, red: f32| Fragment {
            x,
            y: 5,
            depth_m: lens.depth_for_coc_px(c),
            color: [red, 0.5, 0.25, 1.0],
            blend: false,
            coverage: FULL_COVERAGE,
            dithered: false,
            back_facing: false,
        };
        let mut tile = layers.begin_tile(rect);
        // Pixels 3 and 9: a front at -2.8 px first, then a surface behind it in the same layer.
        tile.fragment(&fragment(3, -2.8, 0.1));
        tile.fragment(&fragment(9, -2.8, 0.1));
        for (f, hidden) in [
            (fragment(3, 0.0, 0.7), false),
            (fragment(9, -1.5, 0.7), true),
        ] {
            assert_eq!(tile.occluded(f.x, f.y, f.depth_m), hidden, "pixel {}", f.x);
            if !hidden {
                tile.fragment(&f);
            }
        }
        tile.finish();
        layers.end_tiles(vec![(rect, tile)]);
        for x in [3, 9] {
            let i = layers.index(0, x, 5);
            assert!(
                (layers.coc_px[i] + 2.8).abs() < 1e-3,
                "{}",
                layers.coc_px[i]
            );
            assert_eq!(layers.color[i][0], to_half([0.1; 4])[0]);
        }
        let behind = layers.index(1, 3, 5);
        assert!(
            layers.coc_px[behind].abs() < 1e-3,
            "{}",
            layers.coc_px[behind]
        );
        assert_eq!(layers.color[behind][0], to_half([0.7; 4])[0]);
        assert_eq!(layers.coc_px[layers.index(1, 9, 5)], f32::INFINITY);
        assert!(!layers.filled(2));
        // Off: the far one is hidden too, and the next layer stays empty.
        let layers = DepthLayers::for_raster(spacing, w, h).seeing_behind(false);
        let mut tile = layers.begin_tile(rect);
        tile.fragment(&fragment(3, -2.8, 0.1));
        assert!(tile.occluded(3, 5, lens.depth_for_coc_px(0.0)));
    }

    /// A tile of the guard band drops, as if hidden, the fragments at or behind its pixels'
    /// depth limits and keeps nearer ones; a tile inside the frame drops nothing.
    #[test]
    fn a_band_tile_drops_what_the_frame_cannot_read() {
        use crate::raster::fragments::tests::{assert_drops_from, reach, BAND_TILE};
        // The fragment lists' test lens and frame, with square distances as multiview's band.
        let reach = Reach {
            factor: 1.5,
            slack_px: 3.0,
            square: true,
            ..reach()
        };
        let spacing = LayerSpacing {
            lens: reach.lens,
            coc_near_px: -40.0,
            delta_px: 4.0,
            layers: 12,
            overlap: 0.1,
        };
        let layers = DepthLayers::new(spacing, 180, 140).with_reach(reach);
        // 31.5 px left of the frame: only CoCs of (31.5 - 3) / 1.5 = 19 px or more are read.
        let z = reach.depth_limit(8, 70);
        assert!((reach.lens.coc_px(z) + 19.0).abs() < 1e-3, "{z}");
        assert_drops_from(&layers.begin_tile(BAND_TILE), z);
        let inside = layers.begin_tile(TileRect {
            x0: 48,
            y0: 48,
            x1: 64,
            y1: 64,
        });
        assert!(!inside.occluded(50, 50, 50.0));
    }
}
