//! Anisotropic scratch meshes (issue 15): watertight by index, the same depth and removed
//! volume as the analytic groove at far fewer triangles than the isotropic mesh, and
//! robust where scratches cross each other and a dent.

use glam::DVec2;
use synosis::defect::{
    DefectSet, ImprintOptions, ScratchMesh, check_closed_manifold, imprint_with_options,
};
use synosis::scene::Mesh;
use synosis::scene::testbody::{FaceFrame, Variant, face_frames, testbody};

/// Depth below face frame `f`'s plane, mm (positive into the material).
fn depth(f: FaceFrame, p: glam::Vec3) -> f64 {
    -(p.as_dvec3() - f.centre.as_dvec3()).dot(f.normal.as_dvec3())
}

/// Removed volume of instance 1 (projected area times mean corner depth: exact for the
/// piecewise-linear surface) and its deepest vertex.
fn removed_and_deepest(out: &Mesh, f: FaceFrame) -> (f64, f64) {
    let n = f.normal.as_dvec3();
    let (mut removed, mut deepest) = (0.0, 0.0f64);
    for t in 0..out.triangles.len() {
        if out.labels[t].instance != 1 {
            continue;
        }
        let c = out.corners(t);
        let area = 0.5 * out.area_normal(t).as_dvec3().dot(n);
        removed += area * c.iter().map(|&p| depth(f, p)).sum::<f64>() / 3.0;
        deepest = c.iter().map(|&p| depth(f, p)).fold(deepest, f64::max);
    }
    (removed, deepest)
}

/// Closed, consistently wound, no degenerate triangle, none of face `f` flipped.
fn check_mesh(out: &Mesh, f: FaceFrame) {
    check_closed_manifold(out).unwrap();
    assert!(
        out.degenerate_triangles().is_empty(),
        "degenerate triangles"
    );
    for t in 0..out.triangles.len() {
        if out.labels[t].face == f.face {
            let n = out.area_normal(t).as_dvec3().normalize();
            assert!(
                n.dot(f.normal.as_dvec3()) > 1e-3,
                "triangle {t} flipped: {n}"
            );
        }
    }
}

fn straight_scratch(width: f64, depth: f64, from: [f64; 2], to: [f64; 2], instance: u16) -> String {
    let (a, b) = (DVec2::from(from), DVec2::from(to));
    let pts: Vec<String> = (0..=20)
        .map(|i| {
            let p = a + (b - a) * (i as f64 / 20.0);
            format!("[{},{}]", p.x, p.y)
        })
        .collect();
    let depths = vec![depth.to_string(); pts.len()].join(",");
    format!(
        r#"{{"instance":{instance},"class":2,"name":"s{instance}","face":"A","shape":{{"kind":"scratch",
        "path_uv_mm":[{}],"depth_mm":[{depths}],"width_mm":{width},"length_mm":{},"step_mm":0.2,
        "curviness_deg":0}}}}"#,
        pts.join(","),
        (b - a).length()
    )
}

#[test]
fn a_long_straight_scratch_keeps_depth_and_volume_with_far_fewer_triangles() {
    let body = testbody(Variant::B);
    let f = face_frames(&body)[0];
    let (w, d) = (0.05, 0.01);
    let json = format!(
        r#"{{"seed":0,"resolution":8,"defects":[{}]}}"#,
        straight_scratch(w, d, [-2.0, -1.0], [2.0, 0.5], 1)
    );
    let set: DefectSet = serde_json::from_str(&json).unwrap();
    let len = (DVec2::new(4.0, 1.5)).length();
    let r = w / 2.0;
    // Parabolic groove plus its two half-paraboloid ends.
    let analytic = 2.0 / 3.0 * w * d * len + std::f64::consts::PI / 2.0 * r * r * d;
    let mut count = Vec::new();
    for way in [ScratchMesh::Anisotropic, ScratchMesh::Isotropic] {
        let (out, stats) =
            imprint_with_options(&body, &set, ImprintOptions { scratch_mesh: way }).unwrap();
        check_mesh(&out, f);
        let (removed, deepest) = removed_and_deepest(&out, f);
        // docs/defects.md: the removed volume within 0.1 % and the depth within 0.1 % at
        // resolution 8 (measured: 1.0000 and 1.0001, the excess f32 rounding).
        assert!(
            (removed / analytic - 1.0).abs() < 1e-3,
            "{way:?}: removed {removed} vs analytic {analytic}"
        );
        assert!(
            deepest > 0.999 * d && deepest < d + 1e-5,
            "{way:?}: deepest vertex {deepest} vs depth {d}"
        );
        count.push(stats.triangles_out);
    }
    // Along a 4.3 mm straight path the anisotropic mesh needs about 1/8 of the triangles.
    assert!(
        4 * count[0] < count[1],
        "anisotropic {} vs isotropic {} triangles",
        count[0],
        count[1]
    );
}

#[test]
fn crossing_scratches_over_a_dent_stay_watertight() {
    let body = testbody(Variant::B);
    let f = face_frames(&body)[0];
    let dent = r#"{"instance":3,"class":1,"name":"dent","face":"A","shape":{"kind":"dent",
        "centre_uv_mm":[0.0,0.0],"diameter_mm":0.1,"minor_mm":0.08,"rotation_deg":20,
        "depth_mm":0.02,"rim_height_mm":0.02,"rim_width":0.5}}"#;
    let json = format!(
        r#"{{"seed":0,"resolution":8,"defects":[{},{},{}]}}"#,
        straight_scratch(0.03, 0.005, [-1.0, -0.3], [1.0, 0.3], 1),
        // Crossing at a shallow angle, through the dent.
        straight_scratch(0.02, 0.004, [-1.0, 0.05], [1.0, -0.05], 2),
        dent
    );
    let set: DefectSet = serde_json::from_str(&json).unwrap();
    let (out, _) = imprint_with_options(&body, &set, ImprintOptions::default()).unwrap();
    check_mesh(&out, f);
    for k in 1..=3u16 {
        assert!(
            out.labels.iter().any(|l| l.instance == k),
            "defect {k} has no triangles"
        );
    }
    // Where both scratches and the dent overlap, the deepest wins: the dent's 20 um.
    let deepest = (0..out.triangles.len())
        .filter(|&t| out.labels[t].face == f.face)
        .flat_map(|t| out.corners(t))
        .map(|p| depth(f, p))
        .fold(0.0, f64::max);
    assert!(deepest > 0.019 && deepest < 0.02 + 1e-5, "{deepest}");
}
