//! The report's contact sheet (`grid.png`): the ground truth and each method's image side by
//! side, scaled to one width, each with its label and its numbers written under it, so one
//! small picture shows a report at a glance (the README's picture is one).

use crate::image::{ColorImage, Rgba};

/// Width of one tile of the sheet in pixels: five tiles fit a 1280 px wide page.
pub const TILE_WIDTH_PX: usize = 256;
/// Glyph scale of the captions (the 8x8 font drawn at 1:1).
const GLYPH_PX: usize = 8;
/// Gap between tiles, and around the sheet, in pixels.
const GAP_PX: usize = 4;
/// Lines of caption under each tile.
const CAPTION_LINES: usize = 2;
/// Background of the sheet and the captions (premultiplied linear RGBA: a dark grey).
const BACKGROUND: Rgba = [0.01, 0.01, 0.01, 1.0];
/// Colour of the captions' text.
const INK: Rgba = [1.0, 1.0, 1.0, 1.0];

/// One tile: an image and the lines written under it (ASCII; others are shown as `?`, longer
/// lines are cut to the tile's width).
pub struct Tile<'a> {
    /// The image, any size: it is scaled to [`TILE_WIDTH_PX`] wide, its aspect kept.
    pub image: &'a ColorImage,
    /// The caption, one entry a line (at most two are drawn).
    pub caption: Vec<String>,
}

/// The sheet: every tile in one row, in order, each scaled to `tile_width_px` wide by an area
/// average (so no fine detail aliases), its caption under it.
pub fn contact_sheet(tiles: &[Tile], tile_width_px: usize) -> ColorImage {
    let tile_w = tile_width_px.max(GLYPH_PX);
    let tile_h = tiles
        .iter()
        .map(|t| scaled_height(t.image, tile_w))
        .max()
        .unwrap_or(1);
    let caption_h = CAPTION_LINES * (GLYPH_PX + 2);
    let width = GAP_PX + tiles.len().max(1) * (tile_w + GAP_PX);
    let height = GAP_PX + tile_h + caption_h + GAP_PX;
    let mut sheet = ColorImage::new(width, height, BACKGROUND);
    for (k, tile) in tiles.iter().enumerate() {
        let x0 = GAP_PX + k * (tile_w + GAP_PX);
        let scaled = area_scale(tile.image, tile_w, scaled_height(tile.image, tile_w));
        for y in 0..scaled.height() {
            for x in 0..scaled.width() {
                *sheet.get_mut(x0 + x, GAP_PX + y) = scaled.get(x, y);
            }
        }
        for (line, text) in tile.caption.iter().take(CAPTION_LINES).enumerate() {
            let y0 = GAP_PX + tile_h + 2 + line * (GLYPH_PX + 2);
            draw_text(&mut sheet, text, x0, y0, tile_w);
        }
    }
    sheet
}

/// The height of `image` scaled to `width` wide, its aspect kept (at least one pixel).
fn scaled_height(image: &ColorImage, width: usize) -> usize {
    let h = image.height() as f64 * width as f64 / image.width().max(1) as f64;
    (h.round() as usize).max(1)
}

/// `image` resampled to `width` x `height` by the area average of the source pixels each
/// output pixel covers (fractional pixels weighted by their covered part).
pub fn area_scale(image: &ColorImage, width: usize, height: usize) -> ColorImage {
    let sx = image.width() as f64 / width as f64;
    let sy = image.height() as f64 / height as f64;
    // Each output column's source pixels and weights, worked out once.
    let spans = |n_out: usize, scale: f64, n_in: usize| -> Vec<Vec<(usize, f64)>> {
        (0..n_out)
            .map(|o| {
                let a = o as f64 * scale;
                let b = ((o + 1) as f64 * scale).min(n_in as f64);
                let mut span = Vec::new();
                let mut i = a.floor() as usize;
                while (i as f64) < b && i < n_in {
                    let w = (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0);
                    if w > 0.0 {
                        span.push((i, w));
                    }
                    i += 1;
                }
                span
            })
            .collect()
    };
    let cols = spans(width, sx, image.width());
    let rows = spans(height, sy, image.height());
    let mut out = ColorImage::new(width, height, [0.0; 4]);
    for (y, row_span) in rows.iter().enumerate() {
        for (x, col_span) in cols.iter().enumerate() {
            let mut sum = [0.0f64; 4];
            let mut total = 0.0;
            for &(j, wy) in row_span {
                for &(i, wx) in col_span {
                    let p = image.get(i, j);
                    let w = wx * wy;
                    for c in 0..4 {
                        sum[c] += f64::from(p[c]) * w;
                    }
                    total += w;
                }
            }
            if total > 0.0 {
                *out.get_mut(x, y) = sum.map(|s| (s / total) as f32);
            }
        }
    }
    out
}

