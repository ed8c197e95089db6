//! Slope (normal) maps on the object: planar projection of slope maps onto its planar
//! regions (placed by `scene::assemble::place_maps`), packed for glsl/path_trace.comp.
//!
//! Conventions follow the texture module (docs/texture.md): a map is row-major, row 0 at
//! the top, slopes `[dh/dx, dh/dy]` in image axes (x right, y down), unitless (µm/µm).
//! A placed map's x axis and "up" (-y) axis lie in the region's plane, its centre at the
//! placed centre; outside its extent it repeats (`wrap`) or gives zero slopes.
//!
//! The material word of a triangle holds its slot (`MAT_MAP_SHIFT`): slot 0 (table,
//! lights) never has a map, slot `r + 1` is region `r`; a map marked `labelled_only`
//! shades only the region's triangles labelled A, B or C (`MAT_LABELLED`). The header table has one entry
//! per slot; up to three distinct maps (by identity) have one texel buffer each.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::scene::curved::PatchKind;

use crate::gpu_interface::{
    MAP_BUFFER_MASK, MAP_LABELLED_ONLY, MAP_REVOLVED, MAP_TRIPLANAR, MAP_WRAP,
};

/// A curved patch's projection as the shader reads it (src/gpu_interface.in).
pub use crate::gpu_interface::CurvedMapBlock;

/// Per-texel slopes from the texture module (`[dh/dx, dh/dy]`, row 0 at the top, y down,
/// `spacing_um`); the renderer takes it as is.
pub use crate::texture::SlopeMap;

/// A slope map chosen for one inspected face, and its placement on the whole part.
pub use crate::scene::assemble::{Cover, FaceMap, PlacedMap, Placement};

/// One slot's placement as the shader reads it (declared in src/gpu_interface.in).
pub use crate::gpu_interface::MapHeader;

/// Distinct maps (texel buffers) one scene may use at once.
pub const MAP_BUFFERS: usize = 3;

/// Why maps cannot be packed.
#[derive(Debug, thiserror::Error)]
pub enum SlopeError {
    #[error("slope map on region {region}: {message}")]
    Invalid { region: u32, message: String },
    #[error("{0} distinct slope maps on one object; at most {MAP_BUFFERS} fit")]
    TooMany(usize),
}

/// Headers (one per slot: `slots` = regions + 1) and the texels of each distinct map as
/// two f16 slopes in one u32 (`unpackHalf2x16` in the shader): 4 bytes a texel, one
/// buffer per map, so each map may use the whole storage-buffer range (128 MiB on
/// lavapipe: 33.5 M texels, e.g. 5792 x 5792).
pub fn pack(
    maps: &[PlacedMap],
    slots: usize,
    max_bytes: u64,
) -> Result<(Vec<MapHeader>, [Vec<u32>; MAP_BUFFERS]), SlopeError> {
    let (headers, distinct) = pack_headers(maps, slots, max_bytes)?;
    let mut texels: [Vec<u32>; MAP_BUFFERS] = Default::default();
    for (t, s) in texels.iter_mut().zip(&distinct) {
        *t = texel_words(s).map_err(|_| not_finite(maps, s))?;
    }
    Ok((headers, texels))
}

/// The headers of [`pack`] and its distinct maps in buffer order (the map of buffer b
/// is `distinct[b]`, read by headers whose `dims.w & MAP_BUFFER_MASK` is b + 1), without
/// their texels: a renderer takes each map's texel words from wherever it keeps them
/// (`render::device_maps`). Checks everything [`pack`] does but whether the slopes are
/// finite, which [`texel_words`] (and so [`texel_words_into`]) checks.
pub fn pack_headers(
    maps: &[PlacedMap],
    slots: usize,
    max_bytes: u64,
) -> Result<(Vec<MapHeader>, Vec<Arc<SlopeMap>>), SlopeError> {
    let mut headers = vec![MapHeader::default(); slots];
    let mut distinct: Vec<Arc<SlopeMap>> = Vec::new();
    for m in maps {
        let bad = |message: String| SlopeError::Invalid {
            region: m.region,
            message,
        };
        let slot = m.region as usize + 1;
        if slot >= slots {
            return Err(bad(format!("the object has {} regions", slots - 1)));
        }
        let s = &m.slopes;
        let buf = match distinct.iter().position(|d| Arc::ptr_eq(d, s)) {
            Some(b) => b,
            None => {
                if s.width == 0 || s.height == 0 || s.data.len() != s.width * s.height {
                    return Err(bad(format!(
                        "{} x {} texels but {} values",
                        s.width,
                        s.height,
                        s.data.len()
                    )));
                }
                if s.data.len() as u64 * 4 > max_bytes {
                    return Err(bad(format!(
                        "{} x {} texels need {} MiB, more than one storage buffer allows ({} MiB)",
                        s.width,
                        s.height,
                        (s.data.len() as u64 * 4) >> 20,
                        max_bytes >> 20
                    )));
                }
                if !(s.spacing_um.is_finite() && s.spacing_um > 0.0) {
                    return Err(bad(format!("spacing_um = {} must be > 0", s.spacing_um)));
                }
                if distinct.len() == MAP_BUFFERS {
                    let mut all: Vec<_> = maps.iter().map(|m| Arc::as_ptr(&m.slopes)).collect();
                    all.sort();
                    all.dedup();
                    return Err(SlopeError::TooMany(all.len()));
                }
                distinct.push(s.clone());
                distinct.len() - 1
            }
        };
        if headers[slot].dims[3] != 0 {
            return Err(bad("two maps on one region".into()));
        }
        if !(m.centre.is_finite() && m.axis_x.is_finite() && m.axis_up.is_finite()) {
            return Err(bad("placement must be finite".into()));
        }
        let flags = (buf as u32 + 1)
            | if m.wrap { MAP_WRAP } else { 0 }
            | if m.labelled_only {
                MAP_LABELLED_ONLY
            } else {
                0
            };
        headers[slot] = MapHeader {
            origin: m.centre.extend(1000.0 / s.spacing_um as f32).into(),
            axis_x: m.axis_x.extend(0.0).into(),
            axis_up: m.axis_up.extend(0.0).into(),
            dims: [s.width as u32, s.height as u32, 0, flags],
        };
    }
    Ok((headers, distinct))
}

/// [`pack`]'s error for a map whose slopes are not all finite, on the first region
/// `maps` put it on.
pub fn not_finite(maps: &[PlacedMap], s: &Arc<SlopeMap>) -> SlopeError {
    SlopeError::Invalid {
        region: maps
            .iter()
            .find(|m| Arc::ptr_eq(&m.slopes, s))
            .map_or(0, |m| m.region),
        message: "slopes must be finite".into(),
    }
}

/// A slope that is not finite, found by [`texel_words_into`].
#[derive(Debug)]
pub struct NotFinite;

/// A map's texel words as the shader reads them (two f16 slopes in one u32, dh/dx in the
/// low half).
pub fn texel_words(s: &SlopeMap) -> Result<Vec<u32>, NotFinite> {
    let mut out = vec![0u32; s.data.len()];
    texel_words_into(&s.data, &mut out)?;
    Ok(out)
}

/// [`texel_words`] of `slopes` written into `out` (as long as `slopes`), e.g. a mapped
/// buffer's memory; fails at a slope that is not finite (`out` then partly written).
pub fn texel_words_into(slopes: &[[f32; 2]], out: &mut [u32]) -> Result<(), NotFinite> {
    debug_assert_eq!(slopes.len(), out.len());
    for (o, v) in out.iter_mut().zip(slopes) {
        if !(v[0].is_finite() && v[1].is_finite()) {
            return Err(NotFinite);
        }
        *o = f16_bits(v[0]) as u32 | (f16_bits(v[1]) as u32) << 16;
    }
    Ok(())
}

/// f32 to IEEE half bits, rounding to nearest even; beyond the half range it saturates at
/// +-65504 (slopes that steep are clamped to 85 degrees by the shader anyway).
pub fn f16_bits(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let a = b & 0x7fff_ffff;
    if a >= 0x477f_f000 {
        return sign | 0x7bff;
    }
    if a < 0x3880_0000 {
        // Below 2^-14: a subnormal half (or zero below 2^-25).
        if a < 0x3300_0000 {
            return sign;
        }
        let m = (a & 0x7f_ffff) | 0x80_0000;
        let shift = 126 - (a >> 23);
        let q = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let mid = 1 << (shift - 1);
        let r = q + (rem > mid || (rem == mid && q & 1 == 1)) as u32;
        return sign | r as u16;
    }
    let a = a - 0x3800_0000;
    sign | ((a + 0x0fff + ((a >> 13) & 1)) >> 13) as u16
}

