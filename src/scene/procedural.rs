//! Procedural meshes for tests and benchmarks.

use glam::Vec3;

use super::mesh::{Mesh, TriLabel};

/// A closed UV sphere of `radius` with a smooth radial bump pattern of relative height
/// `bump`, `segments` around and `rings` from pole to pole:
/// `2 * segments * (rings - 1)` triangles. Poles are single vertices (fans), so the mesh is
/// watertight and has triangles meeting at high-valence vertices (a hard case).
pub fn bumpy_sphere(segments: u32, rings: u32, radius: f32, bump: f32) -> Mesh {
    let segments = segments.max(3);
    let rings = rings.max(2);
    let mut positions = vec![Vec3::new(0.0, 0.0, radius)];
    for r in 1..rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let k = 1.0 + bump * (5.0 * theta).sin() * (7.0 * phi).cos();
            positions.push(
                radius
                    * k
                    * Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    ),
            );
        }
    }
    positions.push(Vec3::new(0.0, 0.0, -radius));
    let south = positions.len() as u32 - 1;
    let idx = |r: u32, s: u32| 1 + (r - 1) * segments + (s % segments);
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, idx(1, s), idx(1, s + 1)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (idx(r, s), idx(r, s + 1), idx(r + 1, s), idx(r + 1, s + 1));
            triangles.push([a, c, d]);
            triangles.push([a, d, b]);
        }
    }
    for s in 0..segments {
        triangles.push([south, idx(rings - 1, s + 1), idx(rings - 1, s)]);
    }
    let labels = vec![TriLabel::default(); triangles.len()];
    Mesh {
        positions,
        triangles,
        labels,
    }
}

/// A closed hemispherical dome of radius `r` standing on the z = 0 plane: `rings` bands
/// of planar quads (two triangles each; a fan at the pole), `segs` around, and a flat
/// bottom disc (a fan): `2 * segs * rings` triangles. A smooth surface that is no
/// surface of revolution with a straight generatrix: one triplanar patch
/// (`scene::curved`; docs/testbody.md, "Dome").
pub fn dome(r: f32, rings: u32, segs: u32) -> Mesh {
    let mut m = Mesh::default();
    let ring = |m: &mut Mesh, k: u32| -> Vec<u32> {
        let lat = std::f32::consts::FRAC_PI_2 * k as f32 / rings as f32;
        (0..segs)
            .map(|j| {
                let lon = std::f32::consts::TAU * j as f32 / segs as f32;
                m.positions.push(Vec3::new(
                    r * lat.cos() * lon.cos(),
                    r * lat.cos() * lon.sin(),
                    r * lat.sin(),
                ));
                m.positions.len() as u32 - 1
            })
            .collect()
    };
    let rows: Vec<Vec<u32>> = (0..rings).map(|k| ring(&mut m, k)).collect();
    m.positions.push(Vec3::new(0.0, 0.0, r));
    let pole = m.positions.len() as u32 - 1;
    m.positions.push(Vec3::ZERO);
    let bottom = m.positions.len() as u32 - 1;
    for j in 0..segs as usize {
        let j1 = (j + 1) % segs as usize;
        for k in 0..rings as usize - 1 {
            let (lo, hi) = (&rows[k], &rows[k + 1]);
            m.triangles.push([lo[j], lo[j1], hi[j1]]);
            m.triangles.push([lo[j], hi[j1], hi[j]]);
        }
        let top = &rows[rings as usize - 1];
        m.triangles.push([top[j], top[j1], pole]);
        m.triangles.push([rows[0][j1], rows[0][j], bottom]);
    }
    m.labels = vec![TriLabel::default(); m.triangles.len()];
    m
}
