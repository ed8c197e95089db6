//! Anisotropic scratch meshes: the face's triangles near a scratch are cut along rows at
//! fixed offsets from the path (the levels of the piecewise-linear offset field), so a
//! triangle only has to be short across the path, not along it.
//!
//! Conforming by construction: an edge is cut where the linear interpolation of its two
//! end vertices' offsets crosses a row, a function of the edge alone, so both triangles
//! of the edge get the same new vertices (looked up by edge and row). Each triangle is
//! then split along its row segments into convex pieces, each fanned into triangles. A
//! triangle whose offsets are not all usable (a corner in a rounded end cap, across a
//! ridge where the path comes back near itself) but which has cut edges is fanned from
//! its centroid instead; the refinement makes such triangles as small as the isotropic
//! mesh's there.

use std::collections::HashMap;

use glam::DVec3;

use super::DefectError;
use super::region::Region;
use super::tool::DefectTool;
use crate::scene::TriLabel;

/// A vertex whose offset lies within this fraction of the smallest row spacing of a row
/// is taken to lie on that row (no sliver between the vertex and the row).
pub const ROW_SNAP: f64 = 0.1;

fn key(a: u32, b: u32) -> u64 {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    ((lo as u64) << 32) | hi as u64
}

/// The mesh being cut (positions, triangles, labels, the input triangle of each).
pub(crate) struct Pieces<'a> {
    pub positions: &'a mut Vec<DVec3>,
    pub tris: &'a mut Vec<[u32; 3]>,
    pub labels: &'a mut Vec<TriLabel>,
    pub origin: &'a mut Vec<u32>,
}