/// The two f16 halves of a packed word (low half first), as `unpackHalf2x16` gives them:
/// a texel's [dh/dx, dh/dy].
pub fn unpack_half2(word: u32) -> [f32; 2] {
    [f16_to_f32(word as u16), f16_to_f32((word >> 16) as u16)]
}

/// IEEE half bits to f32 (what `unpackHalf2x16` gives).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let e = ((h >> 10) & 0x1f) as i32;
    let m = (h & 0x3ff) as f32;
    sign * match e {
        0 => m * 2f32.powi(-24),
        31 => f32::INFINITY,
        _ => (1.0 + m / 1024.0) * 2f32.powi(e - 15),
    }
}

/// The shading normal the shader computes at `p` on a region with outward normal `n`
/// (CPU mirror for tests and docs): bilinear slopes, perturbed normal in the map axes.
/// `texels` are the header's buffer (`dims.w & MAP_BUFFER_MASK` - 1).
pub fn shading_normal(h: &MapHeader, texels: &[u32], p: Vec3, n: Vec3) -> Vec3 {
    let s = lookup(h, texels, p);
    let ax = Vec3::from_slice(&h.axis_x[..3]);
    let up = Vec3::from_slice(&h.axis_up[..3]);
    // dh/d(up) = -dh/dy because image y points down.
    (n - ax * s[0] + up * s[1]).normalize()
}

/// Bilinear slopes at `p` as the shader computes them: zero outside the map, or the map
/// repeated (`MAP_WRAP`).
pub fn lookup(h: &MapHeader, texels: &[u32], p: Vec3) -> [f32; 2] {
    if h.dims[3] & MAP_BUFFER_MASK == 0 {
        return [0.0; 2];
    }
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let q = [
        d.dot(Vec3::from_slice(&h.axis_x[..3])),
        d.dot(Vec3::from_slice(&h.axis_up[..3])),
    ];
    lookup_plane(h, texels, q)
}

/// The headers' projection blocks (`CurvedMapBlock`, one per slot, zeros for planar
/// slots) for the curved patches' maps, which must be in `headers` already (`pack` of
/// their `map`s with the planar ones): marks their headers `MAP_REVOLVED` or
/// `MAP_TRIPLANAR`.
pub fn curved_blocks(
    curved: &[crate::scene::assemble::PlacedCurved],
    headers: &mut [MapHeader],
) -> Result<Vec<CurvedMapBlock>, SlopeError> {
    let mut blocks = vec![CurvedMapBlock::default(); headers.len().max(1)];
    for c in curved {
        let slot = c.map.region as usize + 1;
        let bad = |message: String| SlopeError::Invalid {
            region: c.map.region,
            message,
        };
        if slot >= headers.len() || headers[slot].dims[3] & MAP_BUFFER_MASK == 0 {
            return Err(bad("a curved patch without its packed map".into()));
        }
        if c.kind == PatchKind::Triplanar {
            if !c.offset_mm.iter().all(|x| x.is_finite()) {
                return Err(bad("triplanar placement must be finite".into()));
            }
            headers[slot].dims[3] |= MAP_TRIPLANAR;
            blocks[slot] = CurvedMapBlock {
                profile: [0.0; 4],
                place: [c.offset_mm[0], c.offset_mm[1], 0.0, 0.0],
            };
            continue;
        }
        let v = [
            c.sin_beta,
            c.cos_beta,
            c.arc_radius,
            c.offset_mm[0],
            c.offset_mm[1],
        ];
        if !(v.iter().all(|x| x.is_finite()) && c.arc_radius > 0.0) {
            return Err(bad("curved placement must be finite, radius > 0".into()));
        }
        headers[slot].dims[3] |= MAP_REVOLVED;
        blocks[slot] = CurvedMapBlock {
            profile: [c.sin_beta, c.cos_beta, c.arc_radius, 0.0],
            place: [c.offset_mm[0], c.offset_mm[1], 0.0, 0.0],
        };
    }
    Ok(blocks)
}

/// Map-plane coordinates (mm along the map's x and up axes from its centre) of `p` on a
/// curved patch's slot (`MAP_REVOLVED`): u = arc radius x theta, v along the generatrix
/// (src/scene/curved.rs), minus the map centre's (u, v). The shader's `map_plane`.
pub fn curved_plane(h: &MapHeader, c: &CurvedMapBlock, p: Vec3) -> [f32; 2] {
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let a = Vec3::from_slice(&h.axis_up[..3]);
    let e0 = Vec3::from_slice(&h.axis_x[..3]);
    let hgt = d.dot(a);
    let r = d - hgt * a;
    let theta = r.dot(a.cross(e0)).atan2(r.dot(e0));
    [
        c.profile[2] * theta - c.place[0],
        r.length() * c.profile[0] + hgt * c.profile[1] - c.place[1],
    ]
}

/// Unit map axes (x, up) in the surface at `p` of a curved patch's slot: about the axis
/// and along the generatrix. The shader's `map_axes`.
pub fn curved_axes(h: &MapHeader, c: &CurvedMapBlock, p: Vec3) -> (Vec3, Vec3) {
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let a = Vec3::from_slice(&h.axis_up[..3]);
    let r = (d - d.dot(a) * a).normalize_or_zero();
    (a.cross(r), r * c.profile[0] + a * c.profile[1])
}

/// Bilinear slopes at `p` on a curved patch's slot, as the shader computes them.
pub fn lookup_curved(h: &MapHeader, c: &CurvedMapBlock, texels: &[u32], p: Vec3) -> [f32; 2] {
    if h.dims[3] & MAP_BUFFER_MASK == 0 {
        return [0.0; 2];
    }
    lookup_plane(h, texels, curved_plane(h, c, p))
}

/// Steepest slope a map may give (85 degrees; the shader's `MAX_SLOPE` in
/// glsl/path_trace.comp, which this CPU mirror must equal).
pub const MAX_SLOPE: f32 = 11.43;

/// Smallest triplanar weight whose projection is read (below it the projection is left
/// out; the shader's `TRIPLANAR_MIN_WEIGHT`).
pub const TRIPLANAR_MIN_WEIGHT: f32 = 1e-3;

/// The shading normal on a triplanar patch's slot, as the shader's `triplanar_normal`
/// computes it: `ng` the geometric normal facing the viewer, `smooth` the patch's smooth
/// normal at `p`. Projection k (frame axis e_k; x = `axis_x`, z = `axis_up`, y = z x x)
/// reads the map at (p - centre) on the plane normal to e_k, its axes oriented so that
/// their cross product is sign(smooth . e_k) e_k; the three slope vectors, brought into
/// the tangent plane of `ng` as a planar map's are, are summed with the weights of
/// `curved::triplanar_weights(smooth)`. Exactly `ng` where the map is flat or the point is
/// seen from inside (smooth . ng <= 0).
pub fn triplanar_normal(
    h: &MapHeader,
    c: &CurvedMapBlock,
    texels: &[u32],
    p: Vec3,
    ng: Vec3,
    smooth: Vec3,
) -> Vec3 {
    if h.dims[3] & MAP_BUFFER_MASK == 0 || smooth.dot(ng) <= 0.0 {
        return ng;
    }
    let ex = Vec3::from_slice(&h.axis_x[..3]);
    let ez = Vec3::from_slice(&h.axis_up[..3]);
    let ey = ez.cross(ex);
    let e = [ex, ey, ez];
    let local = Vec3::new(smooth.dot(ex), smooth.dot(ey), smooth.dot(ez));
    let w = crate::scene::curved::triplanar_weights(local);
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let mut delta = Vec3::ZERO;
    for k in 0..3 {
        if w[k] < TRIPLANAR_MIN_WEIGHT {
            continue;
        }
        let s = if local[k] >= 0.0 { 1.0 } else { -1.0 };
        let (ax, up) = (e[(k + 1) % 3] * s, e[(k + 2) % 3]);
        let q = [d.dot(ax) - c.place[0], d.dot(up) - c.place[1]];
        let sl = Vec2::from(lookup_plane(h, texels, q));
        let len = sl.length();
        let sl = if len > MAX_SLOPE {
            sl * (MAX_SLOPE / len)
        } else {
            sl
        };
        let ax = ax - ax.dot(ng) * ng;
        let up = up - up.dot(ng) * ng;
        delta += w[k] * (-sl.x * ax + sl.y * up);
    }
    if delta == Vec3::ZERO {
        return ng;
    }
    (ng + delta).normalize()
}

