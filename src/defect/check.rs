//! Topology checks shared by the imprinting code and the tests.

use std::collections::HashMap;

use crate::scene::Mesh;

/// Ok when every edge is used by exactly two triangles, once in each direction (closed,
/// edge-manifold, consistently wound), no triangle repeats an index, and every index is
/// in range. The error names the first offending edge or triangle.
pub fn check_closed_manifold(mesh: &Mesh) -> Result<(), String> {
    let n = mesh.positions.len() as u32;
    let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 3);
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if tri.iter().any(|&i| i >= n) {
            return Err(format!("triangle {t} has an index out of range"));
        }
        if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
            return Err(format!("triangle {t} repeats a vertex: {tri:?}"));
        }
        for k in 0..3 {
            let e = (tri[k], tri[(k + 1) % 3]);
            let c = directed.entry(e).or_insert(0);
            *c += 1;
            if *c > 1 {
                return Err(format!(
                    "directed edge {e:?} used twice (second time by triangle {t}): \
                     inconsistent winding or a non-manifold edge"
                ));
            }
        }
    }
    for &(a, b) in directed.keys() {
        if !directed.contains_key(&(b, a)) {
            return Err(format!(
                "edge ({a}, {b}) has no opposite: a hole or a T-junction"
            ));
        }
    }
    Ok(())
}
