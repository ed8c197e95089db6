//! Slope (normal) maps on the inspected faces: planar projection of a per-face slope map,
//! rotated and translated in the face plane, packed for glsl/path_trace.comp.
//!
//! Conventions follow the texture module (docs/texture.md): a map is row-major, row 0 at
//! the top, slopes `[dh/dx, dh/dy]` in image axes (x right, y down), unitless (µm/µm).
//! On a face, the map's x axis is the face frame's `u` rotated by `rotation_deg` about the
//! face normal (counter-clockwise seen from outside, i.e. towards `v`), its "up" (-y) is
//! the rotated `v`, and its centre sits at `centre + offset_mm[0] u + offset_mm[1] v`.

use glam::Vec3;

use crate::scene::testbody::FaceFrame;

/// Per-texel slopes from the texture module (`[dh/dx, dh/dy]`, row 0 at the top, y down,
/// `spacing_um`); the renderer takes it as is.
pub use crate::texture::SlopeMap;

/// A slope map placed on one inspected face (assembled in `scene::assemble`).
pub use crate::scene::assemble::FaceMap;

/// Face ids 0..FACE_SLOTS index the header table (0, "other", never has a map).
pub const FACE_SLOTS: usize = crate::gpu_interface::FACE_SLOTS as usize;

/// One face's placement as the shader reads it (declared in src/gpu_interface.in).
pub use crate::gpu_interface::FaceMapHeader as FaceMapGpu;

