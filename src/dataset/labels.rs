//! Label formats standard tools read: COCO run-length encoding (pycocotools' compressed
//! string form) and polygons traced from instance masks (for LabelMe).

use std::collections::HashMap;

/// COCO RLE of a binary mask given row-major (`mask[y * width + x]`): runs are counted in
/// column-major order, starting with a (possibly empty) run of zeros.
pub fn rle_counts(mask: &[bool], width: usize, height: usize) -> Vec<u32> {
    let mut counts = Vec::new();
    let mut current = false;
    let mut run = 0u32;
    for x in 0..width {
        for y in 0..height {
            let v = mask[y * width + x];
            if v != current {
                counts.push(run);
                run = 0;
                current = v;
            }
            run += 1;
        }
    }
    counts.push(run);
    counts
}

/// pycocotools' `rleToString`: LEB128-like, 5 bits per char offset by 48, with counts
/// after the second stored as differences to the count two before.
pub fn rle_encode_string(counts: &[u32]) -> String {
    let mut s = String::new();
    for (i, &c) in counts.iter().enumerate() {
        let mut x = c as i64;
        if i > 2 {
            x -= counts[i - 2] as i64;
        }
        loop {
            let mut ch = (x & 0x1f) as u8;
            x >>= 5;
            let more = if ch & 0x10 != 0 { x != -1 } else { x != 0 };
            if more {
                ch |= 0x20;
            }
            s.push((ch + 48) as char);
            if !more {
                break;
            }
        }
    }
    s
}

/// Inverse of [`rle_encode_string`] (pycocotools' `rleFrString`).
pub fn rle_decode_string(s: &str) -> Option<Vec<u32>> {
    let bytes = s.as_bytes();
    let mut counts: Vec<i64> = Vec::new();
    let mut p = 0;
    while p < bytes.len() {
        let mut x: i64 = 0;
        let mut k = 0;
        loop {
            let c = (*bytes.get(p)? as i64) - 48;
            if !(0..64).contains(&c) || k > 12 {
                return None;
            }
            x |= (c & 0x1f) << (5 * k);
            p += 1;
            k += 1;
            if c & 0x20 == 0 {
                if c & 0x10 != 0 {
                    x |= -1i64 << (5 * k);
                }
                break;
            }
        }
        if counts.len() > 2 {
            x += counts[counts.len() - 2];
        }
        counts.push(x);
    }
    counts.into_iter().map(|c| u32::try_from(c).ok()).collect()
}

/// Expands column-major RLE counts back to a row-major mask.
pub fn rle_to_mask(counts: &[u32], width: usize, height: usize) -> Option<Vec<bool>> {
    let mut mask = vec![false; width * height];
    let mut k = 0usize;
    let mut v = false;
    for &c in counts {
        for _ in 0..c {
            if k >= width * height {
                return None;
            }
            let (x, y) = (k / height, k % height);
            mask[y * width + x] = v;
            k += 1;
        }
        v = !v;
    }
    (k == width * height).then_some(mask)
}

/// Bounding box [x, y, w, h] of a mask, COCO style.
pub fn bbox(mask: &[bool], width: usize) -> Option<[usize; 4]> {
    let mut b: Option<[usize; 4]> = None;
    for (p, _) in mask.iter().enumerate().filter(|(_, v)| **v) {
        let (x, y) = (p % width, p / width);
        let e = b.get_or_insert([x, y, x, y]);
        e[0] = e[0].min(x);
        e[1] = e[1].min(y);
        e[2] = e[2].max(x);
        e[3] = e[3].max(y);
    }
    b.map(|[x0, y0, x1, y1]| [x0, y0, x1 - x0 + 1, y1 - y0 + 1])
}

