//! How close the imprinted (piecewise-linear) dents and scratches come to the true
//! Boolean difference, against the `resolution` setting: removed volume vs the analytic
//! volume, and measured depth vs specified depth, for single defects on face A of the
//! test body. Run: cargo run --release --example defect_accuracy

use glam::DVec2;
use synosis::defect::{
    Defect, DefectSet, Dent, Scratch, ScratchProfile, Shape, imprint_with_stats,
};
use synosis::scene::testbody::{Variant, face_frames, testbody};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let body = testbody(Variant::B);
    let f = face_frames(&body)[0];
    let dent = |d: f64, minor: f64, depth: f64| {
        Shape::Dent(Dent {
            centre_uv_mm: [0.3, -0.2],
            diameter_mm: d,
            minor_mm: minor,
            rotation_deg: 30.0,
            depth_mm: depth,
            rim_height_mm: 0.0,
            rim_width: 0.5,
        })
    };
    let straight = |w: f64, depth: f64, profile: ScratchProfile| {
        let path: Vec<[f64; 2]> = (0..=50)
            .map(|i| [-4.0 + 0.16 * i as f64, 0.05 * i as f64])
            .collect();
        let len = path
            .windows(2)
            .map(|p| (DVec2::from(p[1]) - DVec2::from(p[0])).length())
            .sum();
        Shape::Scratch(Scratch {
            depth_mm: vec![depth; path.len()],
            path_uv_mm: path,
            width_mm: w,
            length_mm: len,
            step_mm: 0.16,
            curviness_deg: 0.0,
            profile,
        })
    };
    let cases: Vec<(&str, Shape, f64)> = vec![
        (
            "dent d=0.02 mm, e=1, depth 0.1 d",
            dent(0.02, 0.02, 0.002),
            2.0 / 3.0 * std::f64::consts::PI * 0.01 * 0.01 * 0.002,
        ),
        (
            "dent d=0.2 mm, e=2, depth 0.2 d",
            dent(0.2, 0.1, 0.04),
            2.0 / 3.0 * std::f64::consts::PI * 0.1 * 0.05 * 0.04,
        ),
        (
            "dent d=1 mm, e=4, depth 1.0 d",
            dent(1.0, 0.25, 1.0),
            2.0 / 3.0 * std::f64::consts::PI * 0.5 * 0.125 * 1.0,
        ),
        (
            "scratch w=0.1 mm, depth 0.02, L=8.4",
            straight(0.1, 0.02, ScratchProfile::Parabolic),
            0.0,
        ),
        (
            "round scratch w=0.1 mm, depth 0.05 (half tube), L=8.4",
            straight(0.1, 0.05, ScratchProfile::Round),
            0.0,
        ),
    ];
    println!(
        "| defect | resolution | triangles | removed / analytic volume | depth measured / specified |"
    );
    println!("|---|---|---|---|---|");
    for (name, shape, analytic) in cases {
        let (depth, analytic) = match &shape {
            Shape::Dent(d) => (d.depth_mm, analytic),
            Shape::Scratch(s) => {
                let (len, r, d) = (s.length_mm, s.width_mm / 2.0, s.depth_mm[0]);
                let pi = std::f64::consts::PI;
                let volume = match s.profile {
                    // Cross-section 2/3 w d, plus two half-paraboloid end caps (together
                    // one paraboloid, pi r^2 d / 2).
                    ScratchProfile::Parabolic => {
                        2.0 / 3.0 * s.width_mm * d * len + pi / 2.0 * r * r * d
                    }
                    // A circular segment (radius R, sagitta d) swept along the path, plus
                    // the two half spherical caps at the ends (together one cap).
                    ScratchProfile::Round => {
                        let big_r = (r * r + d * d) / (2.0 * d);
                        let segment =
                            big_r * big_r * ((big_r - d) / big_r).acos() - (big_r - d) * r;
                        segment * len + pi * d * d * (3.0 * big_r - d) / 3.0
                    }
                };
                (d, volume)
            }
        };
        for resolution in [4.0, 8.0, 16.0] {
            let set = DefectSet {
                seed: 0,
                resolution,
                defects: vec![Defect {
                    instance: 1,
                    class: 1,
                    name: name.into(),
                    face: "A".into(),
                    shape: shape.clone(),
                }],
            };
            let (out, stats) = imprint_with_stats(&body, &set)?;
            // Integrate the depth over the defect's triangles (projected area times mean
            // corner depth): exact for the piecewise-linear surface, and free of the
            // f32 rounding that swamps a whole-body volume difference for tiny dents.
            let below =
                |p: glam::Vec3| -(p.as_dvec3() - f.centre.as_dvec3()).dot(f.normal.as_dvec3());
            let mut removed = 0.0;
            let mut deepest = 0.0f64;
            for t in 0..out.triangles.len() {
                if out.labels[t].instance != 1 {
                    continue;
                }
                let c = out.corners(t);
                let area = 0.5 * out.area_normal(t).as_dvec3().dot(f.normal.as_dvec3());
                removed += area * c.iter().map(|&p| below(p)).sum::<f64>() / 3.0;
                deepest = c.iter().map(|&p| below(p)).fold(deepest, f64::max);
            }
            println!(
                "| {name} | {resolution} | {} | {:.4} | {:.4} |",
                stats.triangles_out,
                removed / analytic,
                deepest / depth
            );
        }
    }
    Ok(())
}
