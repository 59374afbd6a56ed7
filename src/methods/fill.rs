//! One image, two layers: what a post-process method sees behind near blur (`--occlusion
//! fill`), after Kraus and Strengert, *Depth-of-Field Rendering by Pyramidal Image Processing*
//! (Eurographics 2007): decompose the frame by depth, fill each layer where nearer ones hide
//! it by pyramidal interpolation (pull-push), blur each layer with its own CoC, and composite
//! them front to back.
//!
//! A frame and its depth pass hold one surface a pixel. Blurred as one layer, a near
//! out-of-focus object (a railing, a branch) spreads over what lies behind it, but where its
//! blur turns transparent the method can only show the object's own smear: the surface behind
//! it is not in the frame. Here the frame is split in two:
//! - the **near layer**: the pixels whose CoC radius is at least `near_coc_px` in front of the
//!   focus, with their colour; transparent elsewhere, its depth there filled from the near
//!   pixels around, so that its blur spreads past its silhouette with the near CoC;
//! - the **back layer**: every other pixel, and where the near layer (widened by
//!   `dilate_px` pixels, whose anti-aliased edge colours mix both layers) hides it, colour and
//!   depth filled by pull-push from the back layer's own pixels around the hole.
//!
//! Passes: `fill/decompose` (masks and pull-push), then the method's own passes on each layer
//! (their times summed under the method's pass names), then `fill/composite` (the near layer's
//! blur over the back layer's: `near + (1 - near alpha) back`). A frame with no near pixel is
//! the method's own result, unchanged.
//!
//! The fill is a smooth interpolation: texture hidden behind a near object does not come back,
//! only its colours. Measured against Blender Cycles' truth (see the method pages).

use rayon::prelude::*;

use super::coc_map;
use super::registry::{self, Frame, MethodSettings};
use super::MethodOutput;
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::raster::{to_half, FragmentLists};
use crate::timing::Timings;
use crate::{Error, Result};

/// How a post-process method treats what near blur uncovers (`--occlusion`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Occlusion {
    /// One layer: the frame blurred as it is (the methods as their papers describe them).
    #[default]
    None,
    /// Two layers, the back one filled where the near one hides it (this module).
    Fill,
}

impl Occlusion {
    /// Parses `none` or `fill`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" => Ok(Self::None),
            "fill" => Ok(Self::Fill),
            other => Err(Error::invalid(
                "occlusion",
                format!("{other:?}: expected none or fill"),
            )),
        }
    }

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Fill => "fill",
        }
    }
}

/// Settings of the decomposition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FillSettings {
    /// Pixels at least this CoC radius in front of the focus (pixels) form the near layer.
    pub near_coc_px: f32,
    /// The hole left in the back layer is the near layer widened by this many pixels.
    pub dilate_px: usize,
}

impl Default for FillSettings {
    fn default() -> Self {
        Self {
            near_coc_px: 2.0,
            dilate_px: 1,
        }
    }
}

/// Pass names of the decomposition.
pub mod pass {
    /// Masks and pull-push of both layers.
    pub const DECOMPOSE: &str = "fill/decompose";
    /// The near layer's blur over the back layer's.
    pub const COMPOSITE: &str = "fill/composite";
}

/// Runs the post-process method `settings` on `frame` decomposed into a near and a filled back
/// layer (see the module documentation). A frame with no near pixel gives
/// [`registry::run_frame`]'s result.
pub fn run_frame(
    settings: &MethodSettings,
    frame: &Frame,
    fill: &FillSettings,
) -> Result<MethodOutput> {
    check_budget(settings, frame)?;
    let start = std::time::Instant::now();
    let Some(layers) = decompose(frame, fill)? else {
        return registry::run_frame(settings, frame);
    };
    let mut timings = Timings::default();
    timings.add(pass::DECOMPOSE, start.elapsed().as_secs_f64() * 1e3);
    let back = registry::run_frame(
        settings,
        &Frame {
            color: &layers.back_color,
            depth: &layers.back_depth,
            lens: frame.lens,
        },
    )?;
    let front = registry::run_frame(
        settings,
        &Frame {
            color: &layers.near_color,
            depth: &layers.near_depth,
            lens: frame.lens,
        },
    )?;
    timings.extend(&back.timings);
    timings.extend(&front.timings);
    let image = timings.time(pass::COMPOSITE, || over(&front.image, &back.image))?;
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}

