//! Where no light triangle can hide another (issue 15): for each light triangle of a
//! view, the cells of a 2 x 2 x 2 grid over a box (the part of the stage's box that the
//! camera sees, `seen_box`, where the image's shading points lie) from every point of
//! which every point of the triangle in front of it is seen past all the other light
//! triangles. A light sample's shadow ray from such a cell toward such a triangle then
//! needs the lights' traversal only to find that triangle: the shader tests the sampled
//! triangle alone (glsl/common/trace.glsl, TQ_LIGHT_VISIBLE) and traverses the object up
//! to its hit, the answer the traversal would give; a ray from outside the grid
//! traverses the lights as always. A ring light is a torus, which can hide parts of
//! itself; a panel, bar or dome cannot hide its own front-facing triangles, but another
//! light can.
//!
//! The test is exact geometry in f64 and conservative: a cell is marked only where a
//! separating plane is found between every other light triangle and the convex hull of
//! the triangle and the cell's part in front of the triangle's plane (that hull is the
//! union of the segments between them). Triangles that share an edge or corner with the
//! sampled one may touch the hull there only (a segment can end on the shared edge, the
//! tie a closest-hit traversal settles by the triangle index at the same distance).
//! Another light triangle whose corners lie behind the triangle's plane, or on it to
//! within a few f32 roundings (`PLANE_SLACK`), cannot be in front of any point of it.
//! Each cell is tested widened by `CELL_PAD` so that the shader's f32 arithmetic, which
//! may place a point near a cell's face in its neighbour, stays inside what was tested.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::camera::Camera;
use crate::gpu_interface::{LIGHT_COVER_CELLS, LIGHT_COVER_SIDE};
use crate::trace::TriangleSoup;

/// Corners of another light triangle this far in front of a triangle's plane, relative
/// to the scene's scale (its largest coordinate), count as on it: a few f32 roundings,
/// so that the coplanar triangles of a panel do not hide one another.
pub const PLANE_SLACK: f64 = 4e-7;

/// Margins of the separating planes, relative to the scene's scale: every separation
/// holds by at least this much in f64.
const SEPARATION_MARGIN: f64 = 1e-9;

/// The grid's box is widened by this part of the scene's scale and this many mm: a
/// shadow ray starts a few hundred ulps off the surface (glsl/common/offset_ray.glsl),
/// and the box may end at the object's faces.
const BOX_MARGIN_REL: f64 = 1e-4;
const BOX_MARGIN_MM: f64 = 1e-3;

/// Each cell is tested widened by this part of the scene's scale and this many mm (the
/// shader's cell index from f32 positions errs by far less).
const CELL_PAD_REL: f64 = 1e-5;
const CELL_PAD_MM: f64 = 1e-3;

/// Light triangles handled together by the broad phase (a ring's come in order around
/// it, so neighbours in the list are neighbours in space).
const CLUSTER: usize = 32;

/// Clusters handled together by the broad phase's first level: a group's sphere holds
/// its clusters' spheres, so a plane that has the group's sphere on one side has each of
/// its clusters' there too (the same decisions as testing each cluster, fewer tests).
const GROUP: usize = 8;

/// A mask with every cell marked.
pub const ALL_CELLS: u32 = u32::MAX >> (32 - LIGHT_COVER_CELLS);

/// The most light triangles a hider list holds (more: none kept, the lights traversed).
pub const MAX_HIDERS: usize = 16;

/// The grid and, per light triangle, its mask of cells (bit x + 2 y + 4 z) and its
/// hiders.
#[derive(Clone, Debug, PartialEq)]
pub struct LightCover {
    /// The grid's lower corner and its cells' size (mm).
    pub lo: Vec3,
    pub cell: Vec3,
    pub masks: Vec<u32>,
    /// Per light triangle j with a cell unmarked, the other light triangles (indices in
    /// the light's list, ascending) that might hide a point of j from some point of
    /// such a cell: every triangle the separation test could not set apart from the hull
    /// of j and such a cell's part in front of it. No other triangle can stand between
    /// any point of an unmarked cell and j, so a shadow ray from the grid toward j meets
    /// no light nearer than j but among them (the shader tests j and them instead of
    /// traversing the lights). Empty where every cell is marked, or where more than
    /// `MAX_HIDERS` would be listed.
    pub hiders: Vec<Vec<u32>>,
}

