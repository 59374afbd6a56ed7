//! Procedural textures shared by the built-in scenes, painted in linear light.
//!
//! A [`Canvas`] holds straight-alpha linear RGBA texels. Shapes are painted with supersampled
//! coverage (4x4 samples per texel) so edges are anti-aliased before the texture is mipmapped;
//! text comes from the public-domain 8x8 bitmap font of the `font8x8` crate, enlarged by
//! thresholding the bilinear interpolation of its bitmap, which rounds the staircase of the
//! glyphs into smooth diagonals.

use glam::Vec2;

use super::random::hash2;
use crate::image::{srgb_decode, ColorImage, Rgba};
use crate::scene::{FilterMode, Texture, TextureBinding, TextureSampler, UvTransform, WrapMode};

/// Samples per texel side when painting shapes (16 samples per texel).
const SUPERSAMPLES: usize = 4;

/// A linear-light colour from an sRGB design colour written as `0xRRGGBB`.
pub(crate) fn srgb(hex: u32) -> [f32; 3] {
    let channel = |shift: u32| srgb_decode(((hex >> shift) & 0xff) as f32 / 255.0);
    [channel(16), channel(8), channel(0)]
}

/// Linear interpolation between two colours.
pub(crate) fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    std::array::from_fn(|c| a[c] + (b[c] - a[c]) * t)
}

/// A colour multiplied by `k`.
pub(crate) fn scale(a: [f32; 3], k: f32) -> [f32; 3] {
    a.map(|c| c * k)
}

/// Hermite smoothstep of `x` between `e0` and `e1`.
pub(crate) fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A texture binding with the default trilinear sampler and the given wrap mode and UV scale.
pub(crate) fn binding(texture: usize, wrap: WrapMode, uv_scale: Vec2) -> TextureBinding {
    TextureBinding {
        texture,
        sampler: TextureSampler {
            mag_filter: FilterMode::Linear,
            min_filter: FilterMode::Linear,
            mip_filter: Some(FilterMode::Linear),
            wrap_u: wrap,
            wrap_v: wrap,
        },
        uv_transform: UvTransform {
            scale: uv_scale,
            ..UvTransform::default()
        },
    }
}

/// A straight-alpha linear RGBA image being painted.
#[derive(Clone, Debug)]
pub(crate) struct Canvas {
    width: usize,
    height: usize,
    texels: Vec<Rgba>,
}

impl Canvas {
    /// A canvas filled with `rgba`.
    pub(crate) fn new(width: usize, height: usize, rgba: Rgba) -> Self {
        Self {
            width,
            height,
            texels: vec![rgba; width * height],
        }
    }

    /// Texel (x, y).
    #[cfg(test)]
    pub(crate) fn get(&self, x: usize, y: usize) -> Rgba {
        self.texels[y * self.width + x]
    }

    /// Sets texel (x, y).
    pub(crate) fn set(&mut self, x: usize, y: usize, rgba: Rgba) {
        self.texels[y * self.width + x] = rgba;
    }

    /// Composites `rgb` with coverage `alpha` over texel (x, y) (Porter-Duff over, straight
    /// alpha).
    pub(crate) fn blend(&mut self, x: usize, y: usize, rgb: [f32; 3], alpha: f32) {
        let a = alpha.clamp(0.0, 1.0);
        if a <= 0.0 {
            return;
        }
        let d = &mut self.texels[y * self.width + x];
        let out_a = a + d[3] * (1.0 - a);
        for c in 0..3 {
            d[c] = (rgb[c] * a + d[c] * d[3] * (1.0 - a)) / out_a;
        }
        d[3] = out_a;
    }

    /// Fills the texel rectangle `[x0, x1) x [y0, y1)` (clipped to the canvas) with an opaque
    /// colour.
    pub(crate) fn fill_rect(&mut self, x0: usize, y0: usize, x1: usize, y1: usize, rgb: [f32; 3]) {
        for y in y0..y1.min(self.height) {
            for x in x0..x1.min(self.width) {
                self.set(x, y, [rgb[0], rgb[1], rgb[2], 1.0]);
            }
        }
    }