/// Bilinear slopes at map-plane coordinates `q` (mm along map x and up from its centre).
/// Texel coordinates (x right, y down, texel i's centre at i + 0.5) of the point with
/// plane coordinates `q` (along the map's x and up axes from its centre).
fn plane_xy(h: &MapHeader, q: [f32; 2]) -> (f32, f32) {
    let k = h.origin[3];
    (
        q[0] * k + 0.5 * h.dims[0] as f32,
        -q[1] * k + 0.5 * h.dims[1] as f32,
    )
}

/// The map coordinates of `p` on a planar slot as texture coordinates: u = x / width,
/// v = y / height (texel i's centre at (i + 0.5) / size, row 0 at v = 0, unbounded:
/// the map repeats). A renderer that filters the map bilinearly at (u, v) with
/// wrap-around reads what `lookup` reads (used by the Mitsuba export of
/// examples/render_convergence).
pub fn map_uv(h: &MapHeader, p: Vec3) -> [f32; 2] {
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let (x, y) = plane_xy(
        h,
        [
            d.dot(Vec3::from_slice(&h.axis_x[..3])),
            d.dot(Vec3::from_slice(&h.axis_up[..3])),
        ],
    );
    [x / h.dims[0] as f32, y / h.dims[1] as f32]
}

fn lookup_plane(h: &MapHeader, texels: &[u32], q: [f32; 2]) -> [f32; 2] {
    let (w, ht) = (h.dims[0] as f32, h.dims[1] as f32);
    let (x, y) = plane_xy(h, q);
    let (x0, y0, x1, y1, tx, ty);
    if h.dims[3] & MAP_WRAP != 0 {
        let fx = (x - 0.5) - w * ((x - 0.5) / w).floor();
        let fy = (y - 0.5) - ht * ((y - 0.5) / ht).floor();
        if !(fx >= 0.0 && fy >= 0.0) {
            return [0.0; 2];
        }
        x0 = (fx as u32).min(h.dims[0] - 1);
        y0 = (fy as u32).min(h.dims[1] - 1);
        x1 = if x0 + 1 == h.dims[0] { 0 } else { x0 + 1 };
        y1 = if y0 + 1 == h.dims[1] { 0 } else { y0 + 1 };
        tx = fx - x0 as f32;
        ty = fy - y0 as f32;
    } else {
        if !(x >= 0.0 && y >= 0.0 && x <= w && y <= ht) {
            return [0.0; 2];
        }
        let fx = (x - 0.5).clamp(0.0, w - 1.0);
        let fy = (y - 0.5).clamp(0.0, ht - 1.0);
        (x0, y0) = (fx.floor() as u32, fy.floor() as u32);
        (x1, y1) = ((x0 + 1).min(h.dims[0] - 1), (y0 + 1).min(h.dims[1] - 1));
        (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    }
    let at = |x: u32, y: u32| unpack_half2(texels[(h.dims[2] + y * h.dims[0] + x) as usize]);
    let mut out = [0.0; 2];
    for (c, o) in out.iter_mut().enumerate() {
        let a = at(x0, y0)[c] + (at(x1, y0)[c] - at(x0, y0)[c]) * tx;
        let b = at(x0, y1)[c] + (at(x1, y1)[c] - at(x0, y1)[c]) * tx;
        *o = a + (b - a) * ty;
    }
    out
}

/// u32 words per texel of a moments level (levels 1 and up; [`moments_pyramid`]).
pub const MOMENT_WORDS: usize = 3;

/// Levels of a `width` x `height` map's moment pyramid, level 0 (the map) included: level
/// k has `ceil(width / 2^k)` x `ceil(height / 2^k)` texels, down to 1 x 1.
pub fn moment_levels(width: u32, height: u32) -> u32 {
    let n = width.max(height).max(1);
    // 1 + ceil(log2(n)); the shader: findMSB(n - 1) + 2.
    1 + (32 - (n - 1).leading_zeros())
}

/// Texels per side of level `k`.
pub fn level_dims(width: u32, height: u32, k: u32) -> (u32, u32) {
    (width.div_ceil(1 << k), height.div_ceil(1 << k))
}

/// First word of level `k` (>= 1) in the moments buffer.
pub fn level_offset(width: u32, height: u32, k: u32) -> usize {
    (1..k)
        .map(|j| {
            let (w, h) = level_dims(width, height, j);
            w as usize * h as usize * MOMENT_WORDS
        })
        .sum()
}

/// The slope moments of a packed level-0 map (`pack`'s texels: two f16 slopes a u32) for
/// LEAN filtering (`[render] texture_filter = "lean"`): levels 1 up to 1 x 1, each texel
/// the mean slope and the slope covariance of the level-0 texels under it (a box of
/// 2^k x 2^k texels, clipped at the map's right and bottom edges), in f16:
/// word 0 `[mean dh/dx, mean dh/dy]`, word 1 `[var dh/dx, var dh/dy]`, word 2
/// `[cov, 0]`. Level 0 itself is the map (covariance zero: a bilinear surface has one
/// slope at a point). Central moments rather than raw ones keep the variance exact in
/// f16 when the mean slope is far larger than its spread; the shader's bilinear lookup
/// adds the spread of the interpolated means (a mixture's covariance), which is what
/// interpolating raw moments gives. Memory: `MOMENT_WORDS` x 4 bytes x (1/4 + 1/16 + ...)
/// = 4 bytes per level-0 texel, as much as the map. Built in f64 from the f16 slopes the
/// shader reads.
pub fn moments_pyramid(level0: &[u32], width: u32, height: u32) -> Vec<u32> {
    use rayon::prelude::*;
    let levels = moment_levels(width, height);
    let mut out = vec![0u32; level_offset(width, height, levels)];
    // One level as (mean x, mean y, cxx, cyy, cxy, texel count).
    type M = [f64; 6];
    let mut prev: Vec<M> = level0
        .iter()
        .map(|&w| {
            let [x, y] = unpack_half2(w);
            [x as f64, y as f64, 0.0, 0.0, 0.0, 1.0]
        })
        .collect();
    let (mut pw, mut ph) = (width as usize, height as usize);
    for k in 1..levels {
        let (w, h) = level_dims(width, height, k);
        let (w, h) = (w as usize, h as usize);
        let cur: Vec<M> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let kids: Vec<&M> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .filter(|&&(dx, dy)| 2 * x + dx < pw && 2 * y + dy < ph)
                    .map(|&(dx, dy)| &prev[(2 * y + dy) * pw + 2 * x + dx])
                    .collect();
                let n: f64 = kids.iter().map(|c| c[5]).sum();
                let mx = kids.iter().map(|c| c[5] * c[0]).sum::<f64>() / n;
                let my = kids.iter().map(|c| c[5] * c[1]).sum::<f64>() / n;
                let mut m = [mx, my, 0.0, 0.0, 0.0, n];
                for c in &kids {
                    let (ex, ey) = (c[0] - mx, c[1] - my);
                    m[2] += c[5] * (c[2] + ex * ex);
                    m[3] += c[5] * (c[3] + ey * ey);
                    m[4] += c[5] * (c[4] + ex * ey);
                }
                for v in &mut m[2..5] {
                    *v /= n;
                }
                m
            })
            .collect();
        let base = level_offset(width, height, k);
        out[base..base + w * h * MOMENT_WORDS]
            .par_chunks_mut(MOMENT_WORDS)
            .zip(cur.par_iter())
            .for_each(|(o, m)| {
                let half2 =
                    |a: f64, b: f64| f16_bits(a as f32) as u32 | (f16_bits(b as f32) as u32) << 16;
                o[0] = half2(m[0], m[1]);
                o[1] = half2(m[2], m[3]);
                o[2] = half2(m[4], 0.0);
            });
        (prev, pw, ph) = (cur, w, h);
    }
    out
}

/// The moment pyramid of one map's texel words (`width` x `height`), checked against one
/// storage buffer's `max_bytes`; errors name `region`, the first region showing the map.
pub fn map_moments(
    texels: &[u32],
    width: u32,
    height: u32,
    region: u32,
    max_bytes: u64,
) -> Result<Vec<u32>, SlopeError> {
    let bytes = level_offset(width, height, moment_levels(width, height)) as u64 * 4;
    if bytes > max_bytes {
        return Err(SlopeError::Invalid {
            region,
            message: format!(
                "{width} x {height} texels: the moment pyramid of texture_filter = \"lean\" needs {} MiB, more than one storage buffer allows ({} MiB)",
                bytes >> 20,
                max_bytes >> 20
            ),
        });
    }
    Ok(moments_pyramid(texels, width, height))
}

