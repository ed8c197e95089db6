//! Defect sampling and imprinting: topology, labels, measured sizes, determinism,
//! uniform placement and spec errors.

use glam::{DVec2, DVec3};
use synosis::defect::{
    DefectError, DefectSet, DefectSpec, DefectTool, ScratchProfile, Shape, check_closed_manifold,
    imprint, sample_defects,
};
use synosis::scene::mesh::face_from_name;
use synosis::scene::testbody::{FaceFrame, Variant, face_frames, testbody};
use synosis::scene::{Mesh, export_mesh};

fn volume(m: &Mesh) -> f64 {
    (0..m.triangles.len())
        .map(|t| {
            let [a, b, c] = m.corners(t).map(|p| p.as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

fn frame_of(frames: &[FaceFrame], face: &str) -> FaceFrame {
    let id = face_from_name(face).unwrap();
    *frames.iter().find(|f| f.face == id).unwrap()
}

fn uv(f: FaceFrame, p: DVec3) -> DVec2 {
    let d = p - f.centre.as_dvec3();
    DVec2::new(d.dot(f.u.as_dvec3()), d.dot(f.v.as_dvec3()))
}

/// Depth below the (original) face plane, mm; positive into the material.
fn depth(f: FaceFrame, p: DVec3) -> f64 {
    -(p - f.centre.as_dvec3()).dot(f.normal.as_dvec3())
}

/// Off-plane rounding of f32 positions on a tilted face is a few nm; anything deeper
/// than this was displaced by a defect.
const NOISE: f64 = 1e-5;

/// Vertices of the triangles on face `f` (the only ones a defect there may move).
fn face_vertices(m: &Mesh, f: FaceFrame) -> Vec<DVec3> {
    let mut used = vec![false; m.positions.len()];
    for (t, l) in m.triangles.iter().zip(&m.labels) {
        if l.face == f.face {
            t.iter().for_each(|&i| used[i as usize] = true);
        }
    }
    (0..m.positions.len())
        .filter(|&i| used[i])
        .map(|i| m.positions[i].as_dvec3())
        .collect()
}

/// Topology, orientation and label checks shared by several tests.
fn check_imprinted(input: &Mesh, set: &DefectSet, out: &Mesh) {
    check_closed_manifold(out).unwrap();
    assert!(
        out.degenerate_triangles().is_empty(),
        "degenerate triangles"
    );
    let frames = face_frames(input);
    // Height field: every triangle of an inspected face still faces out of that face.
    for t in 0..out.triangles.len() {
        let face = out.labels[t].face;
        if let Some(f) = frames.iter().find(|f| f.face == face) {
            let n = out.area_normal(t).as_dvec3().normalize();
            assert!(
                n.dot(f.normal.as_dvec3()) > 1e-3,
                "triangle {t} flipped or vertical: {n}"
            );
        }
    }
    for d in &set.defects {
        let f = frame_of(&frames, &d.face);
        let tool = DefectTool::new(d, set.resolution);
        let tris: Vec<usize> = (0..out.triangles.len())
            .filter(|&t| out.labels[t].instance == d.instance)
            .collect();
        assert!(
            !tris.is_empty(),
            "defect {} ({}) has no triangles",
            d.instance,
            d.name
        );
        for &t in &tris {
            assert_eq!(out.labels[t].class, d.class);
            assert_eq!(out.labels[t].face, f.face);
            // At least one corner lies in the defect's footprint (its tool height there
            // is not zero) and was moved by the tool's height.
            let inside = out.corners(t).iter().any(|p| {
                let p = p.as_dvec3();
                let h = tool.height(uv(f, p));
                // f32 positions put a vertex a few nm off where imprint evaluated it.
                (h != 0.0 || tool.near(uv(f, p), 1e-5)) && (depth(f, p) + h).abs() < 1e-4
            });
            if !inside {
                let info: Vec<_> = out
                    .corners(t)
                    .iter()
                    .map(|p| {
                        let p = p.as_dvec3();
                        (uv(f, p), depth(f, p), tool.height(uv(f, p)))
                    })
                    .collect();
                panic!(
                    "triangle {t} labelled {} lies outside its footprint: {info:?}",
                    d.instance
                );
            }
        }
    }
    let labelled = out.labels.iter().filter(|l| l.class != 0).count();
    assert!(labelled > 0);
    assert!(
        out.labels
            .iter()
            .all(|l| (l.class == 0) == (l.instance == 0))
    );
}

#[test]
fn paper_spec_imprint_is_watertight_labelled_and_reapplies_to_the_mirror() {
    let b = testbody(Variant::B);
    let spec = DefectSpec::paper();
    let set = sample_defects(&b, &spec, 7).unwrap();
    assert_eq!(set.defects.len(), 12);
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    // Net material was removed: scratches only remove, and a dent's rim (as high as the
    // dent is deep, over 1 ... 1.5 semi-axes) adds 0.625 pi a b c against the pit's 0.667.
    assert!(volume(&out) < volume(&b));
    // The same face-local set on the mirror body.
    let m = testbody(Variant::M);
    let out_m = imprint(&m, &set).unwrap();
    check_imprinted(&m, &set, &out_m);
    // Same defects, so about the same removed volume; the two faces' coarse diagonals
    // differ, so the refinement (and its interpolation error) differs a little.
    let (rb, rm) = (volume(&b) - volume(&out), volume(&m) - volume(&out_m));
    assert!((rb - rm).abs() < 0.03 * rb, "removed {rb} on B, {rm} on M");
}

#[test]
fn same_seed_same_mesh_bit_for_bit_and_other_seeds_differ() {
    let b = testbody(Variant::B);
    let spec = DefectSpec::paper();
    let one = imprint(&b, &sample_defects(&b, &spec, 42).unwrap()).unwrap();
    let two = imprint(&b, &sample_defects(&b, &spec, 42).unwrap()).unwrap();
    let bits = |m: &Mesh| {
        m.positions
            .iter()
            .flat_map(|p| p.to_array().map(f32::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one.triangles, two.triangles);
    assert_eq!(one.labels, two.labels);
    let dir = tempfile::tempdir().unwrap();
    let (p1, p2) = (dir.path().join("1.glb"), dir.path().join("2.glb"));
    export_mesh(&one, &p1).unwrap();
    export_mesh(&two, &p2).unwrap();
    assert!(std::fs::read(&p1).unwrap() == std::fs::read(&p2).unwrap());
    let other = imprint(&b, &sample_defects(&b, &spec, 43).unwrap()).unwrap();
    assert_ne!(bits(&one), bits(&other));
}

/// Volume removed by defect `instance` below face frame `f` (projected area times mean
/// corner depth per triangle: exact for the piecewise-linear surface).
fn removed_volume(out: &Mesh, f: FaceFrame, instance: u16) -> f64 {
    let n = f.normal.as_dvec3();
    let mut removed = 0.0;
    for t in 0..out.triangles.len() {
        if out.labels[t].instance == instance {
            let area = 0.5 * out.area_normal(t).as_dvec3().dot(n);
            removed += area
                * out
                    .corners(t)
                    .iter()
                    .map(|p| depth(f, p.as_dvec3()))
                    .sum::<f64>()
                / 3.0;
        }
    }
    removed
}

fn dents_only(text: &str) -> DefectSpec {
    DefectSpec::from_toml_str(text, "test").unwrap()
}

#[test]
fn dents_have_the_specified_depth_diameter_and_volume() {
    // The pit alone (rims off; `a_rim_raises_material_around_the_dent` checks the rim).
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        [[dent]]
        name = "big"
        quantity = 4
        diameter_mm = [0.2, 1.0]
        elongation = [1, 4]
        depth = [0.2, 1.0]
        rim_height = 0
        [[dent]]
        name = "tiny"
        quantity = 4
        diameter_mm = 0.02
        elongation = [1, 2]
        depth = [0.05, 0.2]
        rim_height = 0
        "#,
    );
    let set = sample_defects(&b, &spec, 3).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let frames = face_frames(&b);
    let mut analytic = 0.0;
    for d in &set.defects {
        let Shape::Dent(s) = &d.shape else {
            unreachable!()
        };
        let f = frame_of(&frames, &d.face);
        let c = DVec2::from(s.centre_uv_mm);
        let edge = s.minor_mm / set.resolution * 2.0;
        // Only dents no other defect overlaps are measured.
        let alone = set.defects.iter().all(|o| {
            let Shape::Dent(t) = &o.shape else {
                return true;
            };
            o.instance == d.instance
                || o.face != d.face
                || (DVec2::from(t.centre_uv_mm) - c).length()
                    > 0.5 * (s.diameter_mm + t.diameter_mm) + 2.0 * edge
        });
        analytic +=
            2.0 / 3.0 * std::f64::consts::PI * 0.25 * s.diameter_mm * s.minor_mm * s.depth_mm;
        if !alone {
            continue;
        }
        let (sin, cos) = s.rotation_deg.to_radians().sin_cos();
        let major = DVec2::new(cos, sin);
        let mut max_depth = 0.0f64;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for p in face_vertices(&out, f) {
            let q = uv(f, p) - c;
            if q.length() > 0.5 * s.diameter_mm + edge {
                continue;
            }
            let dep = depth(f, p);
            if dep > NOISE {
                max_depth = max_depth.max(dep);
                lo = lo.min(q.dot(major));
                hi = hi.max(q.dot(major));
            }
        }
        let name = format!(
            "dent {} ({}): d={} minor={} depth={}",
            d.instance, d.name, s.diameter_mm, s.minor_mm, s.depth_mm
        );
        assert!(
            max_depth <= s.depth_mm * (1.0 + 1e-4) + 1e-5,
            "{name}: measured depth {max_depth}"
        );
        assert!(
            max_depth >= s.depth_mm * 0.95,
            "{name}: measured depth {max_depth}"
        );
        let width = hi - lo;
        assert!(
            width <= s.diameter_mm + 1e-5,
            "{name}: measured diameter {width}"
        );
        assert!(
            width >= s.diameter_mm - 2.0 * edge - 1e-5,
            "{name}: measured diameter {width}"
        );
    }
    // Removed volume against the analytic half-ellipsoids. Inside a footprint the
    // piecewise-linear surface lies above the (convex) pit and removes less; triangles
    // straddling the rim remove a sliver beyond it; f32 positions add about 1e-3 mm^3 of
    // noise to a whole-body volume. Net: within 2 % here (docs/defects.md).
    let removed = volume(&b) - volume(&out);
    let ratio = removed / analytic;
    eprintln!("removed volume {removed:.5} mm^3, analytic {analytic:.5} mm^3, ratio {ratio:.4}");
    assert!(
        (ratio - 1.0).abs() < 0.02,
        "removed {removed} vs analytic {analytic}: ratio {ratio}"
    );
}

#[test]
fn a_straight_scratch_is_as_long_and_deep_as_specified() {
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        faces = ["A"]
        [[scratch]]
        name = "straight"
        quantity = 1
        width_mm = 0.1
        depth = 0.3
        path_length_mm = 8.0
        step_mm = 0.5
        curviness_deg = 0
        depth_variation = 0
        "#,
    );
    let set = sample_defects(&b, &spec, 11).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let Shape::Scratch(s) = &set.defects[0].shape else {
        unreachable!()
    };
    assert!((s.length_mm - 8.0).abs() < 1e-9);
    let f = frame_of(&face_frames(&b), "A");
    let a = DVec2::from(s.path_uv_mm[0]);
    let dir = (DVec2::from(*s.path_uv_mm.last().unwrap()) - a).normalize();
    let (mut lo, mut hi, mut max_depth) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for p in face_vertices(&out, f) {
        if depth(f, p) > NOISE {
            let t = (uv(f, p) - a).dot(dir);
            lo = lo.min(t);
            hi = hi.max(t);
            max_depth = max_depth.max(depth(f, p));
        }
    }
    let edge = s.width_mm / set.resolution;
    let measured = hi - lo - s.width_mm;
    assert!(
        measured <= 8.0 + 1e-4 && measured >= 8.0 - 2.0 * edge,
        "measured length {measured}"
    );
    assert!(
        (0.03 * 0.95..=0.03 + 1e-5).contains(&max_depth),
        "measured depth {max_depth}"
    );
}

/// `profile = "round"` with depth 0.5: the paper's scratch tool read as a tube of the
/// scratch's diameter sunk to its axis; every vertex across the groove lies on the half
/// circle, and the cross-section removes pi r^2 / 2 per mm of path.
#[test]
fn a_round_scratch_is_a_half_tube() {
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        faces = ["A"]
        [[scratch]]
        name = "tube"
        quantity = 1
        width_mm = 0.1
        depth = 0.5
        path_length_mm = 6.0
        step_mm = 0.5
        curviness_deg = 0
        depth_variation = 0
        profile = "round"
        "#,
    );
    let set = sample_defects(&b, &spec, 11).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let Shape::Scratch(s) = &set.defects[0].shape else {
        unreachable!()
    };
    assert_eq!(s.profile, ScratchProfile::Round);
    let r = s.width_mm / 2.0;
    let f = frame_of(&face_frames(&b), "A");
    let a = DVec2::from(s.path_uv_mm[0]);
    let dir = (DVec2::from(*s.path_uv_mm.last().unwrap()) - a).normalize();
    let mut across = 0;
    for p in face_vertices(&out, f) {
        let q = uv(f, p) - a;
        let (t, dist) = (q.dot(dir), q.perp_dot(dir).abs());
        if t > 0.5 && t < s.length_mm - 0.5 && dist < r {
            // On the circle of radius r about the path (radial distance: f32 vertex
            // positions would make a depth comparison fail near the vertical walls).
            let radial = (depth(f, p).powi(2) + dist * dist).sqrt();
            assert!(
                (radial - r).abs() < 1e-5,
                "vertex at {dist} mm from the path, depth {}: {radial} mm from the axis, not {r}",
                depth(f, p)
            );
            across += 1;
        }
    }
    assert!(across > 100, "only {across} vertices inside the groove");
    // Volume: the half tube along the path plus a hemisphere at the two ends together.
    let removed = removed_volume(&out, f, 1);
    let pi = std::f64::consts::PI;
    let analytic = pi * r * r / 2.0 * s.length_mm + 2.0 / 3.0 * pi * r.powi(3);
    // Piecewise-linear chords under a circle remove a little less (edges of w / 8).
    assert!(
        removed < analytic && removed > 0.97 * analytic,
        "removed {removed} mm^3 vs half tube {analytic}"
    );
    // Deeper than half the width is an undercut: refused, naming the field.
    let err = DefectSpec::from_toml_str(
        r#"
        [[scratch]]
        name = "deep"
        quantity = 1
        width_mm = 0.1
        depth = [0.2, 0.6]
        path_length_mm = 6.0
        step_mm = 0.5
        curviness_deg = 0
        profile = "round"
        "#,
        "deep.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("scratch[0] (deep).depth") && err.contains("0.5"),
        "{err}"
    );
}

#[test]
fn positions_are_uniform_over_the_faces() {
    // 3000 tiny dents on three equal faces, counted on a 5 x 5 grid per face: 75 cells,
    // 40 expected each. Chi-square with 74 degrees of freedom; the critical value at
    // significance 0.001 is 117.4 (Wilson-Hilferty).
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        [[dent]]
        name = "probe"
        quantity = 3000
        diameter_mm = 0.002
        elongation = 1
        depth = 0.1
        "#,
    );
    let set = sample_defects(&b, &spec, 2024).unwrap();
    let mut counts = [0u32; 75];
    for d in &set.defects {
        let Shape::Dent(s) = &d.shape else {
            unreachable!()
        };
        let f = (face_from_name(&d.face).unwrap() - 1) as usize;
        let [x, y] = s.centre_uv_mm;
        assert!(x.abs() < 10.0 && y.abs() < 10.0);
        let cx = (((x + 10.0) / 4.0) as usize).min(4);
        let cy = (((y + 10.0) / 4.0) as usize).min(4);
        counts[f * 25 + cy * 5 + cx] += 1;
    }
    let expected = 3000.0 / 75.0;
    let chi2: f64 = counts
        .iter()
        .map(|&c| (c as f64 - expected).powi(2) / expected)
        .sum();
    assert!(
        chi2 < 117.4,
        "chi-square {chi2} over 74 dof: not uniform ({counts:?})"
    );
    // And not degenerate: the statistic is not suspiciously small either (p > 0.999).
    assert!(
        chi2 > 42.0,
        "chi-square {chi2} too small for independent draws"
    );
}

#[test]
fn overlapping_dents_deepest_wins() {
    let b = testbody(Variant::B);
    let json = r#"{"seed":0,"resolution":8,"defects":[
      {"instance":1,"class":1,"name":"shallow","face":"B","shape":{"kind":"dent","centre_uv_mm":[1,1],
       "diameter_mm":0.6,"minor_mm":0.6,"rotation_deg":0,"depth_mm":0.05,"rim_height_mm":0,"rim_width":0.5}},
      {"instance":2,"class":1,"name":"deep","face":"B","shape":{"kind":"dent","centre_uv_mm":[1.2,1],
       "diameter_mm":0.3,"minor_mm":0.3,"rotation_deg":0,"depth_mm":0.2,"rim_height_mm":0,"rim_width":0.5}}]}"#;
    let set: DefectSet = serde_json::from_str(json).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let f = frame_of(&face_frames(&b), "B");
    let deepest = face_vertices(&out, f)
        .iter()
        .map(|&p| depth(f, p))
        .fold(0.0, f64::max);
    assert!(deepest > 0.19 && deepest <= 0.2 + 1e-5, "{deepest}");
    // Where both overlap, the deep dent owns the triangles at its centre.
    let near_centre = (0..out.triangles.len()).find(|&t| {
        out.corners(t)
            .iter()
            .all(|p| (uv(f, p.as_dvec3()) - DVec2::new(1.2, 1.0)).length() < 0.03)
    });
    assert_eq!(out.labels[near_centre.unwrap()].instance, 2);
}

