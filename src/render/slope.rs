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

use glam::Vec3;

use crate::gpu_interface::{MAP_BUFFER_MASK, MAP_LABELLED_ONLY, MAP_REVOLVED, MAP_WRAP};

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
    let mut headers = vec![MapHeader::default(); slots];
    let mut texels: [Vec<u32>; MAP_BUFFERS] = Default::default();
    let mut distinct: Vec<*const SlopeMap> = Vec::new();
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
        let buf = match distinct.iter().position(|&p| p == Arc::as_ptr(s)) {
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
                if s.data
                    .iter()
                    .any(|v| !(v[0].is_finite() && v[1].is_finite()))
                {
                    return Err(bad("slopes must be finite".into()));
                }
                if distinct.len() == MAP_BUFFERS {
                    let mut all: Vec<_> = maps.iter().map(|m| Arc::as_ptr(&m.slopes)).collect();
                    all.sort();
                    all.dedup();
                    return Err(SlopeError::TooMany(all.len()));
                }
                texels[distinct.len()] = s
                    .data
                    .iter()
                    .map(|v| f16_bits(v[0]) as u32 | (f16_bits(v[1]) as u32) << 16)
                    .collect();
                distinct.push(Arc::as_ptr(s));
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
    Ok((headers, texels))
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
/// their `map`s with the planar ones): marks their headers `MAP_REVOLVED`.
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

/// Bilinear slopes at map-plane coordinates `q` (mm along map x and up from its centre).
fn lookup_plane(h: &MapHeader, texels: &[u32], q: [f32; 2]) -> [f32; 2] {
    let k = h.origin[3];
    let (w, ht) = (h.dims[0] as f32, h.dims[1] as f32);
    let x = q[0] * k + 0.5 * w;
    let y = -q[1] * k + 0.5 * ht;
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
    let at = |x: u32, y: u32| {
        let w = texels[(h.dims[2] + y * h.dims[0] + x) as usize];
        [f16_to_f32(w as u16), f16_to_f32((w >> 16) as u16)]
    };
    let mut out = [0.0; 2];
    for (c, o) in out.iter_mut().enumerate() {
        let a = at(x0, y0)[c] + (at(x1, y0)[c] - at(x0, y0)[c]) * tx;
        let b = at(x0, y1)[c] + (at(x1, y1)[c] - at(x0, y1)[c]) * tx;
        *o = a + (b - a) * ty;
    }
    out
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

    /// On the flange's bore (a curved patch), two neighbouring facets share one map
    /// frame: a point on their common edge gets the same slope from either side, and
    /// points just across the edge get nearly the same; with a planar frame per facet
    /// (before) the two sides disagree there.
    #[test]
    fn curved_patches_give_the_same_slope_on_both_sides_of_a_facet_edge() {
        use crate::scene::assemble::place_curved_maps;
        use crate::scene::{FlangeParams, flange};
        let fp = FlangeParams::default();
        let stage = Stage::new(
            flange(&fp),
            [0.0; 3],
            &crate::scene::config::TableConfig::default(),
        );
        // A 64 x 64 map of 0.1 mm texels with pseudo-random slopes.
        let mut map = SlopeMap::flat(64, 64, 100.0);
        for (i, v) in map.data.iter_mut().enumerate() {
            let h = (i as u32).wrapping_mul(2_654_435_761);
            *v = [
                (h >> 8 & 0xff) as f32 / 255.0 - 0.5,
                (h >> 16 & 0xff) as f32 / 255.0 - 0.5,
            ];
        }
        let maps = [FaceMap {
            face: FACE_A,
            slopes: Arc::new(map),
            rotation_deg: 0.0,
            offset_mm: [0.0; 2],
        }];
        let part = Placement {
            cover: Cover::Part,
            seed: 7,
            ..FACES
        };
        let first = stage.regions.len() as u32;
        let curved = place_curved_maps(&maps, &stage.curved, first, &part);
        assert_eq!(curved.len(), stage.curved.len());
        let slots = stage.regions.len() + stage.curved.len() + 1;
        let all: Vec<PlacedMap> = curved.iter().map(|c| c.map.clone()).collect();
        let (mut h, t) = pack(&all, slots, 1 << 27).expect("pack");
        let blocks = curved_blocks(&curved, &mut h).expect("blocks");
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
        let regions: Vec<RegionFrame> = [t1, t2]
            .iter()
            .map(|&t| stage.regions[stage.region_of[t] as usize])
            .collect();
        let planar = place_maps(&maps, &[frame_a()], &regions, &part).expect("planar");
        let (hp, tp) = pack(&planar, stage.regions.len() + 1, 1 << 27).expect("pack");
        let planar_at = |k: usize, p: Vec3| {
            let hh = &hp[regions[k].id as usize + 1];
            lookup(hh, &tp[(hh.dims[3] & MAP_BUFFER_MASK) as usize - 1], p)
        };
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