impl LightCover {
    /// No cell marked: every shadow ray traverses the lights (no object box, or none
    /// wanted).
    pub fn none(count: usize) -> LightCover {
        LightCover {
            lo: Vec3::ZERO,
            cell: Vec3::ONE,
            masks: vec![0; count],
            hiders: vec![Vec::new(); count],
        }
    }
}

/// The cover of light triangles `lights` over a grid on box `grid` (lower and upper
/// corner); every light triangle's mask 0 without a box (an empty stage, a camera that
/// sees none of it).
pub fn light_cover(lights: &TriangleSoup, grid: Option<[Vec3; 2]>) -> LightCover {
    let count = lights.triangles.len();
    let Some([lo, hi]) = grid else {
        return LightCover::none(count);
    };
    let tris: Vec<[DVec3; 3]> = lights
        .triangles
        .iter()
        .map(|t| t.map(|i| lights.positions[i as usize].as_dvec3()))
        .collect();
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let scale = tris
        .iter()
        .flatten()
        .chain([&lo, &hi])
        .map(|p| p.abs().max_element())
        .fold(1.0, f64::max);
    let margin = BOX_MARGIN_REL * scale + BOX_MARGIN_MM;
    let (lo, hi) = (lo - DVec3::splat(margin), hi + DVec3::splat(margin));
    let side = LIGHT_COVER_SIDE as f64;
    let cell = (hi - lo) / side;
    let clusters: Vec<Sphere> = tris.chunks(CLUSTER).map(Sphere::around).collect();
    let groups: Vec<Sphere> = clusters.chunks(GROUP).map(Sphere::holding).collect();
    let ctx = Ctx {
        tris: &tris,
        clusters: &clusters,
        groups: &groups,
        plane_slack: PLANE_SLACK * scale,
        margin: SEPARATION_MARGIN * scale,
        pad: DVec3::splat(CELL_PAD_REL * scale + CELL_PAD_MM),
    };
    let (masks, hiders) = (0..count)
        .into_par_iter()
        .map(|j| ctx.mask(j, lo, hi, cell))
        .unzip();
    LightCover {
        lo: lo.as_vec3(),
        cell: cell.as_vec3(),
        masks,
        hiders,
    }
}

/// The part of box `object` (lower and upper corner) that `camera` sees, as a box: the
/// points of a lattice over the box that project into the image or near it (a tenth of
/// its size around it), widened by a lattice step and cut to the box; None where none
/// does. The cover's grid spans it, so that its cells are small where the image's
/// shading points lie; rays from outside the grid traverse the lights as always.
pub fn seen_box(camera: &Camera, object: [Vec3; 2]) -> Option<[Vec3; 2]> {
    const STEPS: usize = 24;
    let [lo, hi] = object;
    let step = (hi - lo) / STEPS as f32;
    let (w, h) = (camera.width as f32, camera.height as f32);
    let (mx, my) = (0.1 * w, 0.1 * h);
    let (mut a, mut b) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for i in 0..=STEPS {
        for j in 0..=STEPS {
            for k in 0..=STEPS {
                let p = lo + step * Vec3::new(i as f32, j as f32, k as f32);
                let Some(q) = camera.project(p) else {
                    continue;
                };
                if q.x >= -mx && q.x <= w + mx && q.y >= -my && q.y <= h + my {
                    a = a.min(p);
                    b = b.max(p);
                }
            }
        }
    }
    (a.x <= b.x).then(|| [(a - step).max(lo), (b + step).min(hi)])
}

/// The room triangles `tris` take about the axis through `centre` along unit `axis` (a
/// ring light's): [the hole's radius (no point of them nearer the axis), the half
/// height of the slab about the plane through `centre` normal to the axis that holds
/// them], the first narrowed and the second widened by a part in 10^4 of the largest
/// distance and 10^-3 mm, for the shader's f32 arithmetic; [0, 0] without triangles.
/// A ray that crosses the slab inside the hole, or never meets the slab, meets none of
/// them (glsl/common/lights.glsl `misses_lights`).
pub fn ring_room(tris: &[[Vec3; 3]], centre: Vec3, axis: Vec3) -> [f32; 2] {
    if tris.is_empty() {
        return [0.0, 0.0];
    }
    let (c, a) = (centre.as_dvec3(), axis.as_dvec3().normalize());
    let e1 = a.any_orthonormal_vector();
    let e2 = a.cross(e1);
    let (mut hole, mut half, mut far) = (f64::INFINITY, 0.0f64, 0.0f64);
    for t in tris {
        let p = t.map(|v| v.as_dvec3() - c);
        let q = p.map(|v| glam::DVec2::new(v.dot(e1), v.dot(e2)));
        for v in &p {
            half = half.max(v.dot(a).abs());
            far = far.max(v.length());
        }
        hole = hole.min(distance_to_origin(q));
    }
    let slack = 1e-4 * far + 1e-3;
    [(hole - slack).max(0.0) as f32, (half + slack) as f32]
}

