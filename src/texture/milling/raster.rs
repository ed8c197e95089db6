//! Sub-model 3 and rasterisation: the tile index of rings and the ordered convex
//! combination f = L_k R_k + (1 - L_k) f evaluated on each ring's band.

use std::f32::consts::PI;

use super::rings::Ring;

pub(super) const TILE: usize = 128;

#[allow(clippy::too_many_arguments)]
pub(super) fn annulus_hits_rect(
    cx: f64,
    cy: f64,
    r_in: f64,
    r_out: f64,
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
) -> bool {
    let nx = cx.clamp(x0, x1) - cx;
    let ny = cy.clamp(y0, y1) - cy;
    let near = nx * nx + ny * ny;
    let fx = (cx - x0).abs().max((cx - x1).abs());
    let fy = (cy - y0).abs().max((cy - y1).abs());
    let far = fx * fx + fy * fy;
    near <= r_out * r_out && far >= r_in.max(0.0) * r_in.max(0.0)
}

/// Per-tile ring lists in composition order (rings are already sorted).
pub(super) fn index_rings(
    rings: &[Ring],
    tiles_x: usize,
    tiles_y: usize,
    tile_mm: f64,
) -> Vec<Vec<u32>> {
    let mut buckets = vec![Vec::new(); tiles_x * tiles_y];
    for (k, r) in rings.iter().enumerate() {
        let (cx, cy, ro) = (r.c[0] as f64, r.c[1] as f64, r.r_out as f64);
        let tx0 = ((cx - ro) / tile_mm).floor().max(0.0) as usize;
        let ty0 = ((cy - ro) / tile_mm).floor().max(0.0) as usize;
        let tx1 = (((cx + ro) / tile_mm).floor().max(0.0) as usize).min(tiles_x - 1);
        let ty1 = (((cy + ro) / tile_mm).floor().max(0.0) as usize).min(tiles_y - 1);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let (x0, y0) = (tx as f64 * tile_mm, ty as f64 * tile_mm);
                if annulus_hits_rect(
                    cx,
                    cy,
                    r.r_in as f64,
                    ro,
                    x0,
                    y0,
                    x0 + tile_mm,
                    y0 + tile_mm,
                ) {
                    buckets[ty * tiles_x + tx].push(k as u32);
                }
            }
        }
    }
    buckets
}

pub(super) struct TileCtx {
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) cols: usize,
    pub(super) rows: usize,
    pub(super) s: f32,
}

/// Composes one ring into a tile: f = L_k R_k + (1 - L_k) f on the ring's band only.
pub(super) fn raster_ring(r: &Ring, pool: &[f32], t: &TileCtx, tile: &mut [f32]) {
    let s = t.s;
    let (cx, cy) = (r.c[0], r.c[1]);
    let row_lo = (((cy - r.r_out) / s - 0.5).ceil().max(t.y0 as f32) as usize).max(t.y0);
    let row_hi = (((cy + r.r_out) / s - 0.5).floor()).min((t.y0 + t.rows) as f32 - 1.0);
    if row_hi < row_lo as f32 {
        return;
    }
    let noise = &pool[r.noise_off..r.noise_off + r.noise_len];
    let inv_band = 1.0 / (r.r_out - r.r_in);
    let inv_rout = 1.0 / r.r_out;
    for j in row_lo..=row_hi as usize {
        let dy = (j as f32 + 0.5) * s - cy;
        let ext_out = r.r_out * r.r_out - dy * dy;
        if ext_out < 0.0 {
            continue;
        }
        let xo = ext_out.sqrt();
        let ext_in = r.r_in * r.r_in - dy * dy;
        let row = &mut tile[(j - t.y0) * TILE..(j - t.y0) * TILE + t.cols];
        let mut seg = |xa: f32, xb: f32| {
            let ia = (((cx + xa) / s - 0.5).ceil()).max(t.x0 as f32) as usize;
            let ib = (((cx + xb) / s - 0.5).floor()).min((t.x0 + t.cols) as f32 - 1.0);
            if ib < ia as f32 {
                return;
            }
            for i in ia..=ib as usize {
                let dx = (i as f32 + 0.5) * s - cx;
                let rad = (dx * dx + dy * dy).sqrt();
                if rad < r.r_in || rad > r.r_out {
                    continue;
                }
                let front = 0.5 + 0.5 * (dx * r.dir[0] + dy * r.dir[1]) * inv_rout;
                let mut v = ring_profile(r, rad - r.r0, front);
                if r.noise_amp > 0.0 {
                    let env = cos_half_pi((rad - r.r_in) * inv_band - 0.5);
                    v += r.noise_amp * env * lookup(noise, fast_atan2(dy, dx));
                }
                let l = r.ab[0] + (r.ab[1] - r.ab[0]) * front;
                let f = &mut row[i - t.x0];
                *f = l * v + (1.0 - l) * *f;
            }
        };
        if ext_in > 0.0 {
            let xi = ext_in.sqrt();
            seg(-xo, -xi);
            seg(xi, xo);
        } else {
            seg(-xo, xo);
        }
    }
}

