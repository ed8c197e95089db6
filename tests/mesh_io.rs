//! glTF import/export: round trip with labels, and every bad input gets a clear error.

use glam::Vec3;
use synosis::scene::{Degenerates, Mesh, MeshError, TriLabel, export_mesh, import_mesh};

fn quad(label_b: TriLabel) -> Mesh {
    Mesh {
        positions: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        labels: vec![
            TriLabel {
                face: 1,
                class: 0,
                instance: 0,
            },
            label_b,
        ],
    }
}

#[test]
fn round_trip_glb_and_gltf_keep_geometry_and_labels() {
    let dir = tempfile::tempdir().unwrap();
    let m = quad(TriLabel {
        face: 3,
        class: 2,
        instance: 7,
    });
    for name in ["q.glb", "q.gltf"] {
        let p = dir.path().join(name);
        export_mesh(&m, &p).unwrap();
        let back = import_mesh(&p, Degenerates::Reject).unwrap().mesh;
        assert_eq!(back.triangles.len(), 2, "{name}");
        // Exported primitives share one vertex list, so the import is identical.
        assert_eq!(back, m, "{name}");
    }
}

#[test]
fn missing_file_is_a_clear_error() {
    let e = import_mesh("/nonexistent/x.glb".as_ref(), Degenerates::Reject)
        .err()
        .unwrap();
    assert!(matches!(e, MeshError::NotFound { .. }));
    assert!(e.to_string().contains("/nonexistent/x.glb"));
}

#[test]
fn malformed_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.gltf");
    std::fs::write(&p, b"{ this is not json").unwrap();
    let e = import_mesh(&p, Degenerates::Reject).err().unwrap();
    assert!(matches!(e, MeshError::Malformed { .. }), "{e}");
    let p = dir.path().join("bad.glb");
    std::fs::write(&p, b"glTF\x02\x00\x00\x00garbage").unwrap();
    let e = import_mesh(&p, Degenerates::Reject).err().unwrap();
    assert!(matches!(e, MeshError::Malformed { .. }), "{e}");
}

#[test]
fn empty_mesh_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("empty.gltf");
    std::fs::write(
        &p,
        br#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[]}],"scene":0}"#,
    )
    .unwrap();
    let e = import_mesh(&p, Degenerates::Reject).err().unwrap();
    assert!(matches!(e, MeshError::Empty { .. }), "{e}");
}

#[test]
fn degenerate_triangles_are_rejected_or_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = quad(TriLabel::default());
    m.positions.push(Vec3::new(2.0, 0.0, 0.0));
    m.triangles.push([0, 1, 4]); // collinear corners: zero area
    m.labels.push(TriLabel::default());
    let p = dir.path().join("deg.glb");
    export_mesh(&m, &p).unwrap();
    let e = import_mesh(&p, Degenerates::Reject).err().unwrap();
    match e {
        MeshError::Degenerate { count, first, .. } => assert_eq!((count, first), (1, 2)),
        other => panic!("expected Degenerate, got {other}"),
    }
    let ok = import_mesh(&p, Degenerates::Drop).unwrap();
    assert_eq!(ok.dropped_degenerate, 1);
    assert_eq!(ok.mesh.triangles.len(), 2);
}