#[test]
fn a_rim_raises_material_around_the_dent() {
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        faces = ["C"]
        [[dent]]
        name = "rimmed"
        quantity = 1
        diameter_mm = 0.5
        elongation = 1
        depth = 0.2
        rim_height = 1.0
        rim_width = 0.4
        "#,
    );
    let set = sample_defects(&b, &spec, 5).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let f = frame_of(&face_frames(&b), "C");
    let highest = face_vertices(&out, f)
        .iter()
        .map(|&p| -depth(f, p))
        .fold(0.0, f64::max);
    // Rim as high as the dent is deep (0.1 mm), within the patch resolution.
    assert!(
        highest > 0.09 && highest <= 0.1 + 1e-5,
        "rim height {highest}"
    );
}

#[test]
fn defects_that_cannot_fit_or_do_not_fit_this_mesh_are_errors() {
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        max_tries = 50
        [[dent]]
        name = "huge"
        quantity = 1
        diameter_mm = 19.9
        elongation = 1
        depth = 0.1
        "#,
    );
    let err = sample_defects(&b, &spec, 1).unwrap_err();
    assert!(matches!(err, DefectError::NoFit { .. }), "{err}");
    assert!(err.to_string().contains("huge"), "{err}");
    let json = r#"{"seed":0,"resolution":8,"defects":[
      {"instance":1,"class":1,"name":"edge","face":"A","shape":{"kind":"dent","centre_uv_mm":[9.9,0],
       "diameter_mm":1.0,"minor_mm":1.0,"rotation_deg":0,"depth_mm":0.1,"rim_height_mm":0,"rim_width":0.5}}]}"#;
    let set: DefectSet = serde_json::from_str(json).unwrap();
    assert!(matches!(
        imprint(&b, &set),
        Err(DefectError::OutsideFace { instance: 1, .. })
    ));
    // A mesh without labelled faces.
    let mut plain = b.clone();
    plain.labels.iter_mut().for_each(|l| l.face = 0);
    assert!(matches!(
        sample_defects(&plain, &DefectSpec::paper(), 1),
        Err(DefectError::NoFace { .. })
    ));
}