/// Bytes a pixel the decomposition holds at its peak besides the method's own run: the masks,
/// the back and near layers' colour and depth, the pull-push pyramids of a colour and a depth
/// (a third more than their base), the two-fragment lists of the layered methods, the back
/// layer's blurred image while the near one is blurred, and the composite.
pub const BYTES_PER_PIXEL: u64 = 160;

/// Refuses a decomposition whose estimate (the method's, [`registry::peak_bytes`], and
/// [`BYTES_PER_PIXEL`]) exceeds the memory budget, before anything is allocated.
fn check_budget(settings: &MethodSettings, frame: &Frame) -> Result<()> {
    let (w, h) = (frame.color.width(), frame.color.height());
    crate::budget::check(
        registry::peak_bytes(settings, w, h) + (w * h) as u64 * BYTES_PER_PIXEL,
        &format!("{} with --occlusion fill at {w}x{h}", settings.id()),
        "the resolution",
    )
}

/// A frame split in two layers (see the module documentation).
struct Layers {
    /// The near pixels (row-major).
    near: Vec<bool>,
    near_color: ColorImage,
    near_depth: GrayImage,
    back_color: ColorImage,
    back_depth: GrayImage,
}

/// Pass `decompose`: the frame's near layer and its filled back layer, or `None` when no pixel
/// is near.
fn decompose(frame: &Frame, fill: &FillSettings) -> Result<Option<Layers>> {
    let (w, h) = (frame.color.width(), frame.color.height());
    let near: Vec<bool> = frame
        .depth
        .pixels()
        .par_iter()
        .map(|&z| frame.lens.coc_px(z) <= -fill.near_coc_px)
        .collect();
    if !near.iter().any(|&n| n) {
        return Ok(None);
    }
    let hole = dilate(&near, w, h, fill.dilate_px);
    // The back layer: its own pixels, and the hole filled from them.
    let back_known: Vec<f32> = hole.iter().map(|&hd| f32::from(u8::from(!hd))).collect();
    let (back_color, back_depth) = pull_push_color_depth(frame.color, frame.depth, &back_known);
    // The near layer: its pixels, transparent elsewhere, its depth spread from its pixels.
    let near_known: Vec<f32> = near.iter().map(|&n| f32::from(u8::from(n))).collect();
    let mut near_depth = pull_push_depth(frame.depth, &near_known);
    // Beyond the reach of the nearest blur the near layer is empty and its blur adds nothing:
    // in focus there, so that the method's gather is a single tap.
    let reach = frame
        .depth
        .pixels()
        .par_iter()
        .zip(near.par_iter())
        .filter(|(_, &n)| n)
        .map(|(&z, _)| frame.lens.coc_px(z).abs())
        .reduce(|| 0.0f32, f32::max);
    let reached = dilate(&near, w, h, reach.ceil() as usize + 2);
    let focus_m = frame.lens.focus_m;
    near_depth
        .pixels_mut()
        .par_iter_mut()
        .zip(reached.par_iter())
        .filter(|(_, &r)| !r)
        .for_each(|(z, _)| *z = focus_m);
    let near_color = ColorImage::from_vec(
        w,
        h,
        frame
            .color
            .pixels()
            .par_iter()
            .zip(near.par_iter())
            .map(|(&c, &n)| if n { c } else { [0.0; 4] })
            .collect(),
    )?;
    Ok(Some(Layers {
        near,
        near_color,
        near_depth,
        back_color,
        back_depth,
    }))
}

