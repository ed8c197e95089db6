//! The built-in test body (variants B and M) and per-face frames for any labelled mesh.
//!
//! We have no CAD file of the paper's test bodies, so the body is built procedurally as a
//! convex polyhedron: a 50 x 50 x 50 mm block standing on the table (z = 0) with three
//! cuts, each of which carries one inspected 20 x 20 mm square:
//! - A: a 45-degree chamfer along the top edge at +y (facing +y and up),
//! - B: a chamfer of the vertical edge at (+x, -y) (facing sideways),
//! - C: a corner cut at (-x, -y, top) (normal (-1, -1, 1) / sqrt 3).
//!
//! The arrangement is chiral, so M (the mirror image across the plane x = 0) is a
//! different body, as in the paper. See docs/testbody.md.

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::mesh::{FACE_A, FACE_B, FACE_C, FACE_OTHER, FaceId, Mesh, TriLabel};

/// Edge length of the inspected squares, mm.
pub const INSPECTED_SIZE_MM: f64 = 20.0;

/// Which test body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// The base body.
    B,
    /// The mirror image of B across the vertical plane x = 0.
    M,
}

/// A planar face's placement, for planar texture projection and face-local coordinates.
///
/// `u` is the up-slope direction: world +Z projected into the face plane; for faces
/// within about 8 degrees of horizontal (|n.z| > 0.99), world +X projected instead.
/// `v = normal x u`, so (u, v, normal) is right-handed. The rule depends only on the
/// normal, so the same face of another copy of the object gets the same frame, and a
/// mirrored face gets the mirrored u (and a v that is the negated mirror of v).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceFrame {
    pub face: FaceId,
    /// Area-weighted centroid of the face's triangles.
    pub centre: Vec3,
    /// Area-weighted outward unit normal.
    pub normal: Vec3,
    pub u: Vec3,
    pub v: Vec3,
    /// Half extent of the face's vertices along u and v, measured from `centre`
    /// (the larger of the two sides, so the square [-h, h] covers the face).
    pub half_size: Vec2,
    /// Total triangle area of the face, mm^2.
    pub area: f32,
}

/// The in-plane frame (u, v) for a unit normal, by the rule documented on [`FaceFrame`].
pub fn frame_axes(normal: DVec3) -> (DVec3, DVec3) {
    let reference = if normal.z.abs() > 0.99 {
        DVec3::X
    } else {
        DVec3::Z
    };
    let u = (reference - normal * reference.dot(normal)).normalize();
    let v = normal.cross(u);
    (u, v)
}

/// Frames of every inspected face (face id 1, 2, 3) present in `mesh`, in face-id order.
/// Faces with zero total area are skipped.
pub fn face_frames(mesh: &Mesh) -> Vec<FaceFrame> {
    let mut out = Vec::new();
    for face in [FACE_A, FACE_B, FACE_C] {
        let tris: Vec<usize> = (0..mesh.triangles.len())
            .filter(|&t| mesh.labels[t].face == face)
            .collect();
        let mut area_normal = DVec3::ZERO;
        let mut weighted = DVec3::ZERO;
        let mut area = 0.0;
        for &t in &tris {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let n = (b - a).cross(c - a);
            let da = 0.5 * n.length();
            area_normal += n;
            weighted += (a + b + c) / 3.0 * da;
            area += da;
        }
        if !(area > 0.0) || area_normal.length_squared() == 0.0 {
            continue;
        }
        let centre = weighted / area;
        let normal = area_normal.normalize();
        let (u, v) = frame_axes(normal);
        let mut half = DVec2::ZERO;
        for &t in &tris {
            for p in mesh.corners(t) {
                let d = p.as_dvec3() - centre;
                half = half.max(DVec2::new(d.dot(u).abs(), d.dot(v).abs()));
            }
        }
        out.push(FaceFrame {
            face,
            centre: centre.as_vec3(),
            normal: normal.as_vec3(),
            u: u.as_vec3(),
            v: v.as_vec3(),
            half_size: half.as_vec2(),
            area: area as f32,
        });
    }
    out
}

/// A half-space n.x <= d; `face` labels the inspected square cut into its face.
struct Plane {
    n: DVec3,
    d: f64,
    face: FaceId,
}

fn plane(n: DVec3, d_unnormalised: f64, face: FaceId) -> Plane {
    let len = n.length();
    Plane {
        n: n / len,
        d: d_unnormalised / len,
        face,
    }
}