#[test]
fn a_curvy_scratch_removes_the_volume_of_its_path_length() {
    // Constant depth, so removed volume = (2/3) w d L + the rounded ends (pi r^2 d / 2),
    // less the small overlaps on the inside of each bend: the length recovered from the
    // volume must match the path length.
    let b = testbody(Variant::B);
    let spec = dents_only(
        r#"
        faces = ["B"]
        [[scratch]]
        name = "curvy"
        quantity = 1
        width_mm = 0.08
        depth = 0.25
        path_length_mm = 15.0
        step_mm = 1.0
        curviness_deg = 20
        depth_variation = 0
        "#,
    );
    let set = sample_defects(&b, &spec, 17).unwrap();
    let out = imprint(&b, &set).unwrap();
    check_imprinted(&b, &set, &out);
    let Shape::Scratch(s) = &set.defects[0].shape else {
        unreachable!()
    };
    let f = frame_of(&face_frames(&b), "B");
    let removed = removed_volume(&out, f, 1);
    let (w, d) = (s.width_mm, s.depth_mm[0]);
    let caps = std::f64::consts::PI / 2.0 * (w / 2.0).powi(2) * d;
    let measured = (removed - caps) / (2.0 / 3.0 * w * d);
    let turns: f64 = s
        .path_uv_mm
        .windows(3)
        .map(|p| {
            let (a, b, c) = (DVec2::from(p[0]), DVec2::from(p[1]), DVec2::from(p[2]));
            (b - a).angle_to(c - b).abs()
        })
        .sum();
    assert!(
        turns > 1.0,
        "the walk should bend (total turning {turns} rad)"
    );
    assert!(
        (measured - s.length_mm).abs() < 0.02 * s.length_mm,
        "length from volume {measured} vs path {}",
        s.length_mm
    );
}

