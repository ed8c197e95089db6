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