/// Outer boundary polygons of the 4-connected components of `mask`, one per component,
/// in LabelMe's convention (pixel (x, y) has its centre at (x, y)). The polygon runs
/// through the centres of the component's boundary pixels (integer vertices; a part one
/// pixel wide becomes a line there), so LabelMe's own `shape_to_mask` (Pillow: vertices
/// rounded to integers, polygon filled and its 1-pixel outline drawn, i.e. every pixel
/// whose centre lies inside or on the polygon) gives back exactly the component, holes
/// included as filled (LabelMe polygons have no holes).
pub fn trace_polygons(mask: &[bool], width: usize, height: usize) -> Vec<Vec<[f64; 2]>> {
    let inside = |x: i64, y: i64| {
        x >= 0
            && y >= 0
            && x < width as i64
            && y < height as i64
            && mask[y as usize * width + x as usize]
    };
    let mut label = vec![0u32; width * height];
    let mut polys = Vec::new();
    let mut next = 0u32;
    for start in 0..width * height {
        if !mask[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        // Flood fill the 4-connected component.
        let mut comp = Vec::new();
        let mut stack = vec![start];
        label[start] = next;
        while let Some(p) = stack.pop() {
            comp.push(p);
            let (x, y) = ((p % width) as i64, (p / width) as i64);
            for (nx, ny) in [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)] {
                if inside(nx, ny) {
                    let q = ny as usize * width + nx as usize;
                    if label[q] == 0 {
                        label[q] = next;
                        stack.push(q);
                    }
                }
            }
        }
        let id = next;
        let in_comp = |x: i64, y: i64| inside(x, y) && label[y as usize * width + x as usize] == id;
        // Directed pixel edges, clockwise on screen (y down) around each pixel; edges
        // between two pixels of the component are never emitted.
        let mut out: HashMap<(i64, i64), Vec<(i64, i64)>> = HashMap::new();
        for &p in &comp {
            let (x, y) = ((p % width) as i64, (p / width) as i64);
            if !in_comp(x, y - 1) {
                out.entry((x, y)).or_default().push((x + 1, y));
            }
            if !in_comp(x + 1, y) {
                out.entry((x + 1, y)).or_default().push((x + 1, y + 1));
            }
            if !in_comp(x, y + 1) {
                out.entry((x + 1, y + 1)).or_default().push((x, y + 1));
            }
            if !in_comp(x - 1, y) {
                out.entry((x, y + 1)).or_default().push((x, y));
            }
        }
        let mut loops: Vec<Vec<(i64, i64)>> = Vec::new();
        let mut starts: Vec<(i64, i64)> = out.keys().copied().collect();
        starts.sort();
        for s in starts {
            while out.get(&s).is_some_and(|v| !v.is_empty()) {
                let mut lp = vec![s];
                let mut prev_dir: Option<(i64, i64)> = None;
                let mut cur = s;
                while let Some(cands) = out.get_mut(&cur) {
                    if cands.is_empty() {
                        break;
                    }
                    // At a pinch vertex (two diagonal pixels) turn left on screen, which
                    // keeps both pixels in one loop that touches itself: its pixel-centre
                    // fill is still exact, and the component stays one polygon.
                    let k = match prev_dir {
                        Some(d) if cands.len() > 1 => {
                            let left = (d.1, -d.0);
                            cands
                                .iter()
                                .position(|&n| (n.0 - cur.0, n.1 - cur.1) == left)
                                .unwrap_or(0)
                        }
                        _ => 0,
                    };
                    let n = cands.swap_remove(k);
                    prev_dir = Some((n.0 - cur.0, n.1 - cur.1));
                    cur = n;
                    if cur == s && out.get(&s).is_none_or(|v| v.is_empty()) {
                        break;
                    }
                    lp.push(cur);
                }
                loops.push(lp);
            }
        }
        // The outer boundary encloses the most area; the rest are holes.
        let area = |l: &Vec<(i64, i64)>| {
            let mut a = 0i64;
            for i in 0..l.len() {
                let (p, q) = (l[i], l[(i + 1) % l.len()]);
                a += p.0 * q.1 - q.0 * p.1;
            }
            a.abs()
        };
        if let Some(outer) = loops.into_iter().max_by_key(area) {
            polys.push(inset_half_pixel(&simplify(&outer)));
        }
    }
    polys
}

/// Moves each corner of a pixel-edge loop (clockwise on screen, the component on the
/// right; corner (X, Y) is the point (X - 0.5, Y - 0.5)) half a pixel inwards along both
/// edges: the loop through the boundary pixels' centres, with integer vertices.
fn inset_half_pixel(l: &[(i64, i64)]) -> Vec<[f64; 2]> {
    let n = l.len();
    let mut out: Vec<[f64; 2]> = Vec::with_capacity(n);
    for i in 0..n {
        let (a, b, c) = (l[(i + n - 1) % n], l[i], l[(i + 1) % n]);
        let d1 = ((b.0 - a.0).signum(), (b.1 - a.1).signum());
        let d2 = ((c.0 - b.0).signum(), (c.1 - b.1).signum());
        // The component's side of a step d is (-d.y, d.x) on screen (y down).
        let (n1, n2) = ((-d1.1, d1.0), (-d2.1, d2.0));
        let p = [
            b.0 as f64 - 0.5 + 0.5 * (n1.0 + n2.0) as f64,
            b.1 as f64 - 0.5 + 0.5 * (n1.1 + n2.1) as f64,
        ];
        // Repeated points are kept: LabelMe wants at least 3 points, and a one-pixel
        // part (4 equal points) is drawn by the outline.
        out.push(p);
    }
    out
}

/// Drops vertices on a straight line between their neighbours.
fn simplify(l: &[(i64, i64)]) -> Vec<(i64, i64)> {
    let n = l.len();
    if n < 4 {
        return l.to_vec();
    }
    (0..n)
        .filter(|&i| {
            let (a, b, c) = (l[(i + n - 1) % n], l[i], l[(i + 1) % n]);
            (b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0) != 0
        })
        .map(|i| l[i])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_string_matches_pycocotools() {
        // By hand: a 3x3 mask with its middle column set has counts [3, 3, 3]; small
        // counts are one char each, 48 + c.
        assert_eq!(rle_encode_string(&[3, 3, 3]), "333");
        // 30 = 0b11110 has bit 4 set, so it needs a continuation: (30 | 0x20) + 48 = 'n',
        // then '0'. The fourth count is stored as 1 - 2 = -1: 0x1f + 48 = 'O'.
        let s = rle_encode_string(&[0, 2, 30, 1]);
        assert_eq!(s, "02n0O");
        assert_eq!(rle_decode_string(&s), Some(vec![0, 2, 30, 1]));
    }
}