/// The footprint's mip level as the shader computes it for a primary hit: the pixel
/// cone's width at the hit, `pixel_angle` (rad: `PathParams::pixel_angle` x cos^1.5 of
/// the ray's angle to the camera axis) x the
/// distance `t` (mm), widened by 1 / |cos| of the angle between the ray and the surface
/// (clamped at `LEAN_MIN_COS`), in texels (`texels_per_mm`, `MapHeader::origin.w`), times
/// `scale`; log2 of it. Below 0 (the footprint is under a texel) nothing is filtered.
pub fn lean_lambda(
    pixel_angle: f32,
    t: f32,
    cos_surface: f32,
    texels_per_mm: f32,
    scale: f32,
) -> f32 {
    let width_mm = pixel_angle * t / cos_surface.abs().max(LEAN_MIN_COS);
    (width_mm * texels_per_mm * scale).log2()
}

/// Smallest |cos| between the primary ray and the surface in the footprint (about 87
/// degrees off the normal): keeps the footprint finite at grazing angles.
pub const LEAN_MIN_COS: f32 = 0.05;

/// Mean slope and slope variance (trace of the covariance: var dh/dx + var dh/dy) at `p`
/// at mip level `lambda` (fractional: trilinear between floor and floor + 1, clamped to
/// the top level), as the shader computes them; `lambda <= 0`: the level-0 lookup
/// ([`lookup`]) and variance 0, exactly.
pub fn lookup_lean(
    h: &MapHeader,
    texels: &[u32],
    moments: &[u32],
    p: Vec3,
    lambda: f32,
) -> ([f32; 2], f32) {
    let m0 = lookup(h, texels, p);
    if lambda.is_nan() || lambda <= 0.0 || h.dims[3] & MAP_BUFFER_MASK == 0 {
        return (m0, 0.0);
    }
    let top = (moment_levels(h.dims[0], h.dims[1]) - 1) as f32;
    if top < 1.0 {
        return (m0, 0.0);
    }
    let l = lambda.min(top);
    let k = l.floor() as u32;
    let f = l - k as f32;
    // The lower level (level 0: the point lookup, no spread).
    let (ma, va) = if k == 0 {
        (m0, 0.0)
    } else {
        match level_moments(h, moments, p, k) {
            Some(r) => r,
            None => return (m0, 0.0),
        }
    };
    if f == 0.0 {
        return (ma, va);
    }
    let Some((mb, vb)) = level_moments(h, moments, p, (k + 1).min(top as u32)) else {
        return (m0, 0.0);
    };
    mix_moments(ma, va, mb, vb, f)
}

/// Mixture of two slope distributions with weights 1 - f and f: its mean and variance.
fn mix_moments(ma: [f32; 2], va: f32, mb: [f32; 2], vb: f32, f: f32) -> ([f32; 2], f32) {
    // GLSL's mix: a (1 - f) + b f.
    let m = [ma[0] * (1.0 - f) + mb[0] * f, ma[1] * (1.0 - f) + mb[1] * f];
    let d2 = |a: [f32; 2]| (a[0] - m[0]) * (a[0] - m[0]) + (a[1] - m[1]) * (a[1] - m[1]);
    (m, (1.0 - f) * (va + d2(ma)) + f * (vb + d2(mb)))
}