/// The fragment lists of a frame for the layered methods: with `fill`, each near pixel holds
/// its own fragment and, behind it, the filled back layer's; every other pixel the back
/// layer's (where the near layer's widened edge hid it, filled). Without, one fragment a
/// pixel: the frame as it is.
pub fn fragment_lists(frame: &Frame, fill: Option<&FillSettings>) -> Result<FragmentLists> {
    coc_map::check_frame(frame.color, frame.depth, frame.lens)?;
    let (w, h) = (frame.color.width(), frame.color.height());
    let layers = match fill {
        Some(fill) => decompose(frame, fill)?,
        None => None,
    };
    let (depth, color) = (frame.depth.pixels(), frame.color.pixels());
    let Some(l) = layers else {
        let offsets = (0..=(w * h) as u32).collect();
        let color = color.par_iter().map(|&c| to_half(c)).collect();
        return Ok(FragmentLists::from_parts(
            w,
            h,
            offsets,
            depth.to_vec(),
            color,
        ));
    };
    // Offsets from the near pixels' counts (two fragments each), then the fragments, nearest
    // first.
    let mut offsets = Vec::with_capacity(w * h + 1);
    offsets.push(0u32);
    let mut total = 0u32;
    for &n in &l.near {
        total += 1 + u32::from(n);
        offsets.push(total);
    }
    let mut zs = Vec::with_capacity(total as usize);
    let mut cs = Vec::with_capacity(total as usize);
    let (back_z, back_c) = (l.back_depth.pixels(), l.back_color.pixels());
    for i in 0..w * h {
        let back = (back_z[i], back_c[i]);
        let mut put = |(z, c): (f32, Rgba)| {
            zs.push(z);
            cs.push(to_half(c));
        };
        if l.near[i] {
            let own = (depth[i], color[i]);
            let (first, second) = if own.0 <= back.0 {
                (own, back)
            } else {
                (back, own)
            };
            put(first);
            put(second);
        } else {
            put(back);
        }
    }
    Ok(FragmentLists::from_parts(w, h, offsets, zs, cs))
}

/// A layered method (`multilayer`, `splat`) on a frame: its fragment lists
/// ([`fragment_lists`]; decomposed and filled with `occlusion` `fill`), then the method's
/// passes on them. Timed as `fill/decompose` and the method's passes.
pub fn run_layered(
    settings: &MethodSettings,
    frame: &Frame,
    occlusion: Occlusion,
) -> Result<MethodOutput> {
    check_budget(settings, frame)?;
    let start = std::time::Instant::now();
    let fill = FillSettings::default();
    let lists = fragment_lists(frame, (occlusion == Occlusion::Fill).then_some(&fill))?;
    let decompose_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut out = match settings {
        MethodSettings::Multilayer(s) => super::multilayer::render_lists(lists, frame.lens, s)?,
        MethodSettings::Splat(s) => super::splat::render_lists(lists, frame.lens, s)?.0,
        other => {
            return Err(Error::invalid(
                "method",
                format!(
                    "{} does not take fragment lists; the layered methods that blur a frame: \
                     multilayer, splat",
                    other.id()
                ),
            ))
        }
    };
    let mut timings = Timings::default();
    timings.add(pass::DECOMPOSE, decompose_ms);
    timings.extend(&out.timings);
    out.timings = timings;
    Ok(out)
}

/// `front` over `back`, premultiplied: `front + (1 - front alpha) back`.
fn over(front: &ColorImage, back: &ColorImage) -> Result<ColorImage> {
    let pixels: Vec<Rgba> = front
        .pixels()
        .par_iter()
        .zip(back.pixels())
        .map(|(f, b)| {
            let t = 1.0 - f[3].clamp(0.0, 1.0);
            [
                f[0] + t * b[0],
                f[1] + t * b[1],
                f[2] + t * b[2],
                f[3] + t * b[3],
            ]
        })
        .collect();
    ColorImage::from_vec(front.width(), front.height(), pixels)
}

/// `mask` widened by `r` pixels (a square window), in time independent of `r` (running counts
/// along rows, then columns).
fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    if r == 0 {
        return mask.to_vec();
    }
    // Along each row: whether any of the pixels within r is set.
    let mut rows = vec![false; w * h];
    rows.par_chunks_mut(w)
        .zip(mask.par_chunks(w))
        .for_each(|(out, src)| {
            let mut prefix = vec![0u32; w + 1];
            for x in 0..w {
                prefix[x + 1] = prefix[x] + u32::from(src[x]);
            }
            for (x, o) in out.iter_mut().enumerate() {
                *o = prefix[(x + r + 1).min(w)] > prefix[x.saturating_sub(r)];
            }
        });
    // Down each column, a band of rows at a time.
    let mut count = vec![0u32; w];
    let mut out = vec![false; w * h];
    let row = |y: usize| &rows[y * w..(y + 1) * w];
    for y in 0..r.min(h) {
        for (c, &b) in count.iter_mut().zip(row(y)) {
            *c += u32::from(b);
        }
    }
    for y in 0..h {
        if y + r < h {
            for (c, &b) in count.iter_mut().zip(row(y + r)) {
                *c += u32::from(b);
            }
        }
        if y > r {
            for (c, &b) in count.iter_mut().zip(row(y - r - 1)) {
                *c -= u32::from(b);
            }
        }
        for (o, &c) in out[y * w..(y + 1) * w].iter_mut().zip(&count) {
            *o = c > 0;
        }
    }
    out
}