/// The half-spaces bounding variant B. Offsets chosen so every cut face is large enough
/// for a centred 20 mm square with at least 2 mm to spare, and no four planes meet in a
/// point (which would leave collinear vertices and zero-area triangles).
fn planes_b() -> Vec<Plane> {
    vec![
        plane(DVec3::X, 25.0, FACE_OTHER),
        plane(DVec3::NEG_X, 25.0, FACE_OTHER),
        plane(DVec3::Y, 25.0, FACE_OTHER),
        plane(DVec3::NEG_Y, 25.0, FACE_OTHER),
        plane(DVec3::Z, 50.0, FACE_OTHER),
        plane(DVec3::NEG_Z, 0.0, FACE_OTHER),
        // A: top edge at +y, 45 degrees, legs of 24 mm.
        plane(DVec3::new(0.0, 1.0, 1.0), 51.0, FACE_A),
        // B: vertical edge at (+x, -y), legs of 24 mm.
        plane(DVec3::new(1.0, -1.0, 0.0), 26.0, FACE_B),
        // C: corner at (-x, -y, top), legs of 40 mm.
        plane(DVec3::new(-1.0, -1.0, 1.0), 60.0, FACE_C),
    ]
}

/// Keeps the part of a convex polygon with n.p <= d.
fn clip(poly: &[DVec3], n: DVec3, d: f64) -> Vec<DVec3> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let a = poly[i];
        let b = poly[(i + 1) % poly.len()];
        let da = n.dot(a) - d;
        let db = n.dot(b) - d;
        if da <= 0.0 {
            out.push(a);
        }
        if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
            out.push(a + (b - a) * (da / (da - db)));
        }
    }
    out
}

/// Index of `p` in `verts`, merging points closer than 1e-6 mm (clipping computes a
/// shared corner once per face, with rounding differences).
fn vertex_id(verts: &mut Vec<DVec3>, p: DVec3) -> u32 {
    if let Some(i) = verts.iter().position(|q| q.distance_squared(p) < 1e-12) {
        return i as u32;
    }
    verts.push(p);
    (verts.len() - 1) as u32
}

