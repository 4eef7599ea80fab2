//! The band around a mask's edge that the reference leaves out of training (its `mask_at_box` marks it
//! with 100): prepared once per image into the cache, and what the sampler draws from or skips.

use image::GrayImage;

/// The mask-edge band `dilate(mask) − erode(mask)` with a 5×5 kernel, row-major; OpenCV's borders (the
/// image edge neither erodes nor dilates).
pub fn edge_band(mask: &GrayImage) -> Vec<bool> {
    let (w, h) = (mask.width() as usize, mask.height() as usize);
    let fg: Vec<bool> = mask.pixels().map(|p| p[0] != 0).collect();
    // Separable 5×5 window: any/all over each row span, then over each column span of those.
    let window = |n: usize, i: usize| i.saturating_sub(2)..(i + 3).min(n);
    let mut any_row = vec![false; w * h];
    let mut all_row = vec![false; w * h];
    for y in 0..h {
        let row = &fg[y * w..(y + 1) * w];
        for x in 0..w {
            let span = &row[window(w, x)];
            any_row[y * w + x] = span.iter().any(|&f| f);
            all_row[y * w + x] = span.iter().all(|&f| f);
        }
    }
    let mut band = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let any = window(h, y).any(|yy| any_row[yy * w + x]);
            let all = window(h, y).all(|yy| all_row[yy * w + x]);
            band[y * w + x] = any && !all;
        }
    }
    band
}
