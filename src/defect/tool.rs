//! Defecting tools as height fields over a face: the analytic surface a true Boolean
//! difference would leave, evaluated at face-local (u, v).

use glam::DVec2;

use super::region::{Region, point_segment_distance};
use super::sample::{Defect, Shape};
use super::spec::ScratchProfile;

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
    },
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
                    let e = b - a;
                    let l2 = e.length_squared();
                    let t = if l2 > 0.0 {
                        ((p - a).dot(e) / l2).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    let dist2 = (p - (a + e * t)).length_squared();
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