fn cross2(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether `p` lies in the closed triangle (a, b, c), counter-clockwise.
fn in_triangle(p: DVec2, a: DVec2, b: DVec2, c: DVec2) -> bool {
    cross2(b - a, p - a) >= -1e-12
        && cross2(c - b, p - b) >= -1e-12
        && cross2(a - c, p - c) >= -1e-12
}

/// Ear clipping of a counter-clockwise (weakly simple) polygon; `ids` are vertex ids,
/// equal ids mark the two copies of a bridge vertex.
fn ear_clip(pts: &[DVec2], ids: &[u32]) -> Vec<[u32; 3]> {
    let mut ring: Vec<usize> = (0..pts.len()).collect();
    let mut out = Vec::new();
    while ring.len() > 3 {
        let m = ring.len();
        let ear = (0..m).find(|&k| {
            let (p, c, n) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
            if cross2(pts[c] - pts[p], pts[n] - pts[c]) <= 1e-9 {
                return false;
            }
            ring.iter().all(|&q| {
                let same = ids[q] == ids[p] || ids[q] == ids[c] || ids[q] == ids[n];
                same || !in_triangle(pts[q], pts[p], pts[c], pts[n])
            })
        });
        let k = ear.expect("the built-in test body's faces are simple polygons");
        let (p, c, n) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
        out.push([ids[p], ids[c], ids[n]]);
        ring.remove(k);
    }
    out.push([ids[ring[0]], ids[ring[1]], ids[ring[2]]]);
    out
}

/// Builds the test body. Coarse: each face polygon is ear-clipped; an inspected face is
/// the 20 mm square (two triangles, labelled) plus the ring around it (face 0).
pub fn testbody(variant: Variant) -> Mesh {
    let planes = planes_b();
    let mut verts: Vec<DVec3> = Vec::new();
    let mut mesh = Mesh::default();
    for (i, pl) in planes.iter().enumerate() {
        let (u, v) = frame_axes(pl.n);
        let c0 = pl.n * pl.d;
        let big = 500.0;
        let mut poly: Vec<DVec3> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .map(|&(a, b)| c0 + u * (a * big) + v * (b * big))
            .collect();
        for (j, other) in planes.iter().enumerate() {
            if j != i {
                poly = clip(&poly, other.n, other.d);
            }
        }
        let mut ids: Vec<u32> = poly.iter().map(|&p| vertex_id(&mut verts, p)).collect();
        ids.dedup();
        while ids.len() > 1 && ids.first() == ids.last() {
            ids.pop();
        }
        if ids.len() < 3 {
            continue;
        }
        let to2 = |p: DVec3| DVec2::new(p.dot(u), p.dot(v));
        let other = TriLabel {
            face: FACE_OTHER,
            ..TriLabel::default()
        };
        if pl.face == FACE_OTHER {
            let pts: Vec<DVec2> = ids.iter().map(|&k| to2(verts[k as usize])).collect();
            for t in ear_clip(&pts, &ids) {
                mesh.triangles.push(t);
                mesh.labels.push(other);
            }
            continue;
        }
        // Centre the square on the polygon's area centroid.
        let pts: Vec<DVec2> = ids.iter().map(|&k| to2(verts[k as usize])).collect();
        let (mut a2, mut c2) = (0.0, DVec2::ZERO);
        for k in 0..pts.len() {
            let (p, q) = (pts[k], pts[(k + 1) % pts.len()]);
            let w = cross2(p, q);
            a2 += w;
            c2 += (p + q) * w;
        }
        let centre2 = c2 / (3.0 * a2);
        let centre = c0 + u * (centre2.x - c0.dot(u)) + v * (centre2.y - c0.dot(v));
        let s = INSPECTED_SIZE_MM / 2.0;
        let square: Vec<u32> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .map(|&(a, b)| vertex_id(&mut verts, centre + u * (a * s) + v * (b * s)))
            .collect();
        let label = TriLabel {
            face: pl.face,
            ..TriLabel::default()
        };
        for t in [
            [square[0], square[1], square[2]],
            [square[0], square[2], square[3]],
        ] {
            mesh.triangles.push(t);
            mesh.labels.push(label);
        }
        // Ring: outer polygon bridged to the square (hole, clockwise) from the square's
        // corner furthest along +u to the outer corner furthest along +u. Both are
        // extreme in that direction, so the bridge lies beyond the square and inside
        // the convex outer polygon.
        let furthest = |list: &[u32]| {
            (0..list.len())
                .max_by(|&a, &b| {
                    let pa = verts[list[a] as usize].dot(u);
                    let pb = verts[list[b] as usize].dot(u);
                    pa.total_cmp(&pb)
                })
                .unwrap_or(0)
        };
        let ko = furthest(&ids);
        let hole_cw: Vec<u32> = square.iter().rev().copied().collect();
        let kh = furthest(&hole_cw);
        let mut seq: Vec<u32> = Vec::new();
        seq.extend(ids[ko..].iter().chain(&ids[..ko]));
        seq.push(ids[ko]);
        seq.extend(hole_cw[kh..].iter().chain(&hole_cw[..kh]));
        seq.push(hole_cw[kh]);
        let pts: Vec<DVec2> = seq.iter().map(|&k| to2(verts[k as usize])).collect();
        for t in ear_clip(&pts, &seq) {
            mesh.triangles.push(t);
            mesh.labels.push(other);
        }
    }
    mesh.positions = verts.iter().map(|p| p.as_vec3()).collect();
    group_by_label(&mut mesh);
    match variant {
        Variant::B => mesh,
        Variant::M => mirror_x(&mesh),
    }
}

/// Orders triangles by label (first appearance first), as glTF export groups them, so
/// an exported and re-imported body equals the generated one triangle for triangle.
fn group_by_label(mesh: &mut Mesh) {
    let mut order: Vec<TriLabel> = Vec::new();
    for l in &mesh.labels {
        if !order.contains(l) {
            order.push(*l);
        }
    }
    let mut idx: Vec<usize> = (0..mesh.triangles.len()).collect();
    idx.sort_by_key(|&t| order.iter().position(|l| *l == mesh.labels[t]));
    mesh.triangles = idx.iter().map(|&t| mesh.triangles[t]).collect();
    mesh.labels = idx.iter().map(|&t| mesh.labels[t]).collect();
}

/// Mirror image across the plane x = 0, windings reversed so normals stay outward.
pub fn mirror_x(mesh: &Mesh) -> Mesh {
    Mesh {
        positions: mesh
            .positions
            .iter()
            .map(|p| Vec3::new(-p.x, p.y, p.z))
            .collect(),
        triangles: mesh.triangles.iter().map(|&[a, b, c]| [a, c, b]).collect(),
        labels: mesh.labels.clone(),
    }
}