    /// A checkerboard of `cell`-texel squares over `[x0, x1) x [y0, y1)`, colour `a` in the
    /// top-left square.
    pub(crate) fn checker(
        &mut self,
        (x0, y0): (usize, usize),
        (x1, y1): (usize, usize),
        cell: usize,
        a: [f32; 3],
        b: [f32; 3],
    ) {
        for y in y0..y1.min(self.height) {
            for x in x0..x1.min(self.width) {
                let odd = ((x - x0) / cell + (y - y0) / cell) % 2 == 1;
                let c = if odd { b } else { a };
                self.set(x, y, [c[0], c[1], c[2], 1.0]);
            }
        }
    }

    /// Paints a shape over the texel box `[x0, x1) x [y0, y1)` (texel units, y down): `shade`
    /// returns the colour at a point inside the shape and `None` outside. Each texel gets the
    /// mean colour of its covered samples with the covered fraction as coverage.
    pub(crate) fn paint(
        &mut self,
        min: (f32, f32),
        max: (f32, f32),
        shade: impl Fn(f32, f32) -> Option<[f32; 3]>,
    ) {
        self.paint_with_opacity(min, max, 1.0, shade);
    }

    /// As [`Canvas::paint`], with the coverage multiplied by `opacity`.
    pub(crate) fn paint_with_opacity(
        &mut self,
        (x0, y0): (f32, f32),
        (x1, y1): (f32, f32),
        opacity: f32,
        shade: impl Fn(f32, f32) -> Option<[f32; 3]>,
    ) {
        let xa = x0.floor().max(0.0) as usize;
        let ya = y0.floor().max(0.0) as usize;
        let xb = (x1.ceil().max(0.0) as usize).min(self.width);
        let yb = (y1.ceil().max(0.0) as usize).min(self.height);
        let step = 1.0 / SUPERSAMPLES as f32;
        for y in ya..yb {
            for x in xa..xb {
                let mut sum = [0.0f32; 3];
                let mut hits = 0usize;
                for sy in 0..SUPERSAMPLES {
                    for sx in 0..SUPERSAMPLES {
                        let px = x as f32 + (sx as f32 + 0.5) * step;
                        let py = y as f32 + (sy as f32 + 0.5) * step;
                        if let Some(c) = shade(px, py) {
                            for k in 0..3 {
                                sum[k] += c[k];
                            }
                            hits += 1;
                        }
                    }
                }
                if hits > 0 {
                    let n = hits as f32;
                    let coverage = opacity * n / (SUPERSAMPLES * SUPERSAMPLES) as f32;
                    self.blend(x, y, sum.map(|s| s / n), coverage);
                }
            }
        }
    }

    /// Writes `text` (ASCII; other characters show as `?`) with its top-left corner at texel
    /// (x, y), each font pixel `scale` texels wide ([`text_width`] gives the width).
    pub(crate) fn text(&mut self, pos: (f32, f32), scale: f32, text: &str, rgb: [f32; 3]) {
        self.text_rgba(pos, scale, text, [rgb[0], rgb[1], rgb[2], 1.0]);
    }

    /// As [`Canvas::text`], with the ink's opacity in the alpha of `rgba`.
    pub(crate) fn text_rgba(&mut self, (x, y): (f32, f32), scale: f32, text: &str, rgba: Rgba) {
        let bitmap = TextBitmap::new(text);
        let (w, h) = (bitmap.width as f32 * scale, 8.0 * scale);
        let rgb = [rgba[0], rgba[1], rgba[2]];
        let (min, max) = ((x - 1.0, y - 1.0), (x + w + 1.0, y + h + 1.0));
        self.paint_with_opacity(min, max, rgba[3], |px, py| {
            let v = bitmap.bilinear((px - x) / scale - 0.5, (py - y) / scale - 0.5);
            (v >= 0.5).then_some(rgb)
        });
    }

    /// Writes `text` horizontally centred on column `cx`, top at row `y`.
    pub(crate) fn text_centred(&mut self, cx: f32, y: f32, scale: f32, text: &str, rgb: [f32; 3]) {
        let w = text_width(text, scale);
        self.text((cx - 0.5 * w, y), scale, text, rgb);
    }