/// Bilinear moments at level `k` >= 1 (None outside a clipped map).
fn level_moments(h: &MapHeader, moments: &[u32], p: Vec3, k: u32) -> Option<([f32; 2], f32)> {
    let (w, ht) = level_dims(h.dims[0], h.dims[1], k);
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let s = 1.0 / (1u32 << k) as f32;
    let x = (d.dot(Vec3::from_slice(&h.axis_x[..3])) * h.origin[3] + 0.5 * h.dims[0] as f32) * s;
    let y = (-d.dot(Vec3::from_slice(&h.axis_up[..3])) * h.origin[3] + 0.5 * h.dims[1] as f32) * s;
    let (wf, hf) = (w as f32, ht as f32);
    let (x0, y0, x1, y1, tx, ty);
    if h.dims[3] & MAP_WRAP != 0 {
        let fx = (x - 0.5) - wf * ((x - 0.5) / wf).floor();
        let fy = (y - 0.5) - hf * ((y - 0.5) / hf).floor();
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        x0 = (fx as u32).min(w - 1);
        y0 = (fy as u32).min(ht - 1);
        x1 = if x0 + 1 == w { 0 } else { x0 + 1 };
        y1 = if y0 + 1 == ht { 0 } else { y0 + 1 };
        tx = fx - x0 as f32;
        ty = fy - y0 as f32;
    } else {
        let (wl, hl) = (h.dims[0] as f32 * s, h.dims[1] as f32 * s);
        if !(x >= 0.0 && y >= 0.0 && x <= wl && y <= hl) {
            return None;
        }
        let fx = (x - 0.5).clamp(0.0, wf - 1.0);
        let fy = (y - 0.5).clamp(0.0, hf - 1.0);
        (x0, y0) = (fx.floor() as u32, fy.floor() as u32);
        (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(ht - 1));
        (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    }
    let base = level_offset(h.dims[0], h.dims[1], k);
    let at = |x: u32, y: u32| {
        let i = base + (y * w + x) as usize * MOMENT_WORDS;
        let (a, b) = (moments[i], moments[i + 1]);
        let v = unpack_half2(b);
        (unpack_half2(a), v[0] + v[1])
    };
    // Bilinear weights; the mixture of the four texels' distributions.
    let taps = [
        (at(x0, y0), (1.0 - tx) * (1.0 - ty)),
        (at(x1, y0), tx * (1.0 - ty)),
        (at(x0, y1), (1.0 - tx) * ty),
        (at(x1, y1), tx * ty),
    ];
    let mut m = [0.0f32; 2];
    for ((mi, _), wt) in &taps {
        m[0] += wt * mi[0];
        m[1] += wt * mi[1];
    }
    let mut v = 0.0f32;
    for ((mi, vi), wt) in &taps {
        let (ex, ey) = (mi[0] - m[0], mi[1] - m[1]);
        v += wt * (vi + ex * ex + ey * ey);
    }
    Some((m, v))
}

/// GGX alpha widened by the slope variance under the footprint (isotropic LEAN:
/// alpha^2 + var dh/dx + var dh/dy, i.e. each axis's Beckmann-matched alpha^2 / 2 gains
/// that axis's variance, averaged over the two axes), at most 1; unchanged (bit for bit)
/// when the variance is not positive.
pub fn lean_alpha(alpha: f32, var: f32) -> f32 {
    if var > 0.0 {
        (alpha * alpha + var).sqrt().min(1.0)
    } else {
        alpha
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::FaceFrame;
    use crate::scene::assemble::{RegionFrame, Stage, place_maps};
    use crate::scene::mesh::FACE_A;
    use std::sync::Arc;

    fn frame_a() -> FaceFrame {
        FaceFrame {
            face: FACE_A,
            centre: Vec3::new(1.0, 2.0, 3.0),
            normal: Vec3::Z,
            u: Vec3::X,
            v: Vec3::Y,
            half_size: glam::Vec2::splat(10.0),
            area: 400.0,
        }
    }

    fn region_a(f: &FaceFrame) -> RegionFrame {
        RegionFrame {
            id: 0,
            face: f.face,
            centre: f.centre,
            normal: f.normal,
            u: f.u,
            v: f.v,
        }
    }

    const FACES: Placement = Placement {
        cover: Cover::Faces,
        seed: 0,
        rotation_range_deg: 0.0,
        defects: crate::scene::assemble::DefectSurface::Textured,
    };

    #[test]
    fn placement_follows_rotation_offset_and_image_axes() {
        let frame = frame_a();
        // 4 x 4 texels of 1 mm; the top row (y = 0) slopes in y, the rest in x.
        let mut map = SlopeMap::flat(4, 4, 1000.0);
        for (i, s) in map.data.iter_mut().enumerate() {
            *s = if i < 4 { [0.0, 1.0] } else { [1.0, 0.0] };
        }
        let map = Arc::new(map);
        let place = |rotation_deg, offset_mm| FaceMap {
            face: frame.face,
            slopes: map.clone(),
            rotation_deg,
            offset_mm,
        };
        let regions = [region_a(&frame)];
        let placed = |maps: &[FaceMap], p: &Placement| {
            let placed = place_maps(maps, &[frame], &regions, p).expect("place");
            pack(&placed, 2, 1 << 27).expect("pack")
        };
        let (h, t) = placed(&[place(90.0, [5.0, 0.0])], &FACES);
        let (h, t) = (h[1], &t[0]);
        // Rotated 90 degrees: map x = v (+y), map up = -u; centre at (6, 2, 3).
        let centre = Vec3::new(6.0, 2.0, 3.0);
        // 1.5 mm along map x from the centre, 0.5 mm down: texel row 2 (dh/dx = 1), so
        // the normal leans against map x, i.e. towards -y.
        let p = centre + Vec3::Y * 1.5 + Vec3::X * 0.5;
        let n = shading_normal(&h, t, p, Vec3::Z);
        assert!(
            (n - Vec3::new(0.0, -1.0, 1.0).normalize()).length() < 1e-5,
            "{n}"
        );
        // Top row (1.5 mm along map up = -x): dh/dy = 1 with y down, so the height
        // falls towards map up and the normal leans that way: towards -x.
        let p = centre + Vec3::Y * 0.5 - Vec3::X * 1.5;
        let n = shading_normal(&h, t, p, Vec3::Z);
        assert!(
            (n - Vec3::new(-1.0, 0.0, 1.0).normalize()).length() < 1e-5,
            "{n}"
        );
        // Outside the 4 mm map: flat when clipped, the map again 4 mm on when repeated.
        let outside = centre + Vec3::Y * 2.5;
        assert_eq!(lookup(&h, t, outside), [0.0, 0.0]);
        let part = Placement {
            cover: Cover::Part,
            ..FACES
        };
        let (hw, tw) = placed(&[place(90.0, [5.0, 0.0])], &part);
        for k in 0..40 {
            let p = centre + Vec3::new(k as f32 * 0.173 - 3.0, k as f32 * 0.311 - 6.0, 0.0);
            let a = lookup(&hw[1], &tw[0], p);
            let b = lookup(&hw[1], &tw[0], p + Vec3::Y * 4.0 - Vec3::X * 8.0);
            assert!(
                (a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5,
                "{a:?} {b:?}"
            );
            // Inside the map the repeated lookup is the clipped one, bit for bit.
            if (p - centre).abs().max_element() < 1.99 {
                assert_eq!(a, lookup(&h, t, p), "{p}");
            }
        }
        assert_ne!(lookup(&hw[1], &tw[0], outside), [0.0, 0.0]);
        let two = [place(0.0, [0.0; 2]), place(0.0, [0.0; 2])];
        assert!(place_maps(&two, &[frame], &regions, &FACES).is_err());
        let one = place_maps(&[place(0.0, [0.0; 2])], &[frame], &regions, &FACES).expect("one");
        let e = pack(&one, 2, 32).unwrap_err().to_string();
        assert!(e.contains("storage buffer"), "{e}");
    }

    #[test]
    fn map_uv_is_what_a_wrapped_bilinear_texture_reads() {
        // A 5 x 3 map of distinct slopes (not square, not symmetric), rotated and
        // offset, repeated over the part: bilinear filtering with wrap-around at
        // map_uv (texel i's centre at (i + 0.5) / size, row 0 at v = 0; Mitsuba's bitmap
        // texture) reads what the shader's lookup reads.
        let frame = frame_a();
        let mut map = SlopeMap::flat(5, 3, 700.0);
        for (i, s) in map.data.iter_mut().enumerate() {
            *s = [0.1 * i as f32 - 0.4, 0.05 * (i * i % 7) as f32 - 0.1];
        }
        let face_map = FaceMap {
            face: frame.face,
            slopes: Arc::new(map),
            rotation_deg: 30.0,
            offset_mm: [1.3, -0.4],
        };
        let part = Placement {
            cover: Cover::Part,
            ..FACES
        };
        let placed = place_maps(&[face_map], &[frame], &[region_a(&frame)], &part).expect("place");
        let (h, t) = pack(&placed, 2, 1 << 27).expect("pack");
        let (h, t) = (h[1], &t[0]);
        let (w, ht) = (h.dims[0] as i64, h.dims[1] as i64);
        let texel = |x: i64, y: i64| {
            unpack_half2(t[(h.dims[2] as i64 + y.rem_euclid(ht) * w + x.rem_euclid(w)) as usize])
        };
        for k in 0..200 {
            let p = frame.centre
                + Vec3::new(
                    k as f32 * 0.0731 - 7.0,
                    (k * 37 % 200) as f32 * 0.0613 - 6.0,
                    0.0,
                );
            let uv = map_uv(&h, p);
            let (x, y) = (uv[0] * w as f32 - 0.5, uv[1] * ht as f32 - 0.5);
            let (x0, y0) = (x.floor(), y.floor());
            let (tx, ty) = (x - x0, y - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let got = lookup(&h, t, p);
            for (c, got) in got.iter().enumerate() {
                let a = texel(x0, y0)[c] * (1.0 - tx) + texel(x0 + 1, y0)[c] * tx;
                let b = texel(x0, y0 + 1)[c] * (1.0 - tx) + texel(x0 + 1, y0 + 1)[c] * tx;
                let want = a * (1.0 - ty) + b * ty;
                assert!((got - want).abs() < 1e-4, "{p} {c}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn half_conversion_rounds_to_nearest() {
        for x in [
            0.0f32, 1.0, -1.0, 0.5, 1.7320508, 11.43, 1e-3, -6.1e-5, 3.0e-7, 65504.0,
        ] {
            let y = f16_to_f32(f16_bits(x));
            // Half precision: 11 significant bits (relative 2^-11), subnormals 2^-25 absolute.
            assert!((y - x).abs() <= x.abs() * 4.9e-4 + 3.0e-8, "{x} -> {y}");
        }
        assert_eq!(f16_bits(1.0), 0x3c00);
        assert_eq!(f16_bits(-2.0), 0xc000);
        assert_eq!(f16_bits(1e9), 0x7bff);
        assert_eq!(f16_bits(0.0), 0);
    }

    /// `burnished`: the defect triangles leave their regions (no map), the rest keep them.
    #[test]
    fn burnished_defects_get_no_map() {
        let mut mesh = crate::scene::testbody(crate::scene::Variant::B);
        // Mark every third triangle of face A as a dent.
        let marked: Vec<usize> = (0..mesh.labels.len())
            .filter(|&t| mesh.labels[t].face == crate::scene::mesh::FACE_A)
            .step_by(3)
            .collect();
        assert!(!marked.is_empty());
        for &t in &marked {
            mesh.labels[t].class = 1;
        }
        let table = crate::scene::config::TableConfig::default();
        let textured = Stage::new(mesh.clone(), [0.0; 3], &table);
        let mut burnished = Stage::new(mesh, [0.0; 3], &table);
        burnished.burnish_defects();
        assert_eq!(textured.regions, burnished.regions);
        for (t, (&a, &b)) in textured
            .region_of
            .iter()
            .zip(&burnished.region_of)
            .enumerate()
        {
            assert_ne!(a, u32::MAX, "triangle {t}");
            if marked.contains(&t) {
                assert_eq!(b, u32::MAX, "defect triangle {t} keeps a region");
            } else {
                assert_eq!(a, b, "triangle {t}");
            }
        }
    }

    fn stage_b() -> Stage {
        let mesh = crate::scene::testbody(crate::scene::Variant::B);
        Stage::new(
            mesh,
            [0.0; 3],
            &crate::scene::config::TableConfig::default(),
        )
    }

    /// dh/dx (map x) of the grooves of one scene file at `points` on face `face`.
    fn groove_slopes(
        cfg: &crate::scene::config::SceneConfig,
        face: crate::scene::mesh::FaceId,
        points: &[Vec3],
    ) -> Vec<f32> {
        let stage = stage_b();
        let maps =
            crate::scene::assemble::texture_maps(&cfg.texture, &stage.face_frames).expect("maps");
        let placed = place_maps(&maps, &stage.face_frames, &stage.regions, &FACES).expect("place");
        let (h, t) = pack(&placed, stage.regions.len() + 1, 1 << 27).expect("pack");
        let r = stage
            .regions
            .iter()
            .find(|r| r.face == face)
            .expect("region");
        let h = h[r.id as usize + 1];
        points
            .iter()
            .map(|&p| lookup(&h, &t[(h.dims[3] & MAP_BUFFER_MASK) as usize - 1], p)[0])
            .collect()
    }

    #[test]
    fn offsets_move_grooves_by_the_offset_on_their_face_only() {
        let mut cfg = crate::scene::config::SceneConfig::parse(
            "[texture]\nkind = \"test-grooves\"\nspacing_um = 10.0\ngroove_period_mm = 1.2\n\
             rotation_deg = [30.0, 0.0, 0.0]\n",
        )
        .expect("cfg");
        let stage = stage_b();
        let fa = *stage
            .face_frames
            .iter()
            .find(|f| f.face == FACE_A)
            .expect("A");
        let ax = fa.u * 30f32.to_radians().cos() + fa.v * 30f32.to_radians().sin();
        // Points along the grooves' direction of variation (map x) around A's centre.
        let points: Vec<Vec3> = (0..24)
            .map(|i| fa.centre + ax * (i as f32 * 0.05 - 0.6))
            .collect();
        let base = groove_slopes(&cfg, FACE_A, &points);
        // Offset (0.5, 0) along u on the 30-degree face: the grooves move by
        // 0.5 cos 30 = 0.433 mm along map x, so the slope at p + 0.433 ax is the old one at p.
        cfg.texture.offset_mm[0] = [0.5, 0.0];
        let shift = 0.5 * 30f32.to_radians().cos();
        let moved: Vec<Vec3> = points.iter().map(|&p| p + ax * shift).collect();
        for (s, b) in groove_slopes(&cfg, FACE_A, &moved).iter().zip(&base) {
            assert!((s - b).abs() < 0.01, "offset A: {s} vs {b}");
        }
        // An offset on face B leaves face A's grooves where they were.
        cfg.texture.offset_mm[0] = [0.0, 0.0];
        cfg.texture.offset_mm[1] = [3.0, -2.0];
        assert_eq!(
            groove_slopes(&cfg, FACE_A, &points),
            base,
            "offset B moved A"
        );
    }

    /// With `Cover::Part` every object triangle's slot has a repeating map (so every
    /// point of the object gets a slope from a map: no untextured border anywhere), the
    /// inspected faces keep their own map and placement, and the other regions draw
    /// theirs from the seed; with `Cover::Faces` only A, B and C have one.
    #[test]
    fn every_object_triangle_gets_a_map_with_cover_part() {
        let stage = stage_b();
        let maps: Vec<FaceMap> = stage
            .face_frames
            .iter()
            .map(|f| FaceMap {
                face: f.face,
                slopes: Arc::new(SlopeMap::test_grooves(
                    30.0,
                    100.0,
                    1.0 + f.face as f32,
                    20.0,
                )),
                rotation_deg: 10.0 * f.face as f32,
                offset_mm: [0.5, -0.25],
            })
            .collect();
        let part = Placement {
            cover: Cover::Part,
            seed: 7,
            rotation_range_deg: 15.0,
            ..FACES
        };
        let slots = stage.regions.len() + 1;
        let placed = place_maps(&maps, &stage.face_frames, &stage.regions, &part).expect("place");
        let (h, _) = pack(&placed, slots, 1 << 27).expect("pack");
        let objects = stage.region_of.len();
        assert!(objects > 0 && objects + 2 == stage.mesh.triangles.len());
        for (t, &r) in stage.region_of.iter().enumerate() {
            assert_ne!(r, u32::MAX, "triangle {t} has no region");
            let flags = h[r as usize + 1].dims[3];
            assert!(
                flags & MAP_BUFFER_MASK != 0 && flags & MAP_WRAP != 0,
                "triangle {t}"
            );
        }
        assert_eq!(h[0].dims[3], 0, "slot 0 (table) has no map");
        // Inspected faces: their own map, placed in their face frame as with `Faces`.
        let faces = place_maps(&maps, &stage.face_frames, &stage.regions, &FACES).expect("faces");
        assert_eq!(faces.len(), 3);
        for f in &faces {
            let p = placed
                .iter()
                .find(|p| p.region == f.region)
                .expect("same region");
            assert!(Arc::ptr_eq(&p.slopes, &f.slopes) && p.wrap && !f.wrap);
            assert_eq!(
                (p.centre, p.axis_x, p.axis_up),
                (f.centre, f.axis_x, f.axis_up)
            );
        }
        // Other regions: seeded, so the same seed places them the same way and another
        // seed differently.
        let again = place_maps(&maps, &stage.face_frames, &stage.regions, &part).expect("again");
        let other = Placement { seed: 8, ..part };
        let moved = place_maps(&maps, &stage.face_frames, &stage.regions, &other).expect("moved");
        let centres = |v: &[PlacedMap]| v.iter().map(|p| p.centre).collect::<Vec<_>>();
        assert_eq!(centres(&placed), centres(&again));
        assert_ne!(centres(&placed), centres(&moved));
        // A map on a face the mesh does not have is refused.
        let mut bad = maps.clone();
        bad[0].face = 9;
        assert!(place_maps(&bad, &stage.face_frames, &stage.regions, &part).is_err());
    }

    /// The moment pyramid of sinusoidal grooves (dh/dx = S cos(k x), dh/dy = 0) holds at
    /// each level the box-filtered mean and variance of the slope: for N texel centres
    /// spaced h around a block centre c, mean = S cos(k c) D(k), E[s^2] = S^2 / 2 (1 +
    /// cos(2 k c) D(2 k)) with D(k) = sin(N k h / 2) / (N sin(k h / 2)); the top level
    /// (the whole map, four periods) has mean 0 and variance S^2 / 2.
    #[test]
    fn moments_pyramid_matches_box_filtered_grooves() {
        let (spacing, period) = (10.0f64, 0.64f32);
        let map = SlopeMap::test_grooves(2.56, spacing, period, 20.0);
        let n = map.width as u32;
        assert_eq!((n, map.height as u32), (256, 256));
        let level0: Vec<u32> = map
            .data
            .iter()
            .map(|v| f16_bits(v[0]) as u32 | (f16_bits(v[1]) as u32) << 16)
            .collect();
        let pyr = moments_pyramid(&level0, n, n);
        let levels = moment_levels(n, n);
        assert_eq!(levels, 9);
        assert_eq!(pyr.len(), level_offset(n, n, levels));
        // 4 bytes per level-0 texel at most (1/4 + 1/16 + ... < 1/3, 3 words).
        assert!(pyr.len() <= level0.len());
        let s = 20f64.to_radians().tan();
        let k = std::f64::consts::TAU / (period as f64 * 1000.0);
        let d = |k: f64, m: f64| (m * k * spacing / 2.0).sin() / (m * (k * spacing / 2.0).sin());
        let mut checked = 0;
        for l in 1..levels {
            let (w, h) = level_dims(n, n, l);
            let base = level_offset(n, n, l);
            let m = (1u32 << l) as f64;
            for i in (0..w).step_by(((w / 8).max(1)) as usize) {
                // Block centre (µm from the map centre) of column i.
                let c = ((i as f64 + 0.5) * m - 0.5 * n as f64) * spacing;
                let mean = s * (k * c).cos() * d(k, m);
                let var = s * s / 2.0 * (1.0 + (2.0 * k * c).cos() * d(2.0 * k, m)) - mean * mean;
                for j in [0, h - 1] {
                    let o = base + ((j * w + i) as usize) * MOMENT_WORDS;
                    let g = |w: u32, hi: bool| {
                        f16_to_f32(if hi { (w >> 16) as u16 } else { w as u16 }) as f64
                    };
                    let (mx, my) = (g(pyr[o], false), g(pyr[o], true));
                    let (vx, vy, cxy) = (
                        g(pyr[o + 1], false),
                        g(pyr[o + 1], true),
                        g(pyr[o + 2], false),
                    );
                    assert!(
                        (mx - mean).abs() < 1e-3 * s,
                        "level {l} texel {i}: mean {mx} vs {mean}"
                    );
                    assert!(
                        (vx - var).abs() < 0.02 * var + 2e-6,
                        "level {l} texel {i}: variance {vx} vs {var}"
                    );
                    assert_eq!((my, vy, cxy), (0.0, 0.0, 0.0), "level {l} texel {i}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 40, "{checked}");
        // The top level: the whole map.
        let o = level_offset(n, n, levels - 1);
        let top = f16_to_f32(pyr[o + 1] as u16) as f64;
        assert!((top / (s * s / 2.0) - 1.0).abs() < 2e-3, "{top}");
    }

    /// The shader's lookup (CPU mirror): below a texel (lambda <= 0) it is the level-0
    /// lookup, bit for bit, with no variance; at an integer level on a texel centre it
    /// is that texel's moments; between levels it is continuous; the alpha widening
    /// leaves alpha untouched at zero variance.
    #[test]
    fn lean_lookup_levels() {
        let map = Arc::new(SlopeMap::test_grooves(2.56, 10.0, 0.64, 20.0));
        let frame = frame_a();
        let fm = FaceMap {
            face: frame.face,
            slopes: map,
            rotation_deg: 0.0,
            offset_mm: [0.0, 0.0],
        };
        let placed = place_maps(&[fm], &[frame], &[region_a(&frame)], &FACES).expect("place");
        let (h, t) = pack(&placed, 2, 1 << 27).expect("pack");
        let (h, t) = (h[1], &t[0]);
        let (w, ht) = (h.dims[0], h.dims[1]);
        let mom = &map_moments(t, w, ht, 0, 1 << 27).expect("moments");
        assert!(mom.len() > 1000 && map_moments(t, w, ht, 0, 64).is_err());
        let c = Vec3::from_slice(&h.origin[..3]);
        for i in 0..50 {
            let p = c + Vec3::new(i as f32 * 0.0137 - 0.3, i as f32 * 0.0071 - 0.2, 0.0);
            for lambda in [-3.0, -0.01, 0.0, f32::NAN] {
                assert_eq!(lookup_lean(&h, t, mom, p, lambda), (lookup(&h, t, p), 0.0));
            }
            // Continuity at integer levels (from below and above).
            for l in [1.0f32, 2.0, 3.0] {
                let (a, va) = lookup_lean(&h, t, mom, p, l - 1e-4);
                let (b, vb) = lookup_lean(&h, t, mom, p, l);
                let (c2, vc) = lookup_lean(&h, t, mom, p, l + 1e-4);
                for (x, y) in [(a, b), (b, c2)] {
                    assert!(
                        (x[0] - y[0]).abs() < 1e-3 && (x[1] - y[1]).abs() < 1e-3,
                        "{l}: {x:?} {y:?}"
                    );
                }
                assert!(
                    (va - vb).abs() < 1e-4 && (vb - vc).abs() < 1e-4,
                    "{l}: {va} {vb} {vc}"
                );
            }
            // Far above the top level: the whole map's variance.
            let (m, v) = lookup_lean(&h, t, mom, p, 40.0);
            let s2 = 20f32.to_radians().tan().powi(2) / 2.0;
            assert!(
                m[0].abs() < 1e-3 && (v / s2 - 1.0).abs() < 3e-3,
                "{m:?} {v}"
            );
        }
        // At level 2 on a texel centre: that texel's moments. Texel (5, 7) of level 2
        // (64 x 64) has its centre 4 (5.5, 7.5) texels from the map's top-left corner.
        let mm_per_texel = 1.0 / h.origin[3];
        let p = c + Vec3::new(
            (4.0 * 5.5 - 128.0) * mm_per_texel,
            -(4.0 * 7.5 - 128.0) * mm_per_texel,
            0.0,
        );
        let o = level_offset(256, 256, 2) + (7 * 64 + 5) * MOMENT_WORDS;
        let (m, v) = lookup_lean(&h, t, mom, p, 2.0);
        assert!((m[0] - f16_to_f32(mom[o] as u16)).abs() < 1e-6, "{m:?}");
        let want = f16_to_f32(mom[o + 1] as u16) + f16_to_f32((mom[o + 1] >> 16) as u16);
        assert!((v - want).abs() < 1e-6 && want > 0.0, "{v} {want}");
        assert_eq!(lean_alpha(0.1, 0.0), 0.1);
        assert!((lean_alpha(0.3, 0.16) - 0.5).abs() < 1e-6);
        assert_eq!(lean_alpha(0.5, 4.0), 1.0);
        // 2^lambda texels: 1 mrad at 500 mm on a face 60 degrees off the ray, 0.5 mm / px
        // texels per mm 100 -> 100 texels.
        let l = lean_lambda(1e-3, 500.0, 0.5, 100.0, 1.0);
        assert!((l - 100f32.log2()).abs() < 1e-4, "{l}");
    }

    #[test]
    fn grooves_reach_their_max_slope() {
        let m = SlopeMap::test_grooves(2.0, 10.0, 0.5, 60.0);
        let max = m.data.iter().map(|s| s[0].abs()).fold(0.0f32, f32::max);
        // 50 texels per period: the sampled peak is within cos(pi / 50) of the true one.
        assert!(
            (max / 60f32.to_radians().tan() - 1.0).abs() < 0.003,
            "{max}"
        );
    }

    /// Face A's map: 64 x 64 texels of 0.1 mm with pseudo-random slopes in +-0.5.
    fn noise_face_map() -> [FaceMap; 1] {
        let mut map = SlopeMap::flat(64, 64, 100.0);
        for (i, v) in map.data.iter_mut().enumerate() {
            let h = (i as u32).wrapping_mul(2_654_435_761);
            *v = [
                (h >> 8 & 0xff) as f32 / 255.0 - 0.5,
                (h >> 16 & 0xff) as f32 / 255.0 - 0.5,
            ];
        }
        [FaceMap {
            face: FACE_A,
            slopes: Arc::new(map),
            rotation_deg: 0.0,
            offset_mm: [0.0; 2],
        }]
    }

    /// A stage of `mesh` whose curved patches carry `noise_face_map` with
    /// `cover = "part"` and `seed`: the packed headers, texels and projection blocks.
    struct CurvedSetup {
        stage: Stage,
        maps: [FaceMap; 1],
        part: Placement,
        curved: Vec<crate::scene::assemble::PlacedCurved>,
        h: Vec<MapHeader>,
        t: [Vec<u32>; MAP_BUFFERS],
        blocks: Vec<CurvedMapBlock>,
    }

    fn curved_setup(mesh: crate::scene::Mesh, seed: u64) -> CurvedSetup {
        let stage = Stage::new(
            mesh,
            [0.0; 3],
            &crate::scene::config::TableConfig::default(),
        );
        let maps = noise_face_map();
        let part = Placement {
            cover: Cover::Part,
            seed,
            ..FACES
        };
        let first = stage.regions.len() as u32;
        let curved = crate::scene::assemble::place_curved_maps(&maps, &stage.curved, first, &part);
        let slots = stage.regions.len() + stage.curved.len() + 1;
        let all: Vec<PlacedMap> = curved.iter().map(|c| c.map.clone()).collect();
        let (mut h, t) = pack(&all, slots, 1 << 27).expect("pack");
        let blocks = curved_blocks(&curved, &mut h).expect("blocks");
        CurvedSetup {
            stage,
            maps,
            part,
            curved,
            h,
            t,
            blocks,
        }
    }

    /// The slopes at p of triangle `tris[k]`'s region in its own planar frame (what
    /// curved facets had before curved patches).
    fn per_facet_frames(
        stage: &Stage,
        maps: &[FaceMap],
        part: &Placement,
        tris: [usize; 2],
    ) -> impl Fn(usize, Vec3) -> [f32; 2] {
        let regions: Vec<RegionFrame> = tris
            .iter()
            .map(|&t| stage.regions[stage.region_of[t] as usize])
            .collect();
        let planar = place_maps(maps, &[frame_a()], &regions, part).expect("planar");
        let (hp, tp) = pack(&planar, stage.regions.len() + 1, 1 << 27).expect("pack");
        move |k: usize, p: Vec3| {
            let hh = &hp[regions[k].id as usize + 1];
            lookup(hh, &tp[(hh.dims[3] & MAP_BUFFER_MASK) as usize - 1], p)
        }
    }

    /// On a dome (a triplanar patch), two neighbouring facets interpolate the same
    /// smooth normal on their common edge, so (for one base normal) the blended slopes
    /// agree just across the edge; each facet's own planar frame (before) disagrees. At
    /// the pole (smooth normal +Z) the blend is the map projected on the XY plane.
    #[test]
    fn triplanar_patches_are_continuous_across_facet_edges() {
        use crate::scene::curved::decode_normal;
        let CurvedSetup {
            stage,
            maps,
            part,
            h,
            t,
            blocks,
            ..
        } = curved_setup(crate::scene::procedural::dome(20.0, 12, 64), 11);
        assert_eq!(stage.curved.len(), 1);
        let first = stage.regions.len() as u32;
        let slot = first as usize + 1;
        assert!(h[slot].dims[3] & MAP_TRIPLANAR != 0 && h[slot].dims[3] & MAP_REVOLVED == 0);
        let (hs, bs) = (&h[slot], &blocks[slot]);
        let tex = &t[(hs.dims[3] & MAP_BUFFER_MASK) as usize - 1];
        let mesh = &stage.mesh;
        let smooth_at = |t: usize, p: Vec3| {
            // Barycentric interpolation of the coded corner normals, as the shader does.
            let [a, b, c] = mesh.corners(t);
            let n = (b - a).cross(c - a);
            let (u, v) = (
                (p - a).cross(c - a).dot(n) / n.length_squared(),
                (b - a).cross(p - a).dot(n) / n.length_squared(),
            );
            let w = stage.corner_w[t].map(decode_normal);
            (w[0] * (1.0 - u - v) + w[1] * u + w[2] * v).normalize()
        };
        // Two neighbouring dome facets (different regions) halfway up, sharing an edge
        // that runs along a meridian (so the two sides differ in all three weights).
        let n = stage.region_of.len();
        let in_dome = |t: usize| stage.map_slot(t) == slot as u32;
        let (t1, t2, a, b) = (0..n)
            .filter(|&t| in_dome(t))
            .flat_map(|t1| (0..n).map(move |t2| (t1, t2)))
            .filter(|&(t1, t2)| in_dome(t2) && stage.region_of[t1] != stage.region_of[t2])
            .find_map(|(t1, t2)| {
                let (c1, c2) = (mesh.corners(t1), mesh.corners(t2));
                let s: Vec<Vec3> = c1.iter().filter(|p| c2.contains(p)).copied().collect();
                let ok = s.len() == 2
                    && (s[0].z - s[1].z).abs() > 1.0
                    && s[0].z.min(s[1].z) > 6.0
                    && s[0].x.abs().min(s[0].y.abs()) > 3.0;
                ok.then(|| (t1, t2, s[0], s[1]))
            })
            .expect("two neighbouring dome facets");
        let centroid = |t: usize| mesh.corners(t).iter().copied().sum::<Vec3>() / 3.0;
        let facet_n = |t: usize| {
            let [a, b, c] = mesh.corners(t);
            (b - a).cross(c - a).normalize()
        };
        let ng = (facet_n(t1) + facet_n(t2)).normalize();
        // The old way: each facet's own planar frame.
        let per_facet = per_facet_frames(&stage, &maps, &part, [t1, t2]);
        let planar_at = |k: usize, p: Vec3| Vec2::from(per_facet(k, p)).length();
        let (mut worst_tri, mut worst_planar, mut bent) = (0.0f32, 0.0f32, 0.0f32);
        for k in 1..10 {
            let p = a + (b - a) * (k as f32 / 10.0);
            let step = |t: usize| (centroid(t) - p).normalize() * 1e-3;
            let (p1, p2) = (p + step(t1), p + step(t2));
            let n1 = triplanar_normal(hs, bs, tex, p1, ng, smooth_at(t1, p1));
            let n2 = triplanar_normal(hs, bs, tex, p2, ng, smooth_at(t2, p2));
            worst_tri = worst_tri.max((n1 - n2).length());
            bent = bent.max(1.0 - n1.dot(ng));
            worst_planar = worst_planar.max((planar_at(0, p1) - planar_at(1, p2)).abs());
        }
        assert!(bent > 1e-3, "the map does not reach the dome: {bent}");
        // 2 um apart on a 100 um grid of slopes within +-0.5: normals at most 0.03 apart.
        assert!(worst_tri < 0.03, "triplanar: {worst_tri}");
        assert!(
            worst_planar > 0.1,
            "per-facet frames agree by chance: {worst_planar}"
        );
        // At the pole: the XY projection alone.
        let pole = Vec3::new(0.0, 0.0, 20.0);
        let got = triplanar_normal(hs, bs, tex, pole, Vec3::Z, Vec3::Z);
        let d = pole - Vec3::from_slice(&hs.origin[..3]);
        let s = lookup_plane(hs, tex, [d.x - bs.place[0], d.y - bs.place[1]]);
        let want = Vec3::new(-s[0], s[1], 1.0).normalize();
        assert!(
            (got - want).length() < 1e-6 && s != [0.0; 2],
            "{got} {want}"
        );
        // Seen from inside: no perturbation.
        assert_eq!(
            triplanar_normal(hs, bs, tex, pole, -Vec3::Z, Vec3::Z),
            -Vec3::Z
        );
    }

    /// On the flange's bore (a curved patch), two neighbouring facets share one map
    /// frame: a point on their common edge gets the same slope from either side, and
    /// points just across the edge get nearly the same; with a planar frame per facet
    /// (before) the two sides disagree there.
    #[test]
    fn curved_patches_give_the_same_slope_on_both_sides_of_a_facet_edge() {
        use crate::scene::{FlangeParams, flange};
        let fp = FlangeParams::default();
        let CurvedSetup {
            stage,
            maps,
            part,
            curved,
            h,
            t,
            blocks,
        } = curved_setup(flange(&fp), 7);
        assert_eq!(curved.len(), stage.curved.len());
        // Two bore facets sharing an edge (the bore's triangles lie at radius 10).
        let mesh = &stage.mesh;
        let n = stage.region_of.len();
        let on_bore = |t: usize| {
            mesh.corners(t)
                .iter()
                .all(|c| (glam::Vec2::new(c.x, c.y).length() - 10.0).abs() < 1e-3)
        };
        let bore: Vec<usize> = (0..n).filter(|&t| on_bore(t)).collect();
        assert_eq!(bore.len(), 2 * fp.bore_segments as usize);
        let (t1, t2, a, b) = bore
            .iter()
            .flat_map(|&t1| bore.iter().map(move |&t2| (t1, t2)))
            .filter(|&(t1, t2)| stage.region_of[t1] != stage.region_of[t2])
            .find_map(|(t1, t2)| {
                let (c1, c2) = (mesh.corners(t1), mesh.corners(t2));
                let shared: Vec<Vec3> = c1.iter().filter(|p| c2.contains(p)).copied().collect();
                (shared.len() == 2).then(|| (t1, t2, shared[0], shared[1]))
            })
            .expect("two neighbouring bore facets");
        let slot = stage.map_slot(t1);
        assert_eq!(slot, stage.map_slot(t2), "one patch, one slot");
        assert!(h[slot as usize].dims[3] & MAP_REVOLVED != 0);
        let (hs, bs) = (&h[slot as usize], &blocks[slot as usize]);
        let tex = &t[(hs.dims[3] & MAP_BUFFER_MASK) as usize - 1];
        let centroid = |t: usize| mesh.corners(t).iter().copied().sum::<Vec3>() / 3.0;
        // The old way: each facet's own planar frame (place_maps with its region).
        let planar_at = per_facet_frames(&stage, &maps, &part, [t1, t2]);
        let (mut worst_curved, mut worst_planar) = (0.0f32, 0.0f32);
        for k in 1..10 {
            let p = a + (b - a) * (k as f32 / 10.0);
            // Just inside each facet, 1 um from the edge.
            let step = |t: usize| (centroid(t) - p).normalize() * 1e-3;
            let (p1, p2) = (p + step(t1), p + step(t2));
            let s = lookup_curved(hs, bs, tex, p);
            assert!(s != [0.0, 0.0], "the map reaches the bore");
            let (s1, s2) = (
                lookup_curved(hs, bs, tex, p1),
                lookup_curved(hs, bs, tex, p2),
            );
            worst_curved = worst_curved.max((s1[0] - s2[0]).abs().max((s1[1] - s2[1]).abs()));
            let (q1, q2) = (planar_at(0, p1), planar_at(1, p2));
            worst_planar = worst_planar.max((q1[0] - q2[0]).abs().max((q1[1] - q2[1]).abs()));
        }
        // 2 um apart on a 100 um grid of slopes within +-0.5: at most 0.02 apart.
        assert!(worst_curved < 0.02, "curved: {worst_curved}");
        assert!(
            worst_planar > 0.1,
            "per-facet frames agree by chance: {worst_planar}"
        );
        // The map's axes at the edge: about the axis and along it (the bore is vertical).
        let (ax, up) = curved_axes(hs, bs, a);
        assert!(
            ax.z.abs() < 1e-6 && (up.z.abs() - 1.0).abs() < 1e-6,
            "{ax} {up}"
        );
        assert!((ax.length() - 1.0).abs() < 1e-5);
    }
}
