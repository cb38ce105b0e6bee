//! A contact sheet: several images of one size side by side in a grid, each
//! under its name, as one planar RGB image (for the main job's picture).
//!
//! Names are drawn with a built-in 3x5 pixel font (upper case, digits, `-`,
//! `.` and space; anything else is left blank), so no font file is needed.

/// Glyph rows, 3 bits each (left pixel in the high bit), top row first.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        'A' => [0b010, 0b101, 0b111, 0b101, 0b101],
        'B' => [0b110, 0b101, 0b110, 0b101, 0b110],
        'C' => [0b011, 0b100, 0b100, 0b100, 0b011],
        'D' => [0b110, 0b101, 0b101, 0b101, 0b110],
        'E' => [0b111, 0b100, 0b110, 0b100, 0b111],
        'F' => [0b111, 0b100, 0b110, 0b100, 0b100],
        'G' => [0b011, 0b100, 0b101, 0b101, 0b011],
        'H' => [0b101, 0b101, 0b111, 0b101, 0b101],
        'I' => [0b111, 0b010, 0b010, 0b010, 0b111],
        'J' => [0b001, 0b001, 0b001, 0b101, 0b010],
        'K' => [0b101, 0b101, 0b110, 0b101, 0b101],
        'L' => [0b100, 0b100, 0b100, 0b100, 0b111],
        'M' => [0b101, 0b111, 0b111, 0b101, 0b101],
        'N' => [0b110, 0b101, 0b101, 0b101, 0b101],
        'O' => [0b010, 0b101, 0b101, 0b101, 0b010],
        'P' => [0b110, 0b101, 0b110, 0b100, 0b100],
        'Q' => [0b010, 0b101, 0b101, 0b110, 0b011],
        'R' => [0b110, 0b101, 0b110, 0b101, 0b101],
        'S' => [0b011, 0b100, 0b010, 0b001, 0b110],
        'T' => [0b111, 0b010, 0b010, 0b010, 0b010],
        'U' => [0b101, 0b101, 0b101, 0b101, 0b111],
        'V' => [0b101, 0b101, 0b101, 0b101, 0b010],
        'W' => [0b101, 0b101, 0b111, 0b111, 0b101],
        'X' => [0b101, 0b101, 0b010, 0b101, 0b101],
        'Y' => [0b101, 0b101, 0b010, 0b010, 0b010],
        'Z' => [0b111, 0b001, 0b010, 0b100, 0b111],
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b110, 0b001, 0b010, 0b100, 0b111],
        '3' => [0b110, 0b001, 0b010, 0b001, 0b110],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b110, 0b001, 0b110],
        '6' => [0b011, 0b100, 0b110, 0b101, 0b010],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b010, 0b101, 0b010, 0b101, 0b010],
        '9' => [0b010, 0b101, 0b011, 0b001, 0b110],
        '-' => [0, 0, 0b111, 0, 0],
        '.' => [0, 0, 0, 0, 0b010],
        _ => [0; 5],
    }
}

/// Pixels between tiles and around the sheet.
const GAP: usize = 6;
/// Font pixels are drawn as `FONT_SCALE x FONT_SCALE` squares.
const FONT_SCALE: usize = 2;
/// Height of the strip above each tile that holds its name.
const LABEL: usize = 5 * FONT_SCALE + 6;
/// Background and text values (linear; the preview's gamma makes them grey and white).
const BACKGROUND: f32 = 0.02;
const TEXT: f32 = 1.0;

/// A contact sheet of `tiles` (each `(name, three planes of w x h)`),
/// `columns` per row, every tile enlarged `zoom` times (nearest neighbour).
/// Returns the sheet's three planes and its width and height.
///
/// # Panics
/// When a tile does not hold `3 * w * h` values or `columns` or `zoom` is 0.
pub fn contact_sheet(
    tiles: &[(&str, &[f32])],
    w: usize,
    h: usize,
    columns: usize,
    zoom: usize,
) -> (Vec<f32>, usize, usize) {
    assert!(columns > 0 && zoom > 0, "a sheet needs at least one column and a zoom of 1");
    let (tw, th) = (w * zoom, h * zoom);
    let rows = tiles.len().div_ceil(columns);
    let sw = GAP + columns * (tw + GAP);
    let sh = GAP + rows * (LABEL + th + GAP);
    let plane = sw * sh;
    let mut sheet = vec![BACKGROUND; 3 * plane];
    for (i, (name, rgb)) in tiles.iter().enumerate() {
        assert_eq!(rgb.len(), 3 * w * h, "tile '{name}' is not 3 planes of {w}x{h}");
        let x0 = GAP + (i % columns) * (tw + GAP);
        let y0 = GAP + (i / columns) * (LABEL + th + GAP);
        // The name, one font pixel of space between glyphs, clipped to the tile.
        for (n, c) in name.chars().enumerate() {
            for (row, bits) in glyph(c).iter().enumerate() {
                for col in 0..3 {
                    if bits & (0b100 >> col) == 0 {
                        continue;
                    }
                    for sy in 0..FONT_SCALE {
                        for sx in 0..FONT_SCALE {
                            let x = n * 4 * FONT_SCALE + col * FONT_SCALE + sx;
                            let y = y0 + 2 + row * FONT_SCALE + sy;
                            if x < tw {
                                for ch in 0..3 {
                                    sheet[ch * plane + y * sw + x0 + x] = TEXT;
                                }
                            }
                        }
                    }
                }
            }
        }
        for ch in 0..3 {
            for y in 0..th {
                let src = &rgb[ch * w * h + (y / zoom) * w..][..w];
                let dst = &mut sheet[ch * plane + (y0 + LABEL + y) * sw + x0..][..tw];
                for (x, d) in dst.iter_mut().enumerate() {
                    *d = src[x / zoom];
                }
            }
        }
    }
    (sheet, sw, sh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_land_in_their_cells_under_their_names() {
        let (w, h) = (4, 3);
        let a: Vec<f32> = (0..3 * w * h).map(|i| i as f32).collect();
        let b = vec![0.5f32; 3 * w * h];
        let (s, sw, sh) = contact_sheet(&[("a", &a), ("b", &b), ("c", &b)], w, h, 2, 2);
        assert_eq!((sw, sh), (GAP + 2 * (8 + GAP), GAP + 2 * (LABEL + 6 + GAP)));
        // Tile a's pixel (1, 2) of plane 1, zoomed: 2x2 output pixels.
        let plane = sw * sh;
        let v = a[w * h + 2 * w + 1];
        for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            assert_eq!(s[plane + (GAP + LABEL + 4 + dy) * sw + GAP + 2 + dx], v);
        }
        // Tile c starts the second row; the label strip of a has lit pixels.
        assert_eq!(s[(GAP + LABEL + 6 + GAP + LABEL) * sw + GAP], 0.5);
        assert!(s[..GAP * sw + LABEL * sw].contains(&TEXT));
    }
}
