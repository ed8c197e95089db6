//! `synosis defects` and `synosis testbody` end to end: outputs, sidecar, and nothing
//! written when the input is bad.

use std::process::Command;

use synosis::defect::{DefectSet, imprint};
use synosis::scene::{Degenerates, import_mesh};

fn synosis() -> Command {
    Command::new(env!("CARGO_BIN_EXE_synosis"))
}

#[test]
fn cli_writes_mesh_and_sidecar_that_reproduce_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let body = dir.path().join("m.glb");
    let st = synosis()
        .args(["testbody", "--variant", "m", "--out"])
        .arg(&body)
        .status()
        .unwrap();
    assert!(st.success());
    let out = dir.path().join("d.glb");
    let st = synosis()
        .arg("defects")
        .arg(&body)
        .args(["--seed", "9", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let sidecar = dir.path().join("d.defects.json");
    let set: DefectSet = serde_json::from_slice(&std::fs::read(&sidecar).unwrap()).unwrap();
    assert_eq!(set.seed, 9);
    assert_eq!(set.defects.len(), 12);
    // The sidecar re-imprinted onto the input gives the written mesh (up to the f32
    // round trip, which is exact).
    let input = import_mesh(&body, Degenerates::Reject).unwrap().mesh;
    let again = imprint(&input, &set).unwrap();
    let written = import_mesh(&out, Degenerates::Reject).unwrap().mesh;
    assert_eq!(again.positions, written.positions);
    assert_eq!(again.triangles.len(), written.triangles.len());
    let mut a = again.labels.clone();
    let mut b = written.labels.clone();
    a.sort();
    b.sort();
    assert_eq!(a, b);
}

#[test]
fn bad_spec_or_bad_sidecar_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("bad.toml");
    std::fs::write(
        &spec,
        "[[dent]]\nname = \"x\"\nquantity = 1\ndiameter_mm = 0.1\nelongation = 1\ndepth = 5\n",
    )
    .unwrap();
    let out = dir.path().join("d.glb");
    let body = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/testbody-b.glb");
    let res = synosis()
        .arg("defects")
        .arg(&body)
        .arg("--spec")
        .arg(&spec)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!res.status.success());
    let msg = String::from_utf8_lossy(&res.stderr);
    assert!(msg.contains("dent[0] (x).depth"), "{msg}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only the spec remains"
    );
    // A sidecar with a malformed scratch is refused, not indexed out of bounds.
    let set: DefectSet = serde_json::from_str(
        r#"{"seed":0,"resolution":8,"defects":[{"instance":1,"class":2,"name":"s","face":"A",
        "shape":{"kind":"scratch","path_uv_mm":[[0,0],[1,0]],"depth_mm":[0.01],"width_mm":0.1,
        "length_mm":1,"step_mm":1,"curviness_deg":0}}]}"#,
    )
    .unwrap();
    let mesh = import_mesh(&body, Degenerates::Reject).unwrap().mesh;
    let err = imprint(&mesh, &set).unwrap_err().to_string();
    assert!(err.contains("depth_mm"), "{err}");
}