    /// A Siemens star: `spokes` dark sectors of colour `ink` inside the circle of radius `r`
    /// around (cx, cy), a classic target for judging focus.
    pub(crate) fn siemens_star(
        &mut self,
        (cx, cy): (f32, f32),
        r: f32,
        spokes: u32,
        ink: [f32; 3],
    ) {
        let sectors = 2.0 * spokes as f32 / std::f32::consts::TAU;
        self.paint((cx - r, cy - r), (cx + r, cy + r), |px, py| {
            let (dx, dy) = (px - cx, py - cy);
            if dx * dx + dy * dy > r * r {
                return None;
            }
            let sector = ((dy.atan2(dx) + std::f32::consts::PI) * sectors) as u32;
            sector.is_multiple_of(2).then_some(ink)
        });
    }

    /// A filled disc of radius `r` around (cx, cy).
    pub(crate) fn disc(&mut self, (cx, cy): (f32, f32), r: f32, rgb: [f32; 3]) {
        self.paint((cx - r, cy - r), (cx + r, cy + r), |px, py| {
            let (dx, dy) = (px - cx, py - cy);
            (dx * dx + dy * dy <= r * r).then_some(rgb)
        });
    }

    /// Gives fully transparent texels the colour of their covered neighbours (and the mean
    /// covered colour where none is near), so that bilinear filtering at the edge of a cut-out
    /// does not pull in black.
    pub(crate) fn bleed_into_transparent(&mut self) {
        for _ in 0..3 {
            let before = self.texels.clone();
            for y in 0..self.height {
                for x in 0..self.width {
                    if before[y * self.width + x][3] > 0.0 {
                        continue;
                    }
                    let mut sum = [0.0f32; 4];
                    for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        if nx < 0 || ny < 0 || nx >= self.width as i64 || ny >= self.height as i64 {
                            continue;
                        }
                        let n = before[ny as usize * self.width + nx as usize];
                        // Weight by alpha, and let already bled texels (alpha 0, colour set)
                        // count a little so the fill spreads.
                        let w = n[3].max(if n[0] + n[1] + n[2] > 0.0 { 0.01 } else { 0.0 });
                        for c in 0..3 {
                            sum[c] += n[c] * w;
                        }
                        sum[3] += w;
                    }
                    if sum[3] > 0.0 {
                        let t = &mut self.texels[y * self.width + x];
                        for c in 0..3 {
                            t[c] = sum[c] / sum[3];
                        }
                    }
                }
            }
        }
        let (mut mean, mut weight) = ([0.0f32; 3], 0.0f32);
        for t in &self.texels {
            for c in 0..3 {
                mean[c] += t[c] * t[3];
            }
            weight += t[3];
        }
        if weight > 0.0 {
            let mean = mean.map(|m| m / weight);
            for t in &mut self.texels {
                if t[3] <= 0.0 && t[0] + t[1] + t[2] <= 0.0 {
                    *t = [mean[0], mean[1], mean[2], 0.0];
                }
            }
        }
    }

    /// The painted image.
    pub(crate) fn into_image(self) -> ColorImage {
        ColorImage::from_vec(self.width, self.height, self.texels)
            .expect("a canvas holds width * height texels")
    }

    /// The painted texture, with its mip chain.
    pub(crate) fn into_texture(self) -> Texture {
        Texture::new(self.into_image())
    }
}

/// Width in texels of `text` written at `scale`.
pub(crate) fn text_width(text: &str, scale: f32) -> f32 {
    8.0 * text.chars().count() as f32 * scale
}

/// A line of text as a 1-bit image, 8 pixels per character.
struct TextBitmap {
    width: usize,
    rows: [Vec<bool>; 8],
}

impl TextBitmap {
    fn new(text: &str) -> Self {
        let chars: Vec<char> = text.chars().collect();
        let width = 8 * chars.len();
        let rows = std::array::from_fn(|row| {
            let mut bits = Vec::with_capacity(width);
            for &ch in &chars {
                let code = if ch.is_ascii() {
                    ch as usize
                } else {
                    '?' as usize
                };
                // One byte per row, top row first; bit 0 is the leftmost pixel.
                let byte = font8x8::legacy::BASIC_LEGACY[code][row];
                bits.extend((0..8).map(|col| byte >> col & 1 == 1));
            }
            bits
        });
        Self { width, rows }
    }