/// Why face maps cannot be packed.
#[derive(Debug, thiserror::Error)]
pub enum SlopeError {
    #[error("slope map for face {face}: {message}")]
    Invalid { face: &'static str, message: String },
}

/// Headers (one per face id) and, per inspected face A, B, C, its texels as two f16
/// slopes in one u32 (`unpackHalf2x16` in the shader): 4 bytes a texel, and one buffer
/// per face, so each face may use the whole storage-buffer range (128 MiB on lavapipe:
/// 33.5 M texels, e.g. 5792 x 5792). Maps on faces that the mesh does not have are
/// refused, so a typo in a face id cannot silently render flat.
pub fn pack(
    maps: &[FaceMap],
    frames: &[FaceFrame],
    max_bytes: u64,
) -> Result<(Vec<FaceMapGpu>, [Vec<u32>; 3]), SlopeError> {
    let mut headers = vec![FaceMapGpu::default(); FACE_SLOTS];
    let mut texels: [Vec<u32>; 3] = Default::default();
    for m in maps {
        let name = crate::scene::mesh::face_name(m.face);
        let bad = |message: String| SlopeError::Invalid {
            face: name,
            message,
        };
        let frame = frames
            .iter()
            .find(|f| f.face == m.face)
            .ok_or_else(|| bad("the mesh has no such face".into()))?;
        let s = &m.slopes;
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
        if !(m.rotation_deg.is_finite() && m.offset_mm.iter().all(|v| v.is_finite())) {
            return Err(bad("rotation and offset must be finite".into()));
        }
        if headers[m.face as usize].dims[3] != 0 {
            return Err(bad("two maps on one face".into()));
        }
        let (sin, cos) = m.rotation_deg.to_radians().sin_cos();
        let ax = frame.u * cos + frame.v * sin;
        let up = frame.v * cos - frame.u * sin;
        let centre = frame.centre + frame.u * m.offset_mm[0] + frame.v * m.offset_mm[1];
        texels[m.face as usize - 1] = s
            .data
            .iter()
            .map(|v| f16_bits(v[0]) as u32 | (f16_bits(v[1]) as u32) << 16)
            .collect();
        headers[m.face as usize] = FaceMapGpu {
            origin: centre.extend(1000.0 / s.spacing_um as f32).into(),
            axis_x: ax.extend(0.0).into(),
            axis_up: up.extend(0.0).into(),
            dims: [s.width as u32, s.height as u32, 0, 1],
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

/// The shading normal the shader computes at `p` on a face with outward normal `n`
/// (CPU mirror for tests and docs): bilinear slopes, perturbed normal in the map axes.
pub fn shading_normal(h: &FaceMapGpu, texels: &[u32], p: Vec3, n: Vec3) -> Vec3 {
    let s = lookup(h, texels, p);
    let ax = Vec3::from_slice(&h.axis_x[..3]);
    let up = Vec3::from_slice(&h.axis_up[..3]);
    // dh/d(up) = -dh/dy because image y points down.
    (n - ax * s[0] + up * s[1]).normalize()
}

/// Bilinear slopes at `p` (zero outside the map), as the shader computes them.
pub fn lookup(h: &FaceMapGpu, texels: &[u32], p: Vec3) -> [f32; 2] {
    if h.dims[3] == 0 {
        return [0.0; 2];
    }
    let d = p - Vec3::from_slice(&h.origin[..3]);
    let k = h.origin[3];
    let (w, ht) = (h.dims[0] as f32, h.dims[1] as f32);
    let x = d.dot(Vec3::from_slice(&h.axis_x[..3])) * k + 0.5 * w;
    let y = -d.dot(Vec3::from_slice(&h.axis_up[..3])) * k + 0.5 * ht;
    if !(x >= 0.0 && y >= 0.0 && x <= w && y <= ht) {
        return [0.0; 2];
    }
    let fx = (x - 0.5).clamp(0.0, w - 1.0);
    let fy = (y - 0.5).clamp(0.0, ht - 1.0);
    let (x0, y0) = (fx.floor() as u32, fy.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(h.dims[0] - 1), (y0 + 1).min(h.dims[1] - 1));
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
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
    use std::sync::Arc;

    #[test]
    fn placement_follows_rotation_offset_and_image_axes() {
        use glam::Vec2;
        let frame = FaceFrame {
            face: crate::scene::mesh::FACE_A,
            centre: Vec3::new(1.0, 2.0, 3.0),
            normal: Vec3::Z,
            u: Vec3::X,
            v: Vec3::Y,
            half_size: Vec2::splat(10.0),
            area: 400.0,
        };
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
        let (h, t) = pack(&[place(90.0, [5.0, 0.0])], &[frame], 1 << 27).expect("pack");
        let h = h[frame.face as usize];
        let t = &t[frame.face as usize - 1];
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
        // Outside the 4 mm map: flat.
        assert_eq!(lookup(&h, t, centre + Vec3::Y * 2.5), [0.0, 0.0]);
        assert!(
            pack(
                &[place(0.0, [0.0; 2]), place(0.0, [0.0; 2])],
                &[frame],
                1 << 27
            )
            .is_err()
        );
        let e = pack(&[place(0.0, [0.0; 2])], &[frame], 32)
            .unwrap_err()
            .to_string();
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

    /// dh/dx (map x) of the grooves of one scene file at `points` on face `face`.
    fn groove_slopes(
        cfg: &crate::scene::config::SceneConfig,
        face: crate::scene::mesh::FaceId,
        points: &[Vec3],
    ) -> Vec<f32> {
        let mesh = crate::scene::testbody(crate::scene::Variant::B);
        let frames = crate::scene::face_frames(&mesh);
        let maps = crate::scene::assemble::texture_maps(&cfg.texture, &frames).expect("maps");
        let (h, t) = pack(&maps, &frames, 1 << 27).expect("pack");
        points
            .iter()
            .map(|&p| lookup(&h[face as usize], &t[face as usize - 1], p)[0])
            .collect()
    }

    #[test]
    fn offsets_move_grooves_by_the_offset_on_their_face_only() {
        use crate::scene::mesh::FACE_A;
        let mut cfg = crate::scene::config::SceneConfig::parse(
            "[texture]\nkind = \"test-grooves\"\nspacing_um = 10.0\ngroove_period_mm = 1.2\n\
             rotation_deg = [30.0, 0.0, 0.0]\n",
        )
        .expect("cfg");
        let mesh = crate::scene::testbody(crate::scene::Variant::B);
        let frames = crate::scene::face_frames(&mesh);
        let fa = *frames.iter().find(|f| f.face == FACE_A).expect("A");
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
}