/// S_k * T_k at signed radial offset `s` from the indentation centre; `front` in [0, 1]
/// runs linearly from the ring's back (l) to its front (h).
#[inline]
fn ring_profile(r: &Ring, s: f32, front: f32) -> f32 {
    let half = 0.5 * r.wm;
    let lerp = |t: [f32; 2]| t[0] + (t[1] - t[0]) * front;
    if s.abs() <= half {
        -cos_half_pi(s * r.inv_w[0]) * lerp(r.tilt[0])
    } else if s < 0.0 {
        let u = s + half + 0.5 * r.wi;
        if r.wi > 0.0 && u.abs() <= 0.5 * r.wi {
            cos_half_pi(u * r.inv_w[1]) * lerp(r.tilt[1])
        } else {
            0.0
        }
    } else {
        let u = s - half - 0.5 * r.wo;
        if r.wo > 0.0 && u.abs() <= 0.5 * r.wo {
            cos_half_pi(u * r.inv_w[2]) * lerp(r.tilt[2])
        } else {
            0.0
        }
    }
}

/// cos(pi x) for |x| <= 1/2 by its Taylor polynomial (error < 3e-5): the shapes are
/// evaluated for every band pixel of every ring, where libm's cos dominated the time.
#[inline]
fn cos_half_pi(x: f32) -> f32 {
    let t = PI * PI * x * x;
    1.0 + t * (-0.5 + t * (1.0 / 24.0 + t * (-1.0 / 720.0 + t * (1.0 / 40320.0))))
}

/// Linear interpolation in a power-of-two periodic table at `angle` in [-pi, pi];
/// masks instead of `rem_euclid` / `%`, which cost as much as the rest of the pixel.
#[inline]
fn lookup(table: &[f32], angle: f32) -> f32 {
    let n = table.len();
    if n == 0 {
        return 0.0;
    }
    let x = angle * (n as f32 * (0.5 / PI)) + 2.0 * n as f32;
    let i = x as usize;
    let f = x - i as f32;
    let mask = n - 1;
    table[i & mask] * (1.0 - f) + table[(i + 1) & mask] * f
}

/// atan2 with ~1e-5 rad error (minimax polynomial on [0, 1]); the noise table does not need more.
#[inline]
fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let mx = ax.max(ay);
    if mx == 0.0 {
        return 0.0;
    }
    let a = ax.min(ay) / mx;
    let s = a * a;
    let mut r =
        a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    if ay > ax {
        r = PI / 2.0 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 { -r } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_matches_std() {
        for k in 0..1000 {
            let a = k as f32 * 0.00628 - PI;
            let (y, x) = a.sin_cos();
            let e = (fast_atan2(y * 3.0, x * 3.0) - y.atan2(x)).abs();
            assert!(
                e < 3e-5 || (e - 2.0 * PI).abs() < 3e-5,
                "angle {a}: err {e}"
            );
        }
    }

    #[test]
    fn cos_half_pi_is_accurate() {
        for k in 0..=1000 {
            let x = k as f32 / 1000.0 - 0.5;
            assert!((cos_half_pi(x) - (PI * x).cos()).abs() < 3e-5, "x = {x}");
        }
    }

    #[test]
    fn lookup_interpolates_periodically() {
        let table: Vec<f32> = (0..64).map(|i| i as f32).collect();
        let step = 2.0 * PI / 64.0;
        assert!((lookup(&table, 3.0 * step) - 3.0).abs() < 1e-3);
        assert!((lookup(&table, 3.5 * step) - 3.5).abs() < 1e-3);
        assert!((lookup(&table, -PI) - 32.0).abs() < 1e-3);
        assert!((lookup(&table, -0.5 * step) - 31.5).abs() < 1e-2);
    }
}
