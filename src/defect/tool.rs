//! Defecting tools as height fields over a face: the analytic surface a true Boolean
//! difference would leave, evaluated at face-local (u, v).

use glam::DVec2;

use super::region::{Region, point_segment_distance, segment_segment_distance};
use super::sample::{Defect, Shape};
use super::spec::ScratchProfile;

/// The point of segment [a, b] nearest to p: its parameter t in [0, 1] along the segment
/// and its squared distance to p.
fn nearest_on_segment(p: DVec2, a: DVec2, b: DVec2) -> (f64, f64) {
    let e = b - a;
    let l2 = e.length_squared();
    let t = if l2 > 0.0 {
        ((p - a).dot(e) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (t, (p - (a + e * t)).length_squared())
}

/// How far below the face a scratch of `profile`, centre depth `dep` and half-width `r`
/// reaches at squared distance `dist2 < r^2` from its path.
fn scratch_depth_at(profile: ScratchProfile, dep: f64, r: f64, dist2: f64) -> f64 {
    match profile {
        ScratchProfile::Parabolic => dep * (1.0 - dist2 / (r * r)),
        // The circle through the groove's edges (+-r, 0) and its bottom (0, -dep): radius
        // R = (r^2 + dep^2) / (2 dep), centre R - dep above the bottom.
        ScratchProfile::Round => {
            if dep <= 0.0 {
                return 0.0;
            }
            let big_r = (r * r + dep * dep) / (2.0 * dep);
            ((big_r * big_r - dist2).max(0.0).sqrt() - (big_r - dep)).max(0.0)
        }
    }
}

/// A defect compiled for fast evaluation. Heights are along the face normal, in mm:
/// negative below the face (removed material), positive for a raised rim, 0 outside.
#[derive(Clone, Debug)]
pub struct DefectTool {
    pub class: u8,
    pub instance: u16,
    /// Target mesh edge length inside the footprint, mm.
    pub edge_mm: f64,
    /// Bounding box of the footprint (rim included) in (u, v).
    pub lo: DVec2,
    pub hi: DVec2,
    kind: Kind,
}

#[derive(Clone, Debug)]
enum Kind {
    Dent {
        c: DVec2,
        cos: f64,
        sin: f64,
        a: f64,
        b: f64,
        depth: f64,
        rim_h: f64,
        rim_w: f64,
    },
    Scratch {
        pts: Vec<DVec2>,
        depth: Vec<f64>,
        r: f64,
        profile: ScratchProfile,
        /// How the anisotropic mesh follows the path (docs/defects.md, "Imprint").
        along: Box<Along>,
    },
}

/// Anisotropic meshing of a scratch: rows of vertices at fixed offsets from the path
/// (`levels`), triangles between them up to `along` long, finer where the path bends,
/// where the depth's slope changes, at the ends and where the path comes back near
/// itself.
#[derive(Clone, Debug)]
struct Along {
    /// Offsets from the path (mm, signed) of the rows of vertices, ascending.
    levels: Vec<f64>,
    /// Longest edge along a straight, evenly sloped stretch of the path, mm.
    max_mm: f64,
    /// Longest edge within `2 r` of each path point, mm.
    at_point: Vec<f64>,
    /// Segments the path comes back near (isotropic there: the offset field has a ridge).
    fine: Vec<bool>,
    /// Arc length at each path point, mm.
    cum: Vec<f64>,
}

/// Row spacing across a scratch, as a fraction of the target edge `width / resolution`:
/// a bisected right triangle with that hypotenuse has legs of 0.71 and height 0.5 of it,
/// so rows at half the target edge sample the profile as densely as the isotropic mesh.
pub const ROW_SPACING: f64 = 0.5;
/// Longest edge along a scratch as a multiple of the target edge (the anisotropy cap).
pub const ALONG_MAX_RATIO: f64 = 32.0;
/// Where the path turns by an angle phi, the rows (interpolated offsets) bend off their
/// true offset by about `edge * phi / 4`; the edge is limited so that this stays below
/// this fraction of the row spacing.
pub const ROW_TOLERANCE: f64 = 0.5;
/// Where the depth's slope along the path changes by `ds`, a linear piece of length
/// `edge` misses the depth by up to `edge * ds / 4`; the edge is limited so that this
/// stays below this fraction of the local depth.
pub const DEPTH_TOLERANCE: f64 = 0.01;

/// The rows across a scratch (see [`Along`]): `n` intervals per side, spacing at most
/// `q`. Parabolic: even rows, the outermost `e = h / (3 (2 - h / r))` (h the spacing)
/// outside the rim, so the triangles straddling the rim remove what the chords inside
/// leave (the linear interpolant then removes the parabola's exact cross-section).
/// Round: rows evenly spaced in angle along the arc (steep walls get denser rows), the
/// outermost just outside the rim.
fn scratch_levels(profile: ScratchProfile, r: f64, max_depth: f64, q: f64) -> Vec<f64> {
    let n = (r / q).ceil().max(1.0) as usize;
    let mut half: Vec<f64> = match profile {
        ScratchProfile::Parabolic => {
            let h = r / n as f64;
            let e = h / (3.0 * (2.0 - h / r));
            (1..=n)
                .map(|j| if j == n { r + e } else { j as f64 * h })
                .collect()
        }
        ScratchProfile::Round => {
            if max_depth <= 0.0 {
                (1..=n).map(|j| j as f64 * r / n as f64).collect()
            } else {
                let big_r = (r * r + max_depth * max_depth) / (2.0 * max_depth);
                let theta = (r / big_r).clamp(-1.0, 1.0).asin();
                let m = n.max((big_r * theta / q).ceil() as usize);
                // The outermost row a twentieth of the last spacing outside the rim: a
                // vertex exactly on a steep rim would land inside it after f32 rounding.
                let inner = big_r * (theta * (m - 1) as f64 / m as f64).sin();
                (1..=m)
                    .map(|j| {
                        if j == m {
                            r + 0.05 * (r - inner)
                        } else {
                            big_r * (theta * j as f64 / m as f64).sin()
                        }
                    })
                    .collect()
            }
        }
    };
    let mut levels: Vec<f64> = half.iter().rev().map(|&s| -s).collect();
    levels.push(0.0);
    levels.append(&mut half);
    levels
}

impl Along {
    fn new(pts: &[DVec2], depth: &[f64], r: f64, profile: ScratchProfile, edge: f64) -> Along {
        let max_depth = depth.iter().copied().fold(0.0, f64::max);
        let levels = scratch_levels(profile, r, max_depth, ROW_SPACING * edge);
        let max_mm = ALONG_MAX_RATIO * edge;
        let row = ROW_SPACING * edge;
        let n = pts.len();
        let mut at_point = vec![max_mm; n];
        for k in 1..n.saturating_sub(1) {
            let (e0, e1) = (pts[k] - pts[k - 1], pts[k + 1] - pts[k]);
            let (l0, l1) = (e0.length(), e1.length());
            let mut h = max_mm;
            if l0 > 0.0 && l1 > 0.0 {
                let phi = e0.angle_to(e1).abs();
                if phi > 0.0 {
                    h = h.min(4.0 * ROW_TOLERANCE * row / phi);
                }
                let dslope =
                    ((depth[k + 1] - depth[k]) / l1 - (depth[k] - depth[k - 1]) / l0).abs();
                if dslope > 0.0 {
                    h = h.min(4.0 * DEPTH_TOLERANCE * depth[k] / dslope);
                }
            } else {
                h = edge;
            }
            at_point[k] = h.max(edge);
        }
        // Ends (the rounded caps: isotropic).
        if n > 0 {
            at_point[0] = edge;
            at_point[n - 1] = edge;
        }
        let fine = self_approach(pts, 2.0 * (r + max_mm), 4.0 * (r + max_mm));
        let mut cum = vec![0.0; n];
        for i in 1..n {
            cum[i] = cum[i - 1] + (pts[i] - pts[i - 1]).length();
        }
        Along {
            levels,
            max_mm,
            at_point,
            fine,
            cum,
        }
    }
}

/// Segments of the polyline that come within `dist` of another part of the path whose
/// nearest point lies more than `arc` away along the path (a hairpin or a loop, not a
/// bend: around a bend of up to 120 degrees, points within `dist` of each other are less
/// than `dist` apart along the path). Bucketed on a grid, so long paths stay cheap.
fn self_approach(pts: &[DVec2], dist: f64, arc: f64) -> Vec<bool> {
    let nseg = pts.len().saturating_sub(1);
    let mut fine = vec![false; nseg];
    if nseg < 2 {
        return fine;
    }
    let mut cum = vec![0.0; pts.len()];
    for i in 1..pts.len() {
        cum[i] = cum[i - 1] + (pts[i] - pts[i - 1]).length();
    }
    // Distance from `p` to segment k, and the arc length of the nearest point.
    let on = |p: DVec2, k: usize| -> (f64, f64) {
        let (t, d2) = nearest_on_segment(p, pts[k], pts[k + 1]);
        (d2.sqrt(), cum[k] + t * (cum[k + 1] - cum[k]))
    };
    let longest = pts
        .windows(2)
        .map(|w| (w[1] - w[0]).length())
        .fold(0.0, f64::max);
    let cell = longest.max(dist).max(1e-9);
    let key = |p: DVec2| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
    let mut grid: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    for i in 0..nseg {
        let (lo, hi) = (
            key(pts[i].min(pts[i + 1]) - DVec2::splat(dist)),
            key(pts[i].max(pts[i + 1]) + DVec2::splat(dist)),
        );
        for x in lo.0..=hi.0 {
            for y in lo.1..=hi.1 {
                grid.entry((x, y)).or_default().push(i);
            }
        }
    }
    for i in 0..nseg {
        let (lo, hi) = (key(pts[i].min(pts[i + 1])), key(pts[i].max(pts[i + 1])));
        let mut cands: Vec<usize> = Vec::new();
        for x in lo.0..=hi.0 {
            for y in lo.1..=hi.1 {
                cands.extend(grid.get(&(x, y)).into_iter().flatten());
            }
        }
        cands.sort_unstable();
        cands.dedup();
        for j in cands {
            if j <= i + 1
                || segment_segment_distance(pts[i], pts[i + 1], pts[j], pts[j + 1]) >= dist
            {
                continue;
            }
            // Some point of one segment within `dist` of the other, and how far apart
            // along the path the two nearest points are (the smallest such separation
            // over the segments' ends; crossing segments are far apart along the path).
            let mut gap = f64::INFINITY;
            for (p, arc_p, k) in [
                (pts[i], cum[i], j),
                (pts[i + 1], cum[i + 1], j),
                (pts[j], cum[j], i),
                (pts[j + 1], cum[j + 1], i),
            ] {
                let (d, arc_q) = on(p, k);
                if d < dist {
                    gap = gap.min((arc_p - arc_q).abs());
                }
            }
            if gap == f64::INFINITY {
                // They cross (or approach) between their ends.
                gap = cum[j] - cum[i + 1];
            }
            if gap > arc {
                fine[i] = true;
                fine[j] = true;
            }
        }
    }
    fine
}

impl DefectTool {
    /// `resolution`: vertices across the defect's narrowest dimension (see DefectSpec).
    pub fn new(d: &Defect, resolution: f64) -> DefectTool {
        match &d.shape {
            Shape::Dent(s) => {
                let a = 0.5 * s.diameter_mm;
                let b = 0.5 * s.minor_mm;
                let (sin, cos) = s.rotation_deg.to_radians().sin_cos();
                let rim_h = s.rim_height_mm;
                let rim_w = if rim_h > 0.0 { s.rim_width } else { 0.0 };
                let c = DVec2::from(s.centre_uv_mm);
                let reach = a * (1.0 + rim_w);
                DefectTool {
                    class: d.class,
                    instance: d.instance,
                    edge_mm: 2.0 * b / resolution,
                    lo: c - DVec2::splat(reach),
                    hi: c + DVec2::splat(reach),
                    kind: Kind::Dent {
                        c,
                        cos,
                        sin,
                        a,
                        b,
                        depth: s.depth_mm,
                        rim_h,
                        rim_w,
                    },
                }
            }
            Shape::Scratch(s) => {
                let pts: Vec<DVec2> = s.path_uv_mm.iter().map(|&p| DVec2::from(p)).collect();
                let r = 0.5 * s.width_mm;
                let (mut lo, mut hi) =
                    (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
                for &p in &pts {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
                DefectTool {
                    class: d.class,
                    instance: d.instance,
                    edge_mm: s.width_mm / resolution,
                    lo: lo - DVec2::splat(r),
                    hi: hi + DVec2::splat(r),
                    kind: Kind::Scratch {
                        along: Box::new(Along::new(
                            &pts,
                            &s.depth_mm,
                            r,
                            s.profile,
                            s.width_mm / resolution,
                        )),
                        pts,
                        depth: s.depth_mm.clone(),
                        r,
                        profile: s.profile,
                    },
                }
            }
        }
    }

    fn in_box(&self, p: DVec2, pad: f64) -> bool {
        p.x >= self.lo.x - pad
            && p.y >= self.lo.y - pad
            && p.x <= self.hi.x + pad
            && p.y <= self.hi.y + pad
    }

    /// Height of the tool's imprint at `p`.
    pub fn height(&self, p: DVec2) -> f64 {
        if !self.in_box(p, 0.0) {
            return 0.0;
        }
        match &self.kind {
            &Kind::Dent {
                c,
                cos,
                sin,
                a,
                b,
                depth,
                rim_h,
                rim_w,
            } => {
                let d = p - c;
                let x = (d.x * cos + d.y * sin) / a;
                let y = (-d.x * sin + d.y * cos) / b;
                let rho2 = x * x + y * y;
                if rho2 < 1.0 {
                    -depth * (1.0 - rho2).sqrt()
                } else if rim_w > 0.0 && rho2 < (1.0 + rim_w) * (1.0 + rim_w) {
                    let t = (rho2.sqrt() - 1.0) / rim_w;
                    rim_h * 0.5 * (1.0 - (std::f64::consts::TAU * t).cos())
                } else {
                    0.0
                }
            }
            Kind::Scratch {
                pts,
                depth,
                r,
                profile,
                ..
            } => {
                let r = *r;
                let mut h = 0.0f64;
                for i in 0..pts.len().saturating_sub(1) {
                    let (a, b) = (pts[i], pts[i + 1]);
                    if p.x < a.x.min(b.x) - r
                        || p.x > a.x.max(b.x) + r
                        || p.y < a.y.min(b.y) - r
                        || p.y > a.y.max(b.y) + r
                    {
                        continue;
                    }
                    let (t, dist2) = nearest_on_segment(p, a, b);
                    if dist2 < r * r {
                        let dep = depth[i] + (depth[i + 1] - depth[i]) * t;
                        h = h.min(-scratch_depth_at(*profile, dep, r, dist2));
                    }
                }
                h
            }
        }
    }

    /// Conservative: false only if the footprint is farther than `radius` from `p`.
    pub fn near(&self, p: DVec2, radius: f64) -> bool {
        if !self.in_box(p, radius) {
            return false;
        }
        match &self.kind {
            &Kind::Dent {
                c,
                cos,
                sin,
                a,
                b,
                rim_w,
                ..
            } => {
                let d = p - c;
                let x = (d.x * cos + d.y * sin) / a;
                let y = (-d.x * sin + d.y * cos) / b;
                // Normalising by (a, b) shrinks distances by at most 1/b, so
                // (|q| - outer) * b is a lower bound of the true distance.
                ((x * x + y * y).sqrt() - (1.0 + rim_w)) * b <= radius
            }
            Kind::Scratch { pts, r, .. } => {
                let reach = r + radius;
                pts.windows(2).any(|w| {
                    let (a, b) = (w[0], w[1]);
                    !(p.x < a.x.min(b.x) - reach
                        || p.x > a.x.max(b.x) + reach
                        || p.y < a.y.min(b.y) - reach
                        || p.y > a.y.max(b.y) + reach)
                        && point_segment_distance(p, a, b) <= reach
                }) || (pts.len() == 1 && (p - pts[0]).length() <= reach)
            }
        }
    }

    /// The longest edge a triangle with centroid `p` and circumradius-like `radius`
    /// may have, or None if it is farther than `radius` from the footprint. Dents (and
    /// scratches with `anisotropic = false`): the target edge everywhere near the
    /// footprint. Scratches meshed anisotropically: the along-path length (the rows of
    /// [`Self::slice_levels`] then give the resolution across), finer near bends, depth
    /// kinks, the ends and self-approaches.
    pub(crate) fn edge_near(&self, p: DVec2, radius: f64, anisotropic: bool) -> Option<f64> {
        let Kind::Scratch { pts, r, along, .. } = &self.kind else {
            return self.near(p, radius).then_some(self.edge_mm);
        };
        if !anisotropic {
            return self.near(p, radius).then_some(self.edge_mm);
        }
        let r = *r;
        let reach = r + radius;
        if !self.in_box(p, radius) {
            return None;
        }
        if pts.len() == 1 {
            return ((p - pts[0]).length() <= reach).then_some(self.edge_mm);
        }
        let mut best = f64::INFINITY;
        for (i, w) in pts.windows(2).enumerate() {
            let (a, b) = (w[0], w[1]);
            if p.x < a.x.min(b.x) - reach
                || p.x > a.x.max(b.x) + reach
                || p.y < a.y.min(b.y) - reach
                || p.y > a.y.max(b.y) + reach
                || point_segment_distance(p, a, b) > reach
            {
                continue;
            }
            best = best.min(if along.fine[i] {
                self.edge_mm
            } else {
                along.max_mm
            });
        }
        if best == f64::INFINITY {
            return None;
        }
        // Near a path point (bend, depth kink, end): that point's limit.
        let zone = 2.0 * r + radius;
        for (k, &q) in pts.iter().enumerate() {
            if along.at_point[k] < best && (p - q).length_squared() <= zone * zone {
                best = along.at_point[k];
            }
        }
        Some(best)
    }

    /// The rows of an anisotropically meshed scratch: offsets from the path (mm,
    /// ascending); empty for dents.
    pub(crate) fn slice_levels(&self) -> &[f64] {
        match &self.kind {
            Kind::Scratch { along, .. } => &along.levels,
            Kind::Dent { .. } => &[],
        }
    }

    /// The signed distance from the path at `p` (positive left of the path's direction),
    /// the arc length of the nearest path point and the unit direction in which the
    /// signed distance grows; None where the nearest point is an end of the path (in the
    /// rounded caps the offset is not a distance across).
    pub(crate) fn path_coordinates(&self, p: DVec2) -> Option<(f64, f64, DVec2)> {
        let Kind::Scratch { pts, .. } = &self.kind else {
            return None;
        };
        let mut best = (f64::INFINITY, 0usize, 0.0f64);
        for (i, w) in pts.windows(2).enumerate() {
            let (t, d2) = nearest_on_segment(p, w[0], w[1]);
            if d2 < best.0 {
                best = (d2, i, t);
            }
        }
        let (d2, i, t) = best;
        let last = pts.len().checked_sub(2)?;
        if !d2.is_finite() || (i == 0 && t <= 0.0) || (i == last && t >= 1.0) {
            return None;
        }
        let (a, b) = (pts[i], pts[i + 1]);
        let e = b - a;
        // Side: of the segment, or at a joint (nearest point = the joint) of the bisector.
        let side = if t <= 0.0 && i > 0 {
            (e.normalize_or_zero() + (a - pts[i - 1]).normalize_or_zero()).perp_dot(p - a)
        } else if t >= 1.0 && i + 2 < pts.len() {
            (e.normalize_or_zero() + (pts[i + 2] - b).normalize_or_zero()).perp_dot(p - b)
        } else {
            e.perp_dot(p - a)
        };
        let Kind::Scratch { along, .. } = &self.kind else {
            return None;
        };
        let arc = along.cum[i] + t * e.length();
        let d = d2.sqrt();
        let left = e.perp().normalize_or_zero();
        let dir = if d > 1e-12 {
            let q = a + e * t;
            let radial = (p - q) / d;
            if side < 0.0 { -radial } else { radial }
        } else {
            left
        };
        Some((if side < 0.0 { -d } else { d }, arc, dir))
    }

    /// Half-width of a scratch (0 for dents).
    pub(crate) fn half_width(&self) -> f64 {
        match &self.kind {
            Kind::Scratch { r, .. } => *r,
            Kind::Dent { .. } => 0.0,
        }
    }

    /// Whether the footprint, grown by one target edge, lies inside the face (so the
    /// face's border vertices are never displaced and neighbours stay connected).
    pub(crate) fn fits(&self, region: &Region) -> bool {
        match &self.kind {
            &Kind::Dent { c, a, rim_w, .. } => {
                region.disk_fits(c, a * (1.0 + rim_w) + self.edge_mm)
            }
            Kind::Scratch { pts, r, .. } => region.polyline_fits(pts, r + self.edge_mm),
        }
    }
}

/// Combines overlapping imprints: the deepest pit wins; where there is no pit, the
/// highest rim. Returns (height, index of the winning tool).
pub(crate) fn combined_height(
    tools: &[DefectTool],
    idx: &[usize],
    p: DVec2,
) -> (f64, Option<usize>) {
    let mut best = 0.0f64;
    let mut who = None;
    for &k in idx {
        let h = tools[k].height(p);
        if h == 0.0 {
            continue;
        }
        let better = if h < 0.0 {
            h < best || best >= 0.0
        } else {
            best >= 0.0 && h > best
        };
        if better {
            best = h;
            who = Some(k);
        }
    }
    (best, who)
}
