//! Sub-model 1: the tool path, nominal ring centres in chronological order.

use rand::Rng;

use super::{MilledParams, ToolPath};
use crate::texture::error::{Result, check};
use crate::texture::rng::stream;

/// A nominal ring centre on the tool path with its movement direction.
#[derive(Clone, Copy, Debug)]
pub(super) struct PathPoint {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) dir: [f64; 2],
}
/// Nominal ring centres in chronological order. Both paths overshoot the texture by
/// d/2 + 0.5 mm so every ring touching the texture exists; the meander's turn-arounds
/// and the spiral's entry/exit moves therefore lie outside the texture and are not drawn.
pub(super) fn tool_path(p: &MilledParams, w: f64, h: f64, seed: u64) -> Result<Vec<PathPoint>> {
    let d = p.head_diameter_mm;
    let rho = p.rho_mm();
    let delta = p.delta_mm;
    let margin = d / 2.0 + 0.5;
    let mut rng = stream(seed, 0, 0);
    let (ph_rho, ph_delta) = if p.random_path_phase {
        (rng.random::<f64>(), rng.random::<f64>())
    } else {
        (0.0, 0.0)
    };
    let mut pts = Vec::new();
    match p.path {
        ToolPath::Parallel => {
            let y0 = -margin + ph_rho * rho;
            let x0 = -margin + ph_delta * delta;
            let nx = ((w + 2.0 * margin - ph_delta * delta) / delta).ceil() as usize + 1;
            let mut j = 0usize;
            loop {
                let y = y0 + j as f64 * rho;
                if y > h + margin {
                    break;
                }
                for i in 0..nx {
                    let (x, dir) = if j.is_multiple_of(2) {
                        (x0 + i as f64 * delta, [1.0, 0.0])
                    } else {
                        (x0 + (nx - 1 - i) as f64 * delta, [-1.0, 0.0])
                    };
                    pts.push(PathPoint { x, y, dir });
                }
                j += 1;
            }
        }
        ToolPath::Spiral => {
            let [cx, cy] = p.spiral_center_mm.unwrap_or([w / 2.0, h / 2.0]);
            let far = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
                .iter()
                .map(|&(x, y)| ((x - cx).powi(2) + (y - cy).powi(2)).sqrt())
                .fold(0.0f64, f64::max);
            let r_max = far + margin;
            // The spiral is walked from its centre even when that lies far outside.
            let steps = std::f64::consts::PI * r_max * r_max / (rho * delta);
            check(
                steps <= 2e8,
                "spiral_center_mm",
                cx.hypot(cy),
                "close enough to the texture that the spiral needs <= 2e8 steps",
            )?;
            let k = rho / (2.0 * std::f64::consts::PI);
            let mut theta = 0.0f64;
            let rot = ph_rho * 2.0 * std::f64::consts::PI;
            loop {
                let r = k * theta;
                if r > r_max {
                    break;
                }
                let (sn, cs) = (theta + rot).sin_cos();
                let tx = k * cs - r * sn;
                let ty = k * sn + r * cs;
                let norm = (tx * tx + ty * ty).sqrt();
                let (x, y) = (cx + r * cs, cy + r * sn);
                if x > -margin && x < w + margin && y > -margin && y < h + margin {
                    pts.push(PathPoint {
                        x,
                        y,
                        dir: [tx / norm, ty / norm],
                    });
                }
                theta += delta / norm;
            }
            if !p.spiral_outward {
                pts.reverse();
                for q in &mut pts {
                    q.dir = [-q.dir[0], -q.dir[1]];
                }
            }
            if p.spiral_exit_line {
                let (sn, cs) = p.spiral_exit_angle_deg.to_radians().sin_cos();
                let line = (0..=(r_max / delta).ceil() as usize).filter_map(|i| {
                    let r = i as f64 * delta;
                    let (x, y) = (cx + r * cs, cy + r * sn);
                    let inside = x > -margin && x < w + margin && y > -margin && y < h + margin;
                    inside.then_some(PathPoint {
                        x,
                        y,
                        dir: [cs, sn],
                    })
                });
                if p.spiral_outward {
                    // Entry: from outside to the centre, before the spiral.
                    let mut entry: Vec<PathPoint> = line
                        .map(|q| PathPoint {
                            dir: [-cs, -sn],
                            ..q
                        })
                        .collect();
                    entry.reverse();
                    entry.append(&mut pts);
                    pts = entry;
                } else {
                    pts.extend(line);
                }
            }
        }
    }
    Ok(pts)
}