/// Writes `text` with its top-left corner at (`x0`, `y0`), cut to `max_width` pixels.
fn draw_text(sheet: &mut ColorImage, text: &str, x0: usize, y0: usize, max_width: usize) {
    for (k, ch) in text.chars().take(max_width / GLYPH_PX).enumerate() {
        let code = if ch.is_ascii() {
            ch as usize
        } else {
            '?' as usize
        };
        let glyph = font8x8::legacy::BASIC_LEGACY[code];
        for (row, byte) in glyph.iter().enumerate() {
            for col in 0..GLYPH_PX {
                // Bit 0 is the leftmost pixel of the row.
                let (x, y) = (x0 + k * GLYPH_PX + col, y0 + row);
                if byte >> col & 1 == 1 && x < sheet.width() && y < sheet.height() {
                    *sheet.get_mut(x, y) = INK;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_scale_keeps_a_constant_image_constant_and_averages_blocks() {
        let flat = ColorImage::new(7, 5, [0.25, 0.5, 1.0, 1.0]);
        let s = area_scale(&flat, 3, 2);
        for p in s.pixels() {
            for (a, b) in p.iter().zip([0.25, 0.5, 1.0, 1.0]) {
                assert!((a - b).abs() < 1e-6, "{p:?}");
            }
        }
        // A 4x2 image of two 2x2 blocks halves to their means.
        let mut two = ColorImage::new(4, 2, [0.0; 4]);
        for y in 0..2 {
            for x in 2..4 {
                *two.get_mut(x, y) = [1.0; 4];
            }
        }
        let h = area_scale(&two, 2, 1);
        assert_eq!(h.get(0, 0), [0.0; 4]);
        assert_eq!(h.get(1, 0), [1.0; 4]);
        // Three pixels to two: the middle one is shared half and half.
        let mut three = ColorImage::new(3, 1, [0.0; 4]);
        *three.get_mut(1, 0) = [1.0; 4];
        let t = area_scale(&three, 2, 1);
        assert!((t.get(0, 0)[0] - 1.0 / 3.0).abs() < 1e-6);
        assert!((t.get(1, 0)[0] - 1.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn sheet_holds_every_tile_and_its_caption() {
        let a = ColorImage::new(512, 256, [1.0, 0.0, 0.0, 1.0]);
        let b = ColorImage::new(512, 256, [0.0, 0.0, 1.0, 1.0]);
        let tiles = [
            Tile {
                image: &a,
                caption: vec!["truth".into(), "".into()],
            },
            Tile {
                image: &b,
                caption: vec!["m".into(), "30.0 dB".into()],
            },
        ];
        let sheet = contact_sheet(&tiles, 128);
        assert_eq!(sheet.width(), GAP_PX + 2 * (128 + GAP_PX));
        assert_eq!(sheet.height(), GAP_PX + 64 + CAPTION_LINES * 10 + GAP_PX);
        // Tile centres carry their images' colours.
        assert_eq!(sheet.get(GAP_PX + 64, GAP_PX + 32), [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(
            sheet.get(2 * GAP_PX + 128 + 64, GAP_PX + 32),
            [0.0, 0.0, 1.0, 1.0]
        );
        // Each caption line drew ink under its tile, and only there.
        let ink_in = |x0: usize, y0: usize| {
            (y0..y0 + GLYPH_PX)
                .flat_map(|y| (x0..x0 + 128).map(move |x| (x, y)))
                .filter(|&(x, y)| sheet.get(x, y) == INK)
                .count()
        };
        let caption_y = GAP_PX + 64 + 2;
        assert!(ink_in(GAP_PX, caption_y) > 0);
        assert_eq!(
            ink_in(GAP_PX, caption_y + GLYPH_PX + 2),
            0,
            "an empty line draws nothing"
        );
        assert!(ink_in(2 * GAP_PX + 128, caption_y + GLYPH_PX + 2) > 0);
    }
}