/// Planar regions (scene::regions) of a defected mesh are those of the undefected one:
/// same ids, planes, frames, centres and areas; every defect triangle is in the region
/// of its face.
#[test]
fn planar_regions_survive_the_imprint() {
    use synosis::scene::regions::{RegionTolerance, planar_regions, region_per_triangle};
    let b = testbody(Variant::B);
    let tol = RegionTolerance::default();
    let before = planar_regions(&b, &tol);
    let set = sample_defects(&b, &DefectSpec::paper(), 3).unwrap();
    let out = imprint(&b, &set).unwrap();
    let after = planar_regions(&out, &tol);
    assert_eq!(after.len(), before.len());
    for (x, y) in before.iter().zip(&after) {
        assert_eq!((x.id, x.face), (y.id, y.face));
        assert!((x.normal - y.normal).length() < 1e-5);
        assert!((x.u - y.u).length() < 1e-5 && (x.v - y.v).length() < 1e-5);
        assert!(
            (x.centre - y.centre).length() < 1e-3,
            "{} {}",
            x.centre,
            y.centre
        );
        assert!(
            (x.area - y.area).abs() < 1e-4 * x.area,
            "{} {}",
            x.area,
            y.area
        );
    }
    let per = region_per_triangle(&out, &after);
    let mut defect_tris = 0;
    for (t, l) in out.labels.iter().enumerate() {
        assert_ne!(per[t], u32::MAX);
        if l.class != 0 {
            defect_tris += 1;
            assert_eq!(after[per[t] as usize].face, l.face);
        }
    }
    assert!(defect_tris > 0);
}
