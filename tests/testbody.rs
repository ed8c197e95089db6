//! The built-in test body: closed, manifold, outward, the inspected faces where promised,
//! and the shipped glTF files equal to what the generator writes.

use glam::{DVec3, Vec3};
use synosis::defect::check_closed_manifold;
use synosis::scene::mesh::{FACE_A, FACE_B, FACE_C, FACE_OTHER};
use synosis::scene::testbody::{Variant, face_frames, mirror_x, testbody};
use synosis::scene::{Degenerates, Mesh, export_mesh, import_mesh};

fn signed_volume(m: &Mesh) -> f64 {
    (0..m.triangles.len())
        .map(|t| {
            let [a, b, c] = m.corners(t).map(|p| p.as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

#[test]
fn both_variants_are_closed_outward_and_about_50_mm() {
    for v in [Variant::B, Variant::M] {
        let m = testbody(v);
        check_closed_manifold(&m).unwrap_or_else(|e| panic!("{v:?}: {e}"));
        assert!(m.degenerate_triangles().is_empty(), "{v:?}");
        let (lo, hi) = m.bounds();
        let size = hi - lo;
        for k in 0..3 {
            assert!((size[k] - 50.0).abs() < 1e-4, "{v:?} size {size}");
        }
        assert!(lo.z.abs() < 1e-6, "{v:?} stands on z = 0, min z = {}", lo.z);
        // Outward winding gives a positive enclosed volume: the block minus its three
        // cuts (two 24 mm chamfers, a 40 mm corner), about 86000 mm^3.
        let vol = signed_volume(&m);
        assert!(
            vol > 0.6 * 125_000.0 && vol < 125_000.0,
            "{v:?} volume {vol}"
        );
        // Every triangle's normal points away from the body's centroid side of its plane
        // (convex body): the centre lies behind every face.
        let centre = DVec3::new(0.0, 0.0, 25.0);
        for t in 0..m.triangles.len() {
            let [a, ..] = m.corners(t).map(|p| p.as_dvec3());
            let n = m.area_normal(t).as_dvec3();
            assert!(n.dot(a - centre) > 0.0, "{v:?} triangle {t} faces inward");
        }
    }
}

#[test]
fn inspected_faces_are_20_mm_squares_seen_from_distinct_directions() {
    let m = testbody(Variant::B);
    let frames = face_frames(&m);
    assert_eq!(
        frames.iter().map(|f| f.face).collect::<Vec<_>>(),
        vec![FACE_A, FACE_B, FACE_C]
    );
    for f in &frames {
        assert!(
            (f.area - 400.0).abs() < 1e-2,
            "face {} area {}",
            f.face,
            f.area
        );
        assert!((f.half_size - glam::Vec2::splat(10.0)).abs().max_element() < 1e-3);
        assert!((f.normal.length() - 1.0).abs() < 1e-6);
        assert!(f.u.dot(f.normal).abs() < 1e-6 && f.v.dot(f.normal).abs() < 1e-6);
        assert!(
            (f.u.cross(f.v) - f.normal).length() < 1e-5,
            "(u, v, n) right-handed"
        );
        // The face looks up or sideways, never down at the table.
        assert!(f.normal.z > -1e-6, "face {} normal {}", f.face, f.normal);
        // A camera 90 mm out along the normal, tilted 20 degrees, stays above the table.
        let cam = f.centre + f.normal * 90.0;
        assert!(cam.z > 20.0, "face {} camera at {cam}", f.face);
    }
    for i in 0..3 {
        for j in i + 1..3 {
            let c = frames[i].normal.dot(frames[j].normal);
            assert!(c < 0.7, "faces {i} and {j} face similar directions ({c})");
        }
    }
    // Every triangle of an inspected face lies inside its square.
    for t in 0..m.triangles.len() {
        let face = m.labels[t].face;
        if face == FACE_OTHER {
            continue;
        }
        let f = frames.iter().find(|f| f.face == face).unwrap();
        for p in m.corners(t) {
            let d = p - f.centre;
            assert!(d.dot(f.normal).abs() < 1e-4);
            assert!(d.dot(f.u).abs() < 10.0 + 1e-3 && d.dot(f.v).abs() < 10.0 + 1e-3);
        }
    }
}

#[test]
fn mirror_has_the_same_faces_mirrored() {
    let b = testbody(Variant::B);
    let m = testbody(Variant::M);
    assert_eq!(m, mirror_x(&b));
    let mir = |p: Vec3| Vec3::new(-p.x, p.y, p.z);
    let fb = face_frames(&b);
    let fm = face_frames(&m);
    assert_eq!(fb.len(), 3);
    assert_eq!(fm.len(), 3);
    for (x, y) in fb.iter().zip(&fm) {
        assert_eq!(x.face, y.face);
        assert!((mir(x.centre) - y.centre).length() < 1e-4);
        assert!((mir(x.normal) - y.normal).length() < 1e-6);
        assert!(
            (mir(x.u) - y.u).length() < 1e-6,
            "u mirrors with the normal"
        );
        assert!((x.area - y.area).abs() < 1e-3);
    }
    // Chiral: M is not B relabelled, the mirrored centres are not B's.
    assert!((fb[1].centre - fm[1].centre).length() > 1.0);
    assert!((signed_volume(&b) - signed_volume(&m)).abs() < 1e-3);
}

#[test]
fn shipped_files_equal_the_generator_output() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for (v, name) in [
        (Variant::B, "testbody-b.glb"),
        (Variant::M, "testbody-m.glb"),
    ] {
        let fresh = dir.path().join(name);
        export_mesh(&testbody(v), &fresh).unwrap();
        let shipped = root.join("scenes").join(name);
        let a = std::fs::read(&fresh).unwrap();
        let b = std::fs::read(&shipped).unwrap_or_else(|e| panic!("{}: {e}", shipped.display()));
        assert!(
            a == b,
            "{name} drifted from the generator: run `synosis testbody --variant ... --out scenes/{name}`"
        );
        // And it imports back identically, labels included.
        let back = import_mesh(&shipped, Degenerates::Reject).unwrap().mesh;
        assert_eq!(back, testbody(v));
    }
}