/// The colour of `image` and the depth of `depth` where `known` is 1, filled by pull-push
/// elsewhere, in one pyramid (their weights are the same): the colour as it is, the depth as
/// [`pull_push_depth`] fills it. Each channel is computed as a pyramid of its own would.
fn pull_push_color_depth(
    image: &ColorImage,
    depth: &GrayImage,
    known: &[f32],
) -> (ColorImage, GrayImage) {
    let (w, h) = (image.width(), image.height());
    let values: Vec<[f32; 5]> = image
        .pixels()
        .par_iter()
        .zip(depth.pixels().par_iter())
        .map(|(c, &z)| [c[0], c[1], c[2], c[3], 1.0 / z])
        .collect();
    let filled = pull_push(values, known.to_vec(), w, h);
    let color = filled
        .par_iter()
        .map(|v| [v[0], v[1], v[2], v[3]])
        .collect();
    let depth = filled
        .par_iter()
        .zip(depth.pixels().par_iter())
        .zip(known.par_iter())
        .map(|((v, &z), &k)| depth_from_inverse(v[4], z, k))
        .collect();
    (
        ColorImage::from_vec(w, h, color).expect("sizes agree by construction"),
        GrayImage::from_vec(w, h, depth).expect("sizes agree by construction"),
    )
}

/// A filled depth from its interpolated inverse `v`: the pixel's own `z` where it was known
/// (`k` 1), else `1 / v`, infinite where nothing finite was near.
#[inline]
fn depth_from_inverse(v: f32, z: f32, k: f32) -> f32 {
    if k >= 1.0 {
        z
    } else if v > 0.0 {
        1.0 / v
    } else {
        f32::INFINITY
    }
}

/// The depth of `depth` where `known` is 1, filled by pull-push elsewhere: inverse depth is
/// interpolated (so that a far or infinite background does not swamp a near one), then turned
/// back into depth.
fn pull_push_depth(depth: &GrayImage, known: &[f32]) -> GrayImage {
    let (w, h) = (depth.width(), depth.height());
    let values: Vec<[f32; 1]> = depth.pixels().par_iter().map(|&z| [1.0 / z]).collect();
    let filled = pull_push(values, known.to_vec(), w, h);
    let data = filled
        .par_iter()
        .zip(depth.pixels().par_iter())
        .zip(known.par_iter())
        .map(|((v, &z), &k)| depth_from_inverse(v[0], z, k))
        .collect();
    GrayImage::from_vec(w, h, data).expect("sizes agree by construction")
}

/// One level of the pull-push pyramid: values, weights, width, height.
type Level<const N: usize> = (Vec<[f32; N]>, Vec<f32>, usize, usize);

