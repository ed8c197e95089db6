//! How close the imprinted (piecewise-linear) dents and scratches come to the true
//! Boolean difference, against the `resolution` setting: removed volume vs the analytic
//! volume, and measured depth vs specified depth, for single defects on face A of the
//! test body. Scratches are meshed both ways (anisotropic, the default since issue 15,
//! and isotropic); the paper's flat and curvy scratch kinds (width 20 um, the thinnest,
//! depth varying along the path) are measured against a numerical integral of the exact
//! height field. Run: cargo run --release --example defect_accuracy

use glam::DVec2;
use synosis::defect::{
    Defect, DefectSet, DefectSpec, Dent, ImprintOptions, Scratch, ScratchMesh, ScratchProfile,
    Shape, imprint_with_options, sample_defects,
};
use synosis::scene::Mesh;
use synosis::scene::testbody::{Variant, face_frames, testbody};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let body = testbody(Variant::B);
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
        "| defect | mesh | resolution | triangles | removed / analytic volume | depth measured / specified |"
    );
    println!("|---|---|---|---|---|---|");
    let meshes = [ScratchMesh::Anisotropic, ScratchMesh::Isotropic];
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
        let ways: &[ScratchMesh] = match shape {
            Shape::Dent(_) => &meshes[1..],
            Shape::Scratch(_) => &meshes,
        };
        for &way in ways {
            for resolution in [4.0, 8.0, 16.0] {
                let class = if matches!(shape, Shape::Dent(_)) {
                    1
                } else {
                    2
                };
                let set = DefectSet {
                    seed: 0,
                    resolution,
                    defects: vec![Defect {
                        instance: 1,
                        class,
                        name: name.into(),
                        face: "A".into(),
                        shape: shape.clone(),
                    }],
                };
                row(&body, &set, way, name, analytic, depth)?;
            }
        }
    }
    // The paper's scratch kinds at their thinnest (20 um), depth varying along the path.
    for (kind, seed) in [(0usize, 4u64), (1, 4)] {
        let mut spec = DefectSpec::paper();
        spec.faces = vec!["A".into()];
        spec.dent.clear();
        let mut s = spec.scratch[kind].clone();
        s.quantity = 1;
        s.width_mm = synosis::defect::Range::new(0.02, 0.02);
        spec.scratch = vec![s];
        let name = format!("paper {} w=0.02 mm (seed {seed})", spec.scratch[0].name);
        for &way in &meshes {
            for resolution in [4.0, 8.0, 16.0] {
                spec.resolution = resolution;
                let set = sample_defects(&body, &spec, seed)?;
                let Shape::Scratch(sc) = &set.defects[0].shape else {
                    unreachable!()
                };
                let analytic = scratch_volume(sc);
                let depth = sc.depth_mm.iter().copied().fold(0.0, f64::max);
                row(&body, &set, way, &name, analytic, depth)?;
            }
        }
    }
    Ok(())
}

/// Prints one table row: the imprint of `set` (one defect, instance 1, on face A).
fn row(
    body: &Mesh,
    set: &DefectSet,
    way: ScratchMesh,
    name: &str,
    analytic: f64,
    depth: f64,
) -> Result<(), Box<dyn std::error::Error>> {
    let f = face_frames(body)[0];
    let options = ImprintOptions { scratch_mesh: way };
    let (out, stats) = imprint_with_options(body, set, options)?;
    // Integrate the depth over the defect's triangles (projected area times mean corner
    // depth): exact for the piecewise-linear surface, and free of the f32 rounding that
    // swamps a whole-body volume difference for tiny dents.
    let below = |p: glam::Vec3| -(p.as_dvec3() - f.centre.as_dvec3()).dot(f.normal.as_dvec3());
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
    let way = match (way, name.starts_with("dent")) {
        (_, true) => "",
        (ScratchMesh::Anisotropic, _) => "anisotropic",
        (ScratchMesh::Isotropic, _) => "isotropic",
    };
    println!(
        "| {name} | {way} | {} | {} | {:.4} | {:.4} |",
        set.resolution,
        stats.triangles_out,
        removed / analytic,
        deepest / depth
    );
    Ok(())
}

/// Volume under the face of a scratch's exact height field (union of the swept profile:
/// overlaps at bends counted once), by the midpoint rule on a grid of w / 200 around
/// each segment, each sample counted for its nearest segment only (ties: the first).
fn scratch_volume(s: &Scratch) -> f64 {
    let pts: Vec<DVec2> = s.path_uv_mm.iter().map(|&p| DVec2::from(p)).collect();
    let r = s.width_mm / 2.0;
    let n = pts.len() - 1;
    let seg_dist = |p: DVec2, i: usize| -> (f64, f64) {
        let (a, b) = (pts[i], pts[i + 1]);
        let e = b - a;
        let t = ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0);
        ((p - (a + e * t)).length(), t)
    };
    let profile = |dep: f64, d: f64| -> f64 {
        if d >= r {
            return 0.0;
        }
        match s.profile {
            ScratchProfile::Parabolic => dep * (1.0 - d * d / (r * r)),
            ScratchProfile::Round => {
                let big_r = (r * r + dep * dep) / (2.0 * dep);
                ((big_r * big_r - d * d).max(0.0).sqrt() - (big_r - dep)).max(0.0)
            }
        }
    };
    // Segments near each segment (the only ones a sample can be nearer to, or deeper in).
    let near: Vec<Vec<usize>> = (0..n)
        .map(|i| {
            (0..n)
                .filter(|&j| {
                    let d = [pts[j], pts[j + 1]]
                        .iter()
                        .map(|&p| seg_dist(p, i).0)
                        .fold(f64::INFINITY, f64::min);
                    let l = (pts[j + 1] - pts[j]).length();
                    d <= 2.0 * r + l
                })
                .collect()
        })
        .collect();
    let h = s.width_mm / 200.0;
    let mut total = 0.0;
    for i in 0..n {
        let (a, b) = (pts[i], pts[i + 1]);
        let len = (b - a).length();
        let t = (b - a) / len;
        let nrm = t.perp();
        let nt = ((len + 2.0 * r) / h).ceil() as usize;
        let ht = (len + 2.0 * r) / nt as f64;
        for it in 0..nt {
            for is in 0..200 {
                let p = a + t * (-r + (it as f64 + 0.5) * ht) + nrm * (-r + (is as f64 + 0.5) * h);
                let (d_i, _) = seg_dist(p, i);
                if d_i >= r {
                    continue;
                }
                let mut mine = true;
                let mut deepest = 0.0f64;
                for &j in &near[i] {
                    let (d_j, tj) = seg_dist(p, j);
                    if j != i && (d_j < d_i || (d_j == d_i && j < i)) {
                        mine = false;
                        break;
                    }
                    let dep = s.depth_mm[j] + (s.depth_mm[j + 1] - s.depth_mm[j]) * tj;
                    deepest = deepest.max(profile(dep, d_j));
                }
                if mine {
                    total += deepest * ht * h;
                }
            }
        }
    }
    total
}
