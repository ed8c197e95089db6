//! Efros-Freeman image quilting: patches are laid out with a fixed overlap and each new
//! patch is joined to what is already placed along the minimum-error boundary cut
//! (vertical for a left neighbour, horizontal for a top one, both for an L-shaped
//! overlap).

/// Minimum-cost top-to-bottom path through an error image `err` (`w` wide, `h` tall),
/// moving at most one column per row. Returns the path column per row and its cost.
pub fn min_vertical_cut(err: &[f32], w: usize, h: usize) -> (Vec<usize>, f64) {
    if w == 0 || h == 0 {
        return (vec![0; h], 0.0);
    }
    let mut cost: Vec<f64> = err[..w].iter().map(|&e| e as f64).collect();
    let mut from = vec![0u32; w * h];
    let mut next = vec![0.0f64; w];
    for y in 1..h {
        for x in 0..w {
            let mut best = x;
            if x > 0 && cost[x - 1] < cost[best] {
                best = x - 1;
            }
            if x + 1 < w && cost[x + 1] < cost[best] {
                best = x + 1;
            }
            next[x] = cost[best] + err[y * w + x] as f64;
            from[y * w + x] = best as u32;
        }
        std::mem::swap(&mut cost, &mut next);
    }
    let mut x = (0..w)
        .min_by(|&a, &b| cost[a].total_cmp(&cost[b]))
        .unwrap_or(0);
    let total = cost[x];
    let mut path = vec![0usize; h];
    for y in (0..h).rev() {
        path[y] = x;
        x = from[y * w + x] as usize;
    }
    (path, total)
}

/// Places `patch` (`p x p`) at (`x0`, `y0`) into `out` (`ow` wide, holding rows
/// `y0 ..` of the output starting at `out_y0`), cutting against already placed content
/// on the left (`left`) and top (`top`) overlaps of width `o`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn place_patch(
    out: &mut [f32],
    ow: usize,
    out_y0: usize,
    patch: &[f32],
    p: usize,
    x0: usize,
    y0: usize,
    o: usize,
    left: bool,
    top: bool,
) {
    let rows_avail = out.len() / ow + out_y0;
    let pw = p.min(ow - x0);
    let ph = p.min(rows_avail - y0);
    let idx = |x: usize, y: usize| (y0 + y - out_y0) * ow + x0 + x;
    // take_new[y * pw + x]: the new patch wins at this pixel.
    let mut take_new = vec![true; pw * ph];
    if left {
        let ow_ = o.min(pw);
        let mut err = vec![0.0f32; ow_ * ph];
        for y in 0..ph {
            for x in 0..ow_ {
                let d = out[idx(x, y)] - patch[y * p + x];
                err[y * ow_ + x] = d * d;
            }
        }
        let (cut, _) = min_vertical_cut(&err, ow_, ph);
        for (y, &c) in cut.iter().enumerate() {
            take_new[y * pw..y * pw + c].fill(false);
        }
    }
    if top {
        let oh = o.min(ph);
        // Transposed error: columns become rows so the same vertical cut applies.
        let mut err = vec![0.0f32; oh * pw];
        for y in 0..oh {
            for x in 0..pw {
                let d = out[idx(x, y)] - patch[y * p + x];
                err[x * oh + y] = d * d;
            }
        }
        let (cut, _) = min_vertical_cut(&err, oh, pw);
        for (x, &c) in cut.iter().enumerate() {
            for y in 0..c {
                take_new[y * pw + x] = false;
            }
        }
    }
    for y in 0..ph {
        for x in 0..pw {
            if take_new[y * pw + x] {
                out[idx(x, y)] = patch[y * p + x];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cut_follows_zero_valley() {
        let (w, h) = (7, 9);
        let valley = |y: usize| 2 + [0, 1, 2, 1][y % 4];
        let mut err = vec![1.0f32; w * h];
        for y in 0..h {
            err[y * w + valley(y)] = 0.0;
        }
        let (path, cost) = min_vertical_cut(&err, w, h);
        assert_eq!(cost, 0.0);
        for (y, &x) in path.iter().enumerate() {
            assert_eq!(x, valley(y));
        }
    }

    /// L-shaped overlap: old content matches the new patch exactly along row 5 of the
    /// top overlap and column 6 of the left overlap, so both cuts follow those lines and
    /// the new patch wins only right of column 6 and below row 5.
    #[test]
    fn l_shaped_cut_follows_valleys() {
        let (p, o, ow) = (16usize, 8usize, 24usize);
        let (x0, y0) = (8usize, 8usize);
        let patch: Vec<f32> = (0..p * p).map(|i| 100.0 + i as f32).collect();
        let mut out = vec![0.0f32; ow * ow];
        for y in 0..p {
            for x in 0..p {
                let on_valley = (y < o && y == 5) || (x < o && x == 6);
                out[(y0 + y) * ow + x0 + x] = if on_valley { patch[y * p + x] } else { -1.0 };
            }
        }
        let before = out.clone();
        place_patch(&mut out, ow, 0, &patch, p, x0, y0, o, true, true);
        for y in 0..p {
            for x in 0..p {
                let v = out[(y0 + y) * ow + x0 + x];
                let new = x >= 6 && y >= 5;
                let want = if new {
                    patch[y * p + x]
                } else {
                    before[(y0 + y) * ow + x0 + x]
                };
                assert_eq!(v, want, "pixel {x},{y}");
            }
        }
    }
}