/// The distance from the origin to the 2D triangle `q` (0 inside it).
fn distance_to_origin(q: [glam::DVec2; 3]) -> f64 {
    let edge = |a: glam::DVec2, b: glam::DVec2| a.perp_dot(b);
    let s = [edge(q[0], q[1]), edge(q[1], q[2]), edge(q[2], q[0])];
    if s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0) {
        return 0.0;
    }
    (0..3)
        .map(|i| {
            let (a, b) = (q[i], q[(i + 1) % 3]);
            let ab = b - a;
            let t = if ab.length_squared() > 0.0 {
                (-a.dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (a + ab * t).length()
        })
        .fold(f64::INFINITY, f64::min)
}

/// A bounding sphere of a cluster of triangles.
struct Sphere {
    centre: DVec3,
    radius: f64,
}

impl Sphere {
    fn around(tris: &[[DVec3; 3]]) -> Sphere {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for p in tris.iter().flatten() {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let centre = 0.5 * (lo + hi);
        let radius = tris
            .iter()
            .flatten()
            .map(|p| (*p - centre).length())
            .fold(0.0, f64::max);
        Sphere { centre, radius }
    }

    /// A sphere holding `spheres` (each wholly inside it, with room for rounding: the
    /// decisions a plane makes on it hold for each of them).
    fn holding(spheres: &[Sphere]) -> Sphere {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for s in spheres {
            lo = lo.min(s.centre - DVec3::splat(s.radius));
            hi = hi.max(s.centre + DVec3::splat(s.radius));
        }
        let centre = 0.5 * (lo + hi);
        let radius = spheres
            .iter()
            .map(|s| (s.centre - centre).length() + s.radius)
            .fold(0.0, f64::max);
        Sphere {
            centre,
            radius: radius * (1.0 + 1e-9) + 1e-9 * centre.abs().max_element(),
        }
    }
}

/// A plane n . p = d with unit n; the hull lies on its side n . p <= d.
#[derive(Clone, Copy)]
struct Plane {
    n: DVec3,
    d: f64,
}

struct Ctx<'a> {
    tris: &'a [[DVec3; 3]],
    clusters: &'a [Sphere],
    /// Spheres holding each `GROUP` consecutive clusters' spheres.
    groups: &'a [Sphere],
    plane_slack: f64,
    margin: f64,
    /// What each cell is widened by when tested.
    pad: DVec3,
}

impl Ctx<'_> {
    /// Triangle j's mask (all cells where the whole box is clear, else cell by cell)
    /// and its hiders over the unmarked cells (`LightCover::hiders`).
    fn mask(&self, j: usize, lo: DVec3, hi: DVec3, cell: DVec3) -> (u32, Vec<u32>) {
        let t = self.tris[j];
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        if n.length() == 0.0 {
            return (0, Vec::new());
        }
        let front = Plane {
            n: n.normalize(),
            d: n.normalize().dot(t[0]),
        };
        let all = ALL_CELLS;
        if self.clear(j, &front, lo - self.pad, hi + self.pad) {
            return (all, Vec::new());
        }
        let side = LIGHT_COVER_SIDE;
        let mut mask = 0;
        let mut hiders = std::collections::BTreeSet::new();
        let mut listed = true;
        for z in 0..side {
            for y in 0..side {
                for x in 0..side {
                    let a = lo + cell * DVec3::new(x as f64, y as f64, z as f64);
                    let (blo, bhi) = (a - self.pad, a + cell + self.pad);
                    if self.clear(j, &front, blo, bhi) {
                        mask |= 1 << (x + side * (y + side * z));
                    } else if listed {
                        listed = self.hiders(j, &front, blo, bhi, &mut hiders);
                    }
                }
            }
        }
        let hiders = if listed {
            hiders.into_iter().map(|k| k as u32).collect()
        } else {
            Vec::new()
        };
        (mask, hiders)
    }

    /// Whether no other light triangle with a corner in front of j's plane (only they
    /// can stand between j and a point in front of it) meets a segment from box [lo,
    /// hi]'s part in front of j's plane to j anywhere but on an edge or corner it shares
    /// with j.
    fn clear(&self, j: usize, front: &Plane, lo: DVec3, hi: DVec3) -> bool {
        self.walk(j, front, lo, hi, |_| false, |_| false)
    }

    /// Adds to `out` every other light triangle with a corner in front of j's plane
    /// that `separated` cannot set apart from the hull of j and box [lo, hi]'s part in
    /// front of it (those `clear` stops at, all of them); false once `out` would hold
    /// more than `MAX_HIDERS`.
    fn hiders(
        &self,
        j: usize,
        front: &Plane,
        lo: DVec3,
        hi: DVec3,
        out: &mut std::collections::BTreeSet<usize>,
    ) -> bool {
        let listed = out.clone();
        self.walk(
            j,
            front,
            lo,
            hi,
            |k| listed.contains(&k),
            |k| {
                out.insert(k);
                out.len() <= MAX_HIDERS
            },
        )
    }

    /// Walks the other light triangles that might stand between box [lo, hi]'s part in
    /// front of j's plane and j (a corner in front of the plane) and are not `skip`ped,
    /// calls `hider` on each that `separated` cannot set apart from the hull of that
    /// part and j, and stops with false where `hider` says so; true at the end (and
    /// where nothing of the box lies in front of j: j lights none of it).
    ///
    /// The triangles are visited in order, whole groups and clusters at a time: one
    /// behind j's plane (by its sphere, with `plane_slack`) or outside the hull (by one
    /// of its faces) is skipped, one wholly in front has every corner in front; the
    /// others are tested triangle by triangle (a corner in front of the plane, then
    /// `separated`). The same triangles reach `separated` in the same order as testing
    /// each triangle first.
    fn walk(
        &self,
        j: usize,
        front: &Plane,
        lo: DVec3,
        hi: DVec3,
        skip: impl Fn(usize) -> bool,
        mut hider: impl FnMut(usize) -> bool,
    ) -> bool {
        let t = self.tris[j];
        let mut pts = clip_box(lo, hi, front);
        if pts.is_empty() {
            return true;
        }
        pts.extend_from_slice(&t);
        let faces = hull_faces(&pts, self.margin);
        let behind = |s: &Sphere| front.n.dot(s.centre) - front.d + s.radius <= self.plane_slack;
        let out = |s: &Sphere| {
            faces
                .iter()
                .any(|f| f.n.dot(s.centre) - f.d > s.radius + self.margin)
        };
        for (g, gs) in self.groups.iter().enumerate() {
            if behind(gs) || out(gs) {
                continue;
            }
            let clusters = g * GROUP..((g + 1) * GROUP).min(self.clusters.len());
            for (c, s) in clusters.clone().zip(&self.clusters[clusters]) {
                if behind(s) || out(s) {
                    continue;
                }
                let all_in_front = front.n.dot(s.centre) - front.d - s.radius > self.plane_slack;
                for k in c * CLUSTER..((c + 1) * CLUSTER).min(self.tris.len()) {
                    let tk = &self.tris[k];
                    if k == j
                        || skip(k)
                        || !(all_in_front
                            || tk
                                .iter()
                                .any(|v| front.n.dot(*v) - front.d > self.plane_slack))
                    {
                        continue;
                    }
                    if !self.separated(&t, tk, &pts, &faces) && !hider(k) {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// Whether a plane separates triangle `k` from the hull of `pts` (j's corners among
    /// them), touching k at most in corners it shares with j.
    fn separated(&self, j: &[DVec3; 3], k: &[DVec3; 3], pts: &[DVec3], faces: &[Plane]) -> bool {
        let m = self.margin;
        // A face of the hull with k wholly outside it.
        if faces
            .iter()
            .any(|f| k.iter().all(|v| f.n.dot(*v) - f.d > m))
        {
            return true;
        }
        let shared: Vec<DVec3> = k.iter().filter(|v| j.contains(v)).copied().collect();
        let is_shared = |p: &DVec3| shared.contains(p);
        // k's own plane with the hull wholly on one side (but for shared corners).
        let nk = (k[1] - k[0]).cross(k[2] - k[0]);
        if nk.length() > 0.0 {
            let nk = nk.normalize();
            let hs = pts
                .iter()
                .filter(|p| !is_shared(p))
                .map(|p| nk.dot(*p - k[0]));
            let (mut above, mut below) = (true, true);
            for h in hs {
                above &= h > m;
                below &= h < -m;
            }
            if above || below {
                return true;
            }
        }
        if shared.is_empty() {
            return false;
        }
        // A plane through the shared corners with the hull on one side and k's other
        // corners strictly on the other: n . a >= 0 for a in A, n . b > 0 for b in B.
        let v = shared[0];
        let mut a: Vec<DVec3> = pts
            .iter()
            .filter(|p| !is_shared(p))
            .map(|p| *p - v)
            .collect();
        for s in &shared[1..] {
            a.push(*s - v);
            a.push(v - *s);
        }
        let b: Vec<DVec3> = k.iter().filter(|p| !is_shared(p)).map(|w| v - *w).collect();
        cone_separates(&a, &b, m)
    }
}

/// Whether some n has n . a >= 0 for every a in `a` and n . b > margin |b| for every b
/// in `b` (unit n). The feasible cone's extreme rays are cross products of two
/// constraint vectors; their sum lies inside it where it has an inside.
fn cone_separates(a: &[DVec3], b: &[DVec3], margin: f64) -> bool {
    let all: Vec<DVec3> = a.iter().chain(b).copied().collect();
    // Each constraint's slack, once (the same values as computed at every test).
    let slack: Vec<f64> = all.iter().map(|c| -margin * c.length()).collect();
    let feasible = |n: DVec3| all.iter().zip(&slack).all(|(c, s)| n.dot(*c) >= *s);
    let mut sum = DVec3::ZERO;
    for (i, p) in all.iter().enumerate() {
        for q in &all[i + 1..] {
            let c = p.cross(*q);
            let l = c.length();
            if l == 0.0 {
                continue;
            }
            for n in [c / l, -c / l] {
                if feasible(n) {
                    sum += n;
                }
            }
        }
    }
    let l = sum.length();
    if l == 0.0 {
        return false;
    }
    let n = sum / l;
    a.iter().all(|c| n.dot(*c) >= 0.0) && b.iter().all(|c| n.dot(*c) > margin * c.length())
}

/// The corners of box [lo, hi]'s part on the front side of `plane` (n . p >= d): the
/// box's corners there and its edges' crossings of the plane; empty where no corner is
/// strictly in front.
fn clip_box(lo: DVec3, hi: DVec3, plane: &Plane) -> Vec<DVec3> {
    let corner = |i: usize| {
        DVec3::new(
            if i & 1 != 0 { hi.x } else { lo.x },
            if i & 2 != 0 { hi.y } else { lo.y },
            if i & 4 != 0 { hi.z } else { lo.z },
        )
    };
    let h = |p: DVec3| plane.n.dot(p) - plane.d;
    if (0..8).all(|i| h(corner(i)) <= 0.0) {
        return Vec::new();
    }
    let mut pts: Vec<DVec3> = (0..8).map(corner).filter(|p| h(*p) >= 0.0).collect();
    for i in 0..8usize {
        for axis in [1usize, 2, 4] {
            if i & axis != 0 {
                continue;
            }
            let (p, q) = (corner(i), corner(i | axis));
            let (hp, hq) = (h(p), h(q));
            if (hp < 0.0) != (hq < 0.0) {
                pts.push(p + (q - p) * (hp / (hp - hq)));
            }
        }
    }
    pts
}

/// The faces of the convex hull of `pts` as planes with the points on their inner side
/// (every plane through three points with no point more than `margin` outside it; a
/// face may appear more than once).
fn hull_faces(pts: &[DVec3], margin: f64) -> Vec<Plane> {
    let mut faces = Vec::new();
    let n = pts.len();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let c = (pts[j] - pts[i]).cross(pts[k] - pts[i]);
                let l = c.length();
                if l <= 1e-12 * (pts[j] - pts[i]).length() * (pts[k] - pts[i]).length() {
                    continue;
                }
                let u = c / l;
                let d = u.dot(pts[i]);
                let (mut out, mut inn) = (false, false);
                for p in pts {
                    let h = u.dot(*p) - d;
                    out |= h > margin;
                    inn |= h < -margin;
                    if out && inn {
                        break; // points on both sides: not a face, whatever the rest
                    }
                }
                if !out {
                    faces.push(Plane {
                        n: u,
                        d: d + margin,
                    });
                } else if !inn {
                    faces.push(Plane {
                        n: -u,
                        d: -d + margin,
                    });
                }
            }
        }
    }
    faces
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::camera::ring_light;
    use crate::scene::config::LightConfig;

    /// Segment p-q against triangle t in f64 (Moeller-Trumbore): the segment parameter
    /// of the crossing, if any.
    fn cross_at(p: DVec3, q: DVec3, t: &[DVec3; 3]) -> Option<f64> {
        let d = q - p;
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        let h = d.cross(e2);
        let a = e1.dot(h);
        if a.abs() < 1e-14 {
            return None;
        }
        let s = p - t[0];
        let u = s.dot(h) / a;
        let qv = s.cross(e1);
        let v = d.dot(qv) / a;
        let w = e2.dot(qv) / a;
        (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && (0.0..=1.0).contains(&w)).then_some(w)
    }

    fn ring(major: f32, minor: f32, nm: u32, nn: u32, centre: Vec3, axis: Vec3) -> TriangleSoup {
        let cfg = LightConfig {
            major_radius_mm: major,
            minor_radius_mm: minor,
            segments_major: nm,
            segments_minor: nn,
            ..LightConfig::default()
        };
        let (positions, triangles) = ring_light(centre, axis, &cfg);
        TriangleSoup {
            positions,
            triangles,
        }
    }

    /// Every marked (triangle, cell): random segments from the cell's part in front of
    /// the triangle to points of it cross no other light triangle before their end; from
    /// an unmarked cell, only triangles of its hider list where it has one; and the
    /// cover marks at least `want_share` of the cells. Returns how many segments from
    /// unmarked cells were hidden (a check that the segments can find what hides), and
    /// how many of those belong to a triangle with a hider list.
    fn check_marked_cells_are_clear(
        lights: &TriangleSoup,
        object: [Vec3; 2],
        want_share: f64,
    ) -> (usize, usize) {
        let cover = light_cover(lights, Some(object));
        let tris: Vec<[DVec3; 3]> = lights
            .triangles
            .iter()
            .map(|t| t.map(|i| lights.positions[i as usize].as_dvec3()))
            .collect();
        let marked: usize = cover.masks.iter().map(|m| m.count_ones() as usize).sum();
        let share = marked as f64 / (tris.len() * LIGHT_COVER_CELLS as usize) as f64;
        assert!(share >= want_share, "only {share:.3} of the cells marked");
        let mut state = 0x9e3779b97f4a7c15u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let side = LIGHT_COVER_SIDE as usize;
        let (lo, cell) = (cover.lo.as_dvec3(), cover.cell.as_dvec3());
        let mut tested = 0;
        let mut hidden_unmarked = 0;
        let mut hidden_listed = 0;
        for (j, t) in tris.iter().enumerate() {
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            for c in 0..LIGHT_COVER_CELLS as usize {
                let marked = cover.masks[j] & (1 << c) != 0;
                let a = lo
                    + cell
                        * DVec3::new(
                            (c % side) as f64,
                            (c / side % side) as f64,
                            (c / side / side) as f64,
                        );
                for _ in 0..24 {
                    let x = a + cell * DVec3::new(uniform(), uniform(), uniform());
                    let (s, r) = (uniform().sqrt(), uniform());
                    let y = t[0] * (1.0 - s) + t[1] * (s * (1.0 - r)) + t[2] * (s * r);
                    if n.dot(x - y) <= 0.0 {
                        continue;
                    }
                    let hiding: Vec<usize> = (0..tris.len())
                        .filter(|&k| {
                            k != j && cross_at(x, y, &tris[k]).is_some_and(|w| w < 1.0 - 1e-9)
                        })
                        .collect();
                    let hit = !hiding.is_empty();
                    if marked {
                        tested += 1;
                        assert!(!hit, "triangle {j}, cell {c}: marked but hidden from {x}");
                    } else if hit {
                        hidden_unmarked += 1;
                        let list = &cover.hiders[j];
                        if !list.is_empty() {
                            hidden_listed += 1;
                            for k in &hiding {
                                assert!(
                                    list.contains(&(*k as u32)),
                                    "triangle {j}, cell {c}: hidden from {x} by {k}, not in {list:?}"
                                );
                            }
                        }
                    }
                }
            }
        }
        assert!(tested > 200, "only {tested} segments from marked cells");
        for (j, list) in cover.hiders.iter().enumerate() {
            assert!(list.len() <= MAX_HIDERS && list.windows(2).all(|w| w[0] < w[1]));
            assert!(!list.contains(&(j as u32)));
            assert!(list.is_empty() || cover.masks[j] != ALL_CELLS);
        }
        (hidden_unmarked, hidden_listed)
    }

    #[test]
    fn a_ring_above_a_table_is_marked_where_it_is_clear() {
        // The demo's ring (30 / 5 mm) 250 mm above a 400 mm table holding a small part.
        let lights = ring(30.0, 5.0, 48, 12, Vec3::new(0.0, 0.0, 250.0), Vec3::Z);
        let object = [
            Vec3::new(-200.0, -200.0, -1.0),
            Vec3::new(200.0, 200.0, 40.0),
        ];
        check_marked_cells_are_clear(&lights, object, 0.5);
    }

    #[test]
    fn a_ring_close_over_a_part_lists_what_can_hide_each_triangle() {
        // The demo's ring (30 / 5 mm) close over a part: from some cells the tube's inner
        // face is seen at grazing angles, hidden by its neighbours, few of them each.
        let lights = ring(30.0, 5.0, 48, 12, Vec3::new(0.0, 0.0, 60.0), Vec3::Z);
        let object = [Vec3::new(-30.0, -30.0, 0.0), Vec3::new(30.0, 30.0, 30.0)];
        let (hidden, listed) = check_marked_cells_are_clear(&lights, object, 0.5);
        assert!(
            hidden > 0 && listed > 0,
            "{hidden} hidden segments, {listed} listed"
        );
    }

    #[test]
    fn the_seen_box_is_the_part_of_the_box_in_the_image() {
        // A camera 300 mm above the table looking straight down sees a patch of it.
        let cam = Camera::look(Vec3::new(0.0, 0.0, 300.0), -Vec3::Z, Vec3::Y, 10.0, 64, 48);
        let object = [
            Vec3::new(-200.0, -200.0, 0.0),
            Vec3::new(200.0, 200.0, 50.0),
        ];
        let [lo, hi] = seen_box(&cam, object).expect("the table is in view");
        assert!(lo.cmpge(object[0]).all() && hi.cmple(object[1]).all());
        assert!(hi.x - lo.x < 200.0 && hi.x - lo.x > 50.0, "{lo} {hi}");
        // Every lattice point that projects into the image lies inside.
        for p in [Vec3::new(0.0, 0.0, 0.0), Vec3::new(30.0, 20.0, 10.0)] {
            let q = cam.project(p).unwrap();
            assert!(q.x >= 0.0 && q.x <= 64.0 && q.y >= 0.0 && q.y <= 48.0);
            assert!(p.cmpge(lo).all() && p.cmple(hi).all());
        }
        // Looking away: nothing.
        let away = Camera::look(Vec3::new(0.0, 0.0, 300.0), Vec3::Z, Vec3::Y, 10.0, 64, 48);
        assert_eq!(seen_box(&away, object), None);
    }

    #[test]
    fn a_ring_close_to_a_wide_object_is_marked_where_it_is_clear() {
        // A ring tilted and close to a tall wide object: much of it can hide itself.
        let lights = ring(
            40.0,
            12.0,
            24,
            8,
            Vec3::new(10.0, -5.0, 60.0),
            Vec3::new(0.3, 0.1, 1.0),
        );
        let object = [Vec3::new(-80.0, -60.0, -20.0), Vec3::new(70.0, 90.0, 30.0)];
        assert!(check_marked_cells_are_clear(&lights, object, 0.1).0 > 0);
    }

    #[test]
    fn a_panel_does_not_hide_itself() {
        let lights = TriangleSoup {
            positions: vec![
                Vec3::new(-50.0, -50.0, 200.0),
                Vec3::new(50.0, -50.0, 200.0),
                Vec3::new(50.0, 50.0, 200.0),
                Vec3::new(-50.0, 50.0, 200.0),
                Vec3::new(0.0, 0.0, 200.0),
            ],
            // Facing down (-z), fanned about the centre.
            triangles: vec![[4, 1, 0], [4, 2, 1], [4, 3, 2], [4, 0, 3]],
        };
        let cover = light_cover(
            &lights,
            Some([
                Vec3::new(-100.0, -100.0, 0.0),
                Vec3::new(100.0, 100.0, 20.0),
            ]),
        );
        assert_eq!(cover.masks, vec![ALL_CELLS; 4]);
    }

    #[test]
    fn a_light_standing_in_front_of_another_hides_it() {
        // A small panel hanging between a big one and the object: the big one's
        // triangles under it are not marked for the cells below it.
        let mut positions = vec![
            Vec3::new(-100.0, -100.0, 300.0),
            Vec3::new(100.0, -100.0, 300.0),
            Vec3::new(100.0, 100.0, 300.0),
            Vec3::new(-100.0, 100.0, 300.0),
        ];
        positions.extend([
            Vec3::new(-10.0, -10.0, 150.0),
            Vec3::new(10.0, -10.0, 150.0),
            Vec3::new(10.0, 10.0, 150.0),
            Vec3::new(-10.0, 10.0, 150.0),
        ]);
        let lights = TriangleSoup {
            positions,
            triangles: vec![[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]],
        };
        let object = [Vec3::new(-50.0, -50.0, 0.0), Vec3::new(50.0, 50.0, 10.0)];
        let cover = light_cover(&lights, Some(object));
        assert_eq!(cover.masks[0], 0);
        assert_eq!(cover.masks[1], 0);
        assert_eq!(cover.masks[2], ALL_CELLS);
        assert!(check_marked_cells_are_clear(&lights, object, 0.0).0 > 0);
    }

    #[test]
    fn a_rings_room_holds_its_triangles_and_its_hole_is_empty() {
        let (centre, axis) = (
            Vec3::new(5.0, -3.0, 80.0),
            Vec3::new(0.2, 0.1, 1.0).normalize(),
        );
        let lights = ring(30.0, 5.0, 32, 8, centre, axis);
        let tris: Vec<[Vec3; 3]> = lights
            .triangles
            .iter()
            .map(|t| t.map(|i| lights.positions[i as usize]))
            .collect();
        let [hole, half] = ring_room(&tris, centre, axis);
        // The torus's own bounds, less the chords' sag (at most 30 (1 - cos(pi / 32)) =
        // 0.14 mm inwards) and the slack.
        assert!(hole > 24.8 && hole < 25.0, "{hole}");
        assert!((5.0..5.02).contains(&half), "{half}");
        // Points of the triangles lie outside the hole and inside the slab; the hole is
        // tight (some point within 0.05 mm of it).
        let mut nearest = f32::INFINITY;
        for t in &tris {
            for (u, v) in [
                (0.0, 0.0),
                (1.0, 0.0),
                (0.0, 1.0),
                (0.5, 0.5),
                (0.5, 0.0),
                (0.0, 0.5),
                (0.3, 0.3),
            ] {
                let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v - centre;
                let z = p.dot(axis);
                let radial = (p - axis * z).length();
                assert!(radial >= hole && z.abs() <= half, "{radial} {z}");
                nearest = nearest.min(radial);
            }
        }
        assert!(nearest - hole < 0.05, "{nearest} {hole}");
        assert_eq!(ring_room(&[], centre, axis), [0.0, 0.0]);
        assert_eq!(
            distance_to_origin([
                glam::DVec2::new(-1.0, -1.0),
                glam::DVec2::new(2.0, -1.0),
                glam::DVec2::new(-1.0, 2.0)
            ]),
            0.0
        );
        let d = distance_to_origin([
            glam::DVec2::new(1.0, -1.0),
            glam::DVec2::new(1.0, 1.0),
            glam::DVec2::new(3.0, 0.0),
        ]);
        assert!((d - 1.0).abs() < 1e-12, "{d}");
    }

    #[test]
    fn no_box_marks_nothing() {
        let lights = ring(30.0, 5.0, 8, 4, Vec3::ZERO, Vec3::Z);
        assert!(light_cover(&lights, None).masks.iter().all(|&m| m == 0));
    }
}