/// Cuts the triangles of `region`'s face near scratch `tool` along its rows.
pub(crate) fn slice_scratch(
    m: Pieces,
    region: &Region,
    tool: &DefectTool,
    limit: usize,
) -> Result<(), DefectError> {
    let levels = tool.slice_levels();
    if levels.len() < 2 {
        return Ok(());
    }
    let gap = levels
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    let snap = ROW_SNAP * gap;
    let pad = tool.half_width();
    let (lo, hi) = (tool.lo, tool.hi);
    // Triangles of the face whose (u, v) box meets the scratch's box.
    let cands: Vec<usize> = (0..m.tris.len())
        .filter(|&t| {
            if m.labels[t].face != region.face {
                return false;
            }
            let c = m.tris[t].map(|i| region.to_uv(m.positions[i as usize]));
            let (mn, mx) = (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]));
            mx.x >= lo.x - pad && mx.y >= lo.y - pad && mn.x <= hi.x + pad && mn.y <= hi.y + pad
        })
        .collect();
    // Offsets and arc positions of their vertices.
    let mut field: HashMap<u32, Option<(f64, f64)>> = HashMap::with_capacity(cands.len());
    let mut dirs: HashMap<u32, glam::DVec2> = HashMap::new();
    let mut edges: HashMap<u64, u8> = HashMap::with_capacity(cands.len() * 2);
    let mut around: HashMap<u32, Vec<usize>> = HashMap::with_capacity(cands.len());
    let mut order: Vec<u32> = Vec::new();
    for &t in &cands {
        let tri = m.tris[t];
        for k in 0..3 {
            let v = tri[k];
            field.entry(v).or_insert_with(|| {
                order.push(v);
                let (s, arc, dir) = tool.path_coordinates(region.to_uv(m.positions[v as usize]))?;
                dirs.insert(v, dir);
                Some((s, arc))
            });
            around.entry(v).or_default().push(t);
            *edges.entry(key(v, tri[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    // Vertices within half the smallest row spacing of a row move onto it (in the face's
    // plane, along the offset's gradient), unless that would more than halve a
    // triangle's area: the rows then pass through vertices instead of slicing tiny
    // pieces off triangle corners (f32 positions would tilt such pieces' normals).
    let area_uv = |positions: &[DVec3], t: usize| {
        let c = m.tris[t].map(|i| region.to_uv(positions[i as usize]));
        (c[1] - c[0]).perp_dot(c[2] - c[0])
    };
    for &v in &order {
        let Some((s, arc)) = field[&v] else { continue };
        let j = levels.partition_point(|&l| l < s);
        let near = [j.wrapping_sub(1), j]
            .into_iter()
            .filter_map(|l| levels.get(l).copied())
            .min_by(|a, b| (a - s).abs().total_cmp(&(b - s).abs()));
        let Some(l) = near else { continue };
        if (l - s).abs() > 0.5 * gap || l == s {
            continue;
        }
        let d = dirs[&v];
        let old = m.positions[v as usize];
        let new = old + (region.u * d.x + region.v * d.y) * (l - s);
        let before: Vec<f64> = around[&v]
            .iter()
            .map(|&t| area_uv(m.positions, t))
            .collect();
        m.positions[v as usize] = new;
        let ok = around[&v]
            .iter()
            .zip(&before)
            .all(|(&t, &a)| area_uv(m.positions, t) > 0.5 * a);
        if ok {
            field.insert(v, Some((l, arc)));
        } else {
            m.positions[v as usize] = old;
        }
    }
    // What did not move: offsets within a tenth of the spacing of a row count as on it.
    for &v in &order {
        let Some((mut s, arc)) = field[&v] else {
            continue;
        };
        let j = levels.partition_point(|&l| l < s);
        for l in [j.wrapping_sub(1), j] {
            if let Some(&lv) = levels.get(l)
                && (s - lv).abs() < snap
            {
                s = lv;
            }
        }
        field.insert(v, Some((s, arc)));
    }
    // An edge is cut only if both its triangles are cut here (shared by two candidates)
    // and its ends have offsets on the same stretch of the path.
    let cuttable = |positions: &[DVec3], a: u32, b: u32| -> Option<(f64, f64)> {
        if edges.get(&key(a, b)) != Some(&2) {
            return None;
        }
        let ((sa, aa), (sb, ab)) = (field[&a]?, field[&b]?);
        let len = positions[a as usize].distance(positions[b as usize]);
        ((aa - ab).abs() <= 2.0 * len + 2.0 * sa.abs().max(sb.abs()) + 1e-9).then_some((sa, sb))
    };
    // Levels strictly between two offsets, in the order met going from `sa` to `sb`.
    let between = |sa: f64, sb: f64| -> Vec<usize> {
        let (x, y) = (sa.min(sb), sa.max(sb));
        let first = levels.partition_point(|&l| l <= x);
        let last = levels.partition_point(|&l| l < y);
        let mut v: Vec<usize> = (first..last).collect();
        if sa > sb {
            v.reverse();
        }
        v
    };
    let mut cut_at: HashMap<(u64, usize), u32> = HashMap::new();
    for &t in &cands {
        let tri = m.tris[t];
        // The boundary in winding order, each point with its offset (NaN: unknown).
        let mut poly: Vec<(u32, f64)> = Vec::with_capacity(8);
        let mut all_cut = true;
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let sa = field[&a].map_or(f64::NAN, |f| f.0);
            poly.push((a, sa));
            let Some((sa, sb)) = cuttable(m.positions, a, b) else {
                all_cut = false;
                continue;
            };
            for j in between(sa, sb) {
                let ek = key(a, b);
                let v = *cut_at.entry((ek, j)).or_insert_with(|| {
                    // From the lower vertex id, so both sides compute the same point.
                    let (p, q, sp, sq) = if a < b {
                        (a, b, sa, sb)
                    } else {
                        (b, a, sb, sa)
                    };
                    let lam = (levels[j] - sp) / (sq - sp);
                    let (pp, pq) = (m.positions[p as usize], m.positions[q as usize]);
                    m.positions.push(pp + (pq - pp) * lam);
                    (m.positions.len() - 1) as u32
                });
                poly.push((v, levels[j]));
            }
        }
        if poly.len() == 3 {
            continue;
        }
        let mut out: Vec<[u32; 3]> = Vec::new();
        if all_cut {
            for piece in cut_by_levels(poly, levels) {
                fan(&piece, m.positions, &mut out);
            }
        } else {
            let c = tri.map(|i| m.positions[i as usize]);
            m.positions.push((c[0] + c[1] + c[2]) / 3.0);
            let centre = (m.positions.len() - 1) as u32;
            for i in 0..poly.len() {
                out.push([centre, poly[i].0, poly[(i + 1) % poly.len()].0]);
            }
        }
        let (label, from) = (m.labels[t], m.origin[t]);
        m.tris[t] = out[0];
        for &tri in &out[1..] {
            m.tris.push(tri);
            m.labels.push(label);
            m.origin.push(from);
        }
        if m.tris.len() > limit {
            return Err(DefectError::TooLarge { limit });
        }
    }
    Ok(())
}

/// Splits a convex polygon (boundary points with offsets; every crossing of a level with
/// the boundary is a point at exactly that level) along each level into convex pieces.
fn cut_by_levels(mut cur: Vec<(u32, f64)>, levels: &[f64]) -> Vec<Vec<(u32, f64)>> {
    let mut pieces = Vec::new();
    let (lo, hi) = cur
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    for &l in levels.iter().filter(|&&l| l > lo && l < hi) {
        let on: Vec<usize> = (0..cur.len()).filter(|&i| cur[i].1 == l).collect();
        let n = cur.len();
        if on.len() != 2 || on[1] - on[0] == 1 || (on[0] == 0 && on[1] == n - 1) {
            continue;
        }
        let (i, j) = (on[0], on[1]);
        let a: Vec<(u32, f64)> = cur[i..=j].to_vec();
        let b: Vec<(u32, f64)> = cur[j..].iter().chain(&cur[..=i]).copied().collect();
        if a.iter().any(|p| p.1 < l) {
            pieces.push(a);
            cur = b;
        } else {
            pieces.push(b);
            cur = a;
        }
    }
    pieces.push(cur);
    pieces
}

/// Triangulates a convex polygon (winding kept): a quadrilateral across its shorter
/// diagonal, anything larger as a fan from its first point.
fn fan(poly: &[(u32, f64)], positions: &[DVec3], out: &mut Vec<[u32; 3]>) {
    let v: Vec<u32> = poly.iter().map(|p| p.0).collect();
    match v.len() {
        0..=2 => {}
        4 => {
            let d = |a: u32, b: u32| positions[a as usize].distance_squared(positions[b as usize]);
            if d(v[0], v[2]) <= d(v[1], v[3]) {
                out.push([v[0], v[1], v[2]]);
                out.push([v[0], v[2], v[3]]);
            } else {
                out.push([v[1], v[2], v[3]]);
                out.push([v[1], v[3], v[0]]);
            }
        }
        n => {
            for i in 1..n - 1 {
                out.push([v[0], v[i], v[i + 1]]);
            }
        }
    }
}