/// Pyramidal interpolation (pull-push, Gortler et al. 1996; Kraus and Strengert 2007): the
/// values whose weight is 1 are kept, the others are filled from coarser and coarser averages
/// of the weighted values around them, each level blended into the next finer one bilinearly.
fn pull_push<const N: usize>(
    values: Vec<[f32; N]>,
    weights: Vec<f32>,
    w: usize,
    h: usize,
) -> Vec<[f32; N]> {
    // Pull: each level the weighted mean of 2x2 cells of the finer one, weights capped at 1.
    let mut levels: Vec<Level<N>> = vec![(values, weights, w, h)];
    while {
        let (_, _, lw, lh) = levels.last().expect("one level at least");
        *lw > 1 || *lh > 1
    } {
        let (v, wt, lw, lh) = levels.last().expect("one level at least");
        let (cw, ch) = (lw.div_ceil(2), lh.div_ceil(2));
        let mut cv = vec![[0.0f32; N]; cw * ch];
        let mut cwt = vec![0.0f32; cw * ch];
        cv.par_chunks_mut(cw)
            .zip(cwt.par_chunks_mut(cw))
            .enumerate()
            .for_each(|(cy, (row_v, row_w))| {
                for cx in 0..cw {
                    let (mut sum, mut sw) = ([0.0f32; N], 0.0f32);
                    for y in 2 * cy..(2 * cy + 2).min(*lh) {
                        for x in 2 * cx..(2 * cx + 2).min(*lw) {
                            let i = y * lw + x;
                            for k in 0..N {
                                sum[k] += v[i][k] * wt[i];
                            }
                            sw += wt[i];
                        }
                    }
                    if sw > 0.0 {
                        row_v[cx] = sum.map(|s| s / sw);
                    }
                    row_w[cx] = sw.min(1.0);
                }
            });
        levels.push((cv, cwt, cw, ch));
    }
    // Push: from the coarsest, each level's partly known values blended with the coarser
    // level read bilinearly at their centres.
    for l in (0..levels.len() - 1).rev() {
        let (upper, lower) = levels.split_at_mut(l + 1);
        let (v, wt, lw, _) = &mut upper[l];
        let (cv, _, cw, ch) = &lower[0];
        let (lw, cw, ch) = (*lw, *cw, *ch);
        v.par_chunks_mut(lw)
            .zip(wt.par_chunks_mut(lw))
            .enumerate()
            .for_each(|(y, (row_v, row_w))| {
                for x in 0..lw {
                    if row_w[x] >= 1.0 {
                        continue;
                    }
                    // The centre of (x, y) in the coarser level's pixels, less a half.
                    let fx = ((x as f32 + 0.5) * 0.5 - 0.5).clamp(0.0, (cw - 1) as f32);
                    let fy = ((y as f32 + 0.5) * 0.5 - 0.5).clamp(0.0, (ch - 1) as f32);
                    // Truncation is the floor here: both are clamped at 0 (and `floor` is a library call
                    // on the baseline x86-64).
                    let (x0, y0) = (fx as usize, fy as usize);
                    let (x1, y1) = ((x0 + 1).min(cw - 1), (y0 + 1).min(ch - 1));
                    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                    let at = |x: usize, y: usize| cv[y * cw + x];
                    let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
                    let own = row_w[x];
                    for k in 0..N {
                        let top = a[k] + (b[k] - a[k]) * tx;
                        let bottom = c[k] + (d[k] - c[k]) * tx;
                        let coarse = top + (bottom - top) * ty;
                        row_v[x][k] = own * row_v[x][k] + (1.0 - own) * coarse;
                    }
                    row_w[x] = 1.0;
                }
            });
    }
    levels.swap_remove(0).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pull_push_keeps_known_values_and_fills_a_hole_between_two_values_smoothly() {
        let (w, h) = (16, 4);
        // Left half 0, right half 1, the middle four columns unknown.
        let values: Vec<[f32; 1]> = (0..w * h)
            .map(|i| [if i % w < w / 2 { 0.0 } else { 1.0 }])
            .collect();
        let weights: Vec<f32> = (0..w * h)
            .map(|i| if (6..10).contains(&(i % w)) { 0.0 } else { 1.0 })
            .collect();
        let out = pull_push(values.clone(), weights.clone(), w, h);
        for i in 0..w * h {
            if weights[i] == 1.0 {
                assert_eq!(out[i], values[i], "known value {i} kept");
            } else {
                assert!(out[i][0] > 0.0 && out[i][0] < 1.0, "{i}: {:?}", out[i]);
            }
        }
        // Filled values rise from left to right along a row.
        for x in 6..9 {
            assert!(out[x][0] <= out[x + 1][0], "{x}: {:?}", &out[5..11]);
        }
        // A constant image stays constant whatever is unknown.
        let flat = pull_push(vec![[0.3f32; 1]; w * h], weights, w, h);
        assert!(flat.iter().all(|v| (v[0] - 0.3).abs() < 1e-6));
    }

    #[test]
    fn dilate_widens_by_the_radius() {
        let (w, h) = (7, 5);
        let mut m = vec![false; w * h];
        m[2 * w + 3] = true;
        let d = dilate(&m, w, h, 1);
        let count = d.iter().filter(|&&b| b).count();
        assert_eq!(count, 9);
        assert!(d[w + 2] && d[3 * w + 4] && !d[3]);
    }

    #[test]
    fn occlusion_parses_its_two_names() {
        assert_eq!(Occlusion::parse("fill").unwrap(), Occlusion::Fill);
        assert_eq!(Occlusion::parse(" None ").unwrap(), Occlusion::None);
        assert!(Occlusion::parse("fil").is_err());
    }
}