    fn pixel(&self, x: i64, y: i64) -> f32 {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= 8 {
            return 0.0;
        }
        f32::from(u8::from(self.rows[y as usize][x as usize]))
    }

    /// Bilinear interpolation of the bitmap at (x, y), pixel centres at integer coordinates.
    fn bilinear(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (tx, ty) = (x - x0, y - y0);
        let (ix, iy) = (x0 as i64, y0 as i64);
        let top = self.pixel(ix, iy) * (1.0 - tx) + self.pixel(ix + 1, iy) * tx;
        let bottom = self.pixel(ix, iy + 1) * (1.0 - tx) + self.pixel(ix + 1, iy + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// Value noise in [0, 1) at (u, v), on a lattice of `cells` cells per unit that wraps at 1 in
/// both directions, so textures made of it tile.
pub(crate) fn value_noise(u: f32, v: f32, cells: i32, seed: u64) -> f32 {
    let (x, y) = (u * cells as f32, v * cells as f32);
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (smoothstep(0.0, 1.0, x - x0), smoothstep(0.0, 1.0, y - y0));
    let (ix, iy) = (x0 as i32, y0 as i32);
    let h = |dx: i32, dy: i32| {
        hash2(
            (ix + dx).rem_euclid(cells),
            (iy + dy).rem_euclid(cells),
            seed,
        )
    };
    let top = h(0, 0) + (h(1, 0) - h(0, 0)) * tx;
    let bottom = h(0, 1) + (h(1, 1) - h(0, 1)) * tx;
    top + (bottom - top) * ty
}

/// Fractal sum of `octaves` octaves of [`value_noise`], starting at `cells` cells per unit,
/// normalised to [0, 1); tiles with period 1.
pub(crate) fn fbm(u: f32, v: f32, cells: i32, octaves: u32, seed: u64) -> f32 {
    let (mut sum, mut norm, mut amplitude) = (0.0, 0.0, 1.0);
    for k in 0..octaves {
        sum += amplitude * value_noise(u, v, cells << k, seed.wrapping_add(k as u64));
        norm += amplitude;
        amplitude *= 0.5;
    }
    sum / norm
}

/// A 1-pixel-tall colour ramp through `stops` (evenly spaced), for surfaces whose shading is
/// baked into their `u` coordinate.
pub(crate) fn ramp_texture(stops: &[[f32; 3]]) -> Texture {
    let width = 256;
    let mut canvas = Canvas::new(width, 1, [0.0, 0.0, 0.0, 1.0]);
    let segments = (stops.len() - 1) as f32;
    for x in 0..width {
        let s = (x as f32 + 0.5) / width as f32 * segments;
        let i = (s.floor() as usize).min(stops.len() - 2);
        let c = mix(stops[i], stops[i + 1], s - i as f32);
        canvas.set(x, 0, [c[0], c[1], c[2], 1.0]);
    }
    canvas.into_texture()
}

/// The text and colours of a test chart (see [`chart_texture`]).
pub(crate) struct Chart<'a> {
    /// Size in texels.
    pub width: usize,
    /// Size in texels.
    pub height: usize,
    /// Large title line.
    pub title: &'a str,
    /// Medium line under the title, in the accent colour.
    pub subtitle: &'a str,
    /// Small line at the bottom.
    pub caption: &'a str,
    /// Background.
    pub paper: [f32; 3],
    /// Text, frame and dark squares.
    pub ink: [f32; 3],
    /// Subtitle colour.
    pub accent: [f32; 3],
    /// Draw a Siemens star right of the checkerboard.
    pub star: bool,
}

/// A focus test chart: a thin frame, a large title, a subtitle, a checkerboard (with a Siemens
/// star beside it) and a line of small text at the bottom. Sizes are proportional to the
/// height, so the same layout serves a poster and a card.
pub(crate) fn chart_texture(chart: &Chart) -> Texture {
    let (w, h) = (chart.width as f32, chart.height as f32);
    let mut canvas = Canvas::new(chart.width, chart.height, {
        let p = chart.paper;
        [p[0], p[1], p[2], 1.0]
    });
    let margin = (0.045 * h).round();

    // Frame line inside the edge.
    let inset = (0.4 * margin) as usize;
    let line = ((0.008 * h).round() as usize).max(2);
    let (iw, ih) = (chart.width - inset, chart.height - inset);
    canvas.fill_rect(inset, inset, iw, inset + line, chart.ink);
    canvas.fill_rect(inset, ih - line, iw, ih, chart.ink);
    canvas.fill_rect(inset, inset, inset + line, ih, chart.ink);
    canvas.fill_rect(iw - line, inset, iw, ih, chart.ink);

    // Title, as large as fits in 70% of the width and 16% of the height.
    let title_len = chart.title.chars().count().max(1) as f32;
    let title_scale = (0.7 * w / (8.0 * title_len))
        .min(0.16 * h / 8.0)
        .floor()
        .max(1.0);
    let title_y = 1.6 * margin;
    canvas.text_centred(0.5 * w, title_y, title_scale, chart.title, chart.ink);

    let sub_scale = (0.042 * h / 8.0).round().max(1.0);
    let sub_y = title_y + 8.0 * title_scale + 0.6 * margin;
    canvas.text_centred(0.5 * w, sub_y, sub_scale, chart.subtitle, chart.accent);

    let cap_scale = (0.028 * h / 8.0).round().max(1.0);
    let cap_y = h - 1.5 * margin - 8.0 * cap_scale;
    canvas.text_centred(0.5 * w, cap_y, cap_scale, chart.caption, chart.ink);

    // Checkerboard (and star) between the subtitle and the caption.
    let top = sub_y + 8.0 * sub_scale + 0.9 * margin;
    let bottom = cap_y - 0.9 * margin;
    let rows = 8usize;
    let cell = (((bottom - top) / rows as f32).floor() as usize).max(1);
    let board_h = cell * rows;
    let y0 = (top + 0.5 * (bottom - top - board_h as f32)).round() as usize;
    let inner_w = w - 3.0 * margin;
    let board_w_max = if chart.star { 0.58 * inner_w } else { inner_w };
    let cols = ((board_w_max / cell as f32).floor() as usize).max(1);
    let board_w = cols * cell;
    let x0 = if chart.star {
        (1.5 * margin) as usize
    } else {
        ((w - board_w as f32) * 0.5).round() as usize
    };
    canvas.checker(
        (x0, y0),
        (x0 + board_w, y0 + board_h),
        cell,
        chart.ink,
        chart.paper,
    );
    if chart.star {
        let left = (x0 + board_w) as f32 + margin;
        let right = w - 1.5 * margin;
        let r = (0.5 * (right - left)).min(0.5 * board_h as f32);
        let centre = (0.5 * (left + right), y0 as f32 + 0.5 * board_h as f32);
        canvas.siemens_star(centre, r, 18, chart.ink);
    }
    canvas.into_texture()
}

/// A tileable brick wall, one texture repeat per `courses` courses of `bricks_per_course`
/// bricks (running bond: every other course shifted by half a brick). Brick colours vary
/// around `brick` with noise; joints are `mortar`.
pub(crate) fn brick_texture(
    size: usize,
    (bricks_per_course, courses): (usize, usize),
    brick: [f32; 3],
    mortar: [f32; 3],
    seed: u64,
) -> Texture {
    let mut canvas = Canvas::new(size, size, [0.0, 0.0, 0.0, 1.0]);
    let course_h = size as f32 / courses as f32;
    let brick_w = size as f32 / bricks_per_course as f32;
    let joint = (0.08 * course_h).max(1.0);
    for y in 0..size {
        for x in 0..size {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let course = (py / course_h) as usize;
            let shift = if course % 2 == 1 { 0.5 * brick_w } else { 0.0 };
            let bx = (px + shift).rem_euclid(size as f32);
            let index = (bx / brick_w) as usize;
            let (fx, fy) = (bx - index as f32 * brick_w, py - course as f32 * course_h);
            let in_joint = fx < joint || fy < joint;
            let (u, v) = (px / size as f32, py / size as f32);
            let grain = fbm(u, v, 16, 4, seed);
            let c = if in_joint {
                scale(mortar, 0.85 + 0.3 * grain)
            } else {
                let tone = hash2(index as i32, course as i32, seed ^ 0xb1c5);
                let tint = hash2(index as i32, course as i32, seed ^ 0x7a3e);
                let base = mix(
                    brick,
                    mix(brick, [brick[1], brick[1], brick[0]], 0.4),
                    tint * 0.5,
                );
                scale(base, 0.7 + 0.45 * tone + 0.25 * (grain - 0.5))
            };
            canvas.set(x, y, [c[0], c[1], c[2], 1.0]);
        }
    }
    canvas.into_texture()
}

/// Tileable square floor tiles (`tiles` x `tiles` per texture repeat) in two alternating tones
/// with mottled noise and thin dark joints.
pub(crate) fn tile_texture(
    size: usize,
    tiles: usize,
    (a, b): ([f32; 3], [f32; 3]),
    joint_rgb: [f32; 3],
    seed: u64,
) -> Texture {
    let mut canvas = Canvas::new(size, size, [0.0, 0.0, 0.0, 1.0]);
    let tile = size as f32 / tiles as f32;
    let joint = (0.025 * tile).max(1.0);
    for y in 0..size {
        for x in 0..size {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let (tx, ty) = ((px / tile) as usize, (py / tile) as usize);
            let (fx, fy) = (px - tx as f32 * tile, py - ty as f32 * tile);
            let (u, v) = (px / size as f32, py / size as f32);
            let mottle = fbm(u, v, 8, 5, seed);
            let c = if fx < joint || fy < joint {
                joint_rgb
            } else {
                let base = if (tx + ty) % 2 == 0 { a } else { b };
                let tone = hash2(tx as i32, ty as i32, seed);
                scale(base, 0.85 + 0.15 * tone + 0.35 * (mottle - 0.5))
            };
            canvas.set(x, y, [c[0], c[1], c[2], 1.0]);
        }
    }
    canvas.into_texture()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn font_bit_zero_is_the_leftmost_pixel() {
        // 'L' has its vertical stroke on the left: the first column of its top rows is set.
        let l = TextBitmap::new("L");
        assert_eq!(l.pixel(0, 0) + l.pixel(1, 0), 2.0, "{:?}", l.rows[0]);
        assert_eq!(l.pixel(6, 0), 0.0);
        // Its foot runs to the right on the bottom row of ink.
        assert!(l.rows[6].iter().filter(|&&b| b).count() >= 6);
    }

    #[test]
    fn text_is_painted_inside_its_box_only() {
        let mut c = Canvas::new(100, 40, [1.0, 1.0, 1.0, 1.0]);
        c.text((10.0, 8.0), 2.0, "HI", [0.0, 0.0, 0.0]);
        let inked = |x: usize, y: usize| c.get(x, y)[0] < 0.5;
        assert!((0..100).any(|x| (8..24).any(|y| inked(x, y))));
        assert!((0..100).all(|x| !inked(x, 2) && !inked(x, 30)));
        assert!((0..40).all(|y| !inked(5, y) && !inked(50, y)));
    }

    #[test]
    fn noise_tiles_with_period_one() {
        for i in 0..10 {
            let v = i as f32 * 0.1;
            let a = fbm(0.0, v, 8, 3, 5);
            let b = fbm(1.0, v, 8, 3, 5);
            assert!((a - b).abs() < 1e-5);
            assert!((0.0..1.0).contains(&a));
        }
    }

    #[test]
    fn bleeding_keeps_alpha_and_colours_transparent_texels() {
        let mut c = Canvas::new(8, 8, [0.0; 4]);
        c.fill_rect(2, 2, 4, 4, [0.2, 0.6, 0.1]);
        c.bleed_into_transparent();
        let t = c.get(4, 3);
        assert_eq!(t[3], 0.0);
        assert!((t[1] - 0.6).abs() < 1e-5);
        assert!(c.get(7, 7)[1] > 0.5);
        assert_eq!(c.get(2, 2), [0.2, 0.6, 0.1, 1.0]);
    }
}
