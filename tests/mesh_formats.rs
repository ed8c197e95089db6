//! Mesh formats and units (docs/mesh-format.md): the same part written as glTF, OBJ,
//! STL (binary and ASCII) and PLY (ASCII and binary) loads to the same triangles, and
//! renders the same image.

mod common;

use std::fmt::Write as _;
use std::path::Path;

use synosis::render::energy::EnergyTables;
use synosis::render::path_trace::{RenderScene, load_object, path_trace};
use synosis::scene::config::SceneConfig;
use synosis::scene::mesh::face_name;
use synosis::scene::{
    Degenerates, GltfUnitDefault, Mesh, MeshError, MeshUnit, Variant, export_mesh, load_mesh,
    testbody,
};

fn load(path: &Path, unit: Option<MeshUnit>) -> Mesh {
    load_mesh(path, unit, GltfUnitDefault::Spec, Degenerates::Reject)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .imported
        .mesh
}

/// OBJ: one group per run of equal face labels (so labels travel), coordinates divided
/// by `per_mm` (printed exactly).
fn write_obj(m: &Mesh, path: &Path, per_mm: f64) {
    let mut s = String::new();
    for p in &m.positions {
        if per_mm == 1.0 {
            writeln!(s, "v {} {} {}", p.x, p.y, p.z).unwrap();
        } else {
            let [x, y, z] = p.to_array().map(|c| c as f64 / per_mm);
            writeln!(s, "v {x:?} {y:?} {z:?}").unwrap();
        }
    }
    let mut last = None;
    for (t, l) in m.triangles.iter().zip(&m.labels) {
        if last != Some(l.face) {
            writeln!(s, "g {}", face_name(l.face)).unwrap();
            last = Some(l.face);
        }
        writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
    }
    std::fs::write(path, s).unwrap();
}

fn stl_triangles(m: &Mesh) -> Vec<stl_io::Triangle> {
    (0..m.triangles.len())
        .map(|t| {
            let c = m.corners(t);
            let n = m.area_normal(t).normalize();
            stl_io::Triangle {
                normal: stl_io::Normal::new(n.to_array()),
                vertices: c.map(|p| stl_io::Vertex::new(p.to_array())),
            }
        })
        .collect()
}

fn write_stl_ascii(m: &Mesh, path: &Path) {
    let mut s = String::from("solid part\n");
    for tri in stl_triangles(m) {
        let n = tri.normal.0;
        writeln!(s, "facet normal {} {} {}\nouter loop", n[0], n[1], n[2]).unwrap();
        for v in tri.vertices {
            writeln!(s, "vertex {} {} {}", v.0[0], v.0[1], v.0[2]).unwrap();
        }
        s.push_str("endloop\nendfacet\n");
    }
    s.push_str("endsolid part\n");
    std::fs::write(path, s).unwrap();
}

/// PLY, ASCII (double coordinates divided by `per_mm`) or binary little endian (float).
fn write_ply(m: &Mesh, path: &Path, binary: bool, per_mm: f64) {
    let ty = if binary { "float" } else { "double" };
    let fmt = if binary {
        "binary_little_endian"
    } else {
        "ascii"
    };
    let mut out = format!(
        "ply\nformat {fmt} 1.0\ncomment written by the synosis tests\nelement vertex {}\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.positions.len(),
        m.triangles.len()
    )
    .into_bytes();
    for p in &m.positions {
        if binary {
            for c in p.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        } else {
            let [x, y, z] = p.to_array().map(|c| c as f64 / per_mm);
            out.extend_from_slice(format!("{x:?} {y:?} {z:?}\n").as_bytes());
        }
    }
    for t in &m.triangles {
        if binary {
            out.push(3);
            for i in t {
                out.extend_from_slice(&(*i as i32).to_le_bytes());
            }
        } else {
            out.extend_from_slice(format!("3 {} {} {}\n", t[0], t[1], t[2]).as_bytes());
        }
    }
    std::fs::write(path, out).unwrap();
}

/// Every triangle's corners equal, bit for bit, in the same order.
fn assert_same_triangles(name: &str, a: &Mesh, b: &Mesh) {
    assert_eq!(a.triangles.len(), b.triangles.len(), "{name}");
    for t in 0..a.triangles.len() {
        let (ca, cb) = (a.corners(t), b.corners(t));
        for k in 0..3 {
            assert_eq!(
                ca[k].to_array().map(f32::to_bits),
                cb[k].to_array().map(f32::to_bits),
                "{name}: triangle {t} corner {k}: {} vs {}",
                ca[k],
                cb[k]
            );
        }
    }
}

#[test]
fn every_format_loads_the_same_triangles() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let part = testbody(Variant::B);
    export_mesh(&part, &d.join("part.glb")).unwrap();
    write_obj(&part, &d.join("part.obj"), 1.0);
    let mut f = std::fs::File::create(d.join("part.stl")).unwrap();
    stl_io::write_stl(&mut f, stl_triangles(&part).iter()).unwrap();
    drop(f);
    write_stl_ascii(&part, &d.join("part-ascii.stl"));
    write_ply(&part, &d.join("part.ply"), true, 1.0);
    write_ply(&part, &d.join("part-ascii.ply"), false, 1.0);

    // glTF written by synosis: millimetres; `unit = "mm"` on the rest.
    let glb = load(&d.join("part.glb"), None);
    assert_eq!(glb, part);
    for name in [
        "part.obj",
        "part.stl",
        "part-ascii.stl",
        "part.ply",
        "part-ascii.ply",
    ] {
        let m = load(&d.join(name), Some(MeshUnit::Mm));
        assert_same_triangles(name, &part, &m);
        if name.ends_with(".obj") {
            assert_eq!(m.labels, part.labels, "OBJ groups carry the face labels");
        } else {
            assert!(m.labels.iter().all(|l| l.face == 0), "{name}: no labels");
        }
    }

    // Units: metres (OBJ) and inches (PLY) convert back to the same f32 millimetres.
    write_obj(&part, &d.join("part-m.obj"), 1000.0);
    assert_same_triangles(
        "OBJ in m",
        &part,
        &load(&d.join("part-m.obj"), Some(MeshUnit::M)),
    );
    write_ply(&part, &d.join("part-in.ply"), false, 25.4);
    assert_same_triangles(
        "PLY in in",
        &part,
        &load(&d.join("part-in.ply"), Some(MeshUnit::In)),
    );
    // The same OBJ without a unit is read in millimetres: 1000 times smaller.
    let small = load(&d.join("part-m.obj"), None);
    assert!((small.corners(0)[0] * 1000.0 - part.corners(0)[0]).length() < 1e-3);

    // glTF of another exporter in metres (the spec): metres by default, millimetres
    // with the old `gltf` key's default, or as declared.
    let mut metres = part.clone();
    for p in &mut metres.positions {
        *p = (p.as_dvec3() / 1000.0).as_vec3();
    }
    let gltf = d.join("other.gltf");
    export_mesh(&metres, &gltf).unwrap();
    let json = std::fs::read_to_string(&gltf).unwrap();
    assert!(json.contains("\"generator\":\"synosis "));
    std::fs::write(
        &gltf,
        json.replace("\"generator\":\"synosis ", "\"generator\":\"cad "),
    )
    .unwrap();
    let spec = load(&gltf, None);
    let legacy = load_mesh(
        &gltf,
        None,
        GltfUnitDefault::Millimetres,
        Degenerates::Reject,
    )
    .unwrap()
    .imported
    .mesh;
    assert_eq!(legacy, metres);
    for t in 0..part.triangles.len() {
        for (a, b) in part.corners(t).iter().zip(spec.corners(t)) {
            assert!(
                (*a - b).length() <= 1e-5 * a.length().max(1.0),
                "{a} vs {b}"
            );
        }
    }
    assert_eq!(load(&gltf, Some(MeshUnit::Mm)), metres);
}

#[test]
fn bad_mesh_files_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let check = |name: &str, text: &str, want: &str| {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        let e = load_mesh(&p, None, GltfUnitDefault::Spec, Degenerates::Reject)
            .err()
            .unwrap_or_else(|| panic!("{name} loaded"));
        let msg = e.to_string();
        assert!(msg.contains(name) && msg.contains(want), "{name}: {msg}");
        e
    };
    check("x.step", "", "allowed: .gltf, .glb, .obj, .stl, .ply");
    check(
        "bad.ply",
        "ply\nformat ascii 1.0\nelement vertex 1\nend_header\n",
        "PLY",
    );
    check("empty.obj", "v 0 0 0\n", "no triangles");
    check("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "OBJ");
    let e = check(
        "flat.obj",
        "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 4\nf 1 2 3\n",
        "degenerate",
    );
    assert!(matches!(
        e,
        MeshError::Degenerate {
            count: 1,
            first: 1,
            ..
        }
    ));
    check(
        "nan.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n",
        "",
    );
    let p = d.join("missing.stl");
    let e = load_mesh(&p, None, GltfUnitDefault::Spec, Degenerates::Reject)
        .err()
        .unwrap();
    assert!(matches!(e, MeshError::NotFound { .. }), "{e}");
    // A file over the size limit is refused by its size, before it is read (sparse
    // files: nothing is written).
    for name in ["big.stl", "big.glb"] {
        let p = d.join(name);
        std::fs::File::create(&p)
            .unwrap()
            .set_len(synosis::limits::MAX_MESH_BYTES + 1)
            .unwrap();
        let msg = load_mesh(&p, None, GltfUnitDefault::Spec, Degenerates::Reject)
            .err()
            .unwrap_or_else(|| panic!("{name} loaded"))
            .to_string();
        assert!(
            msg.contains(name) && msg.contains("over the limit for mesh files"),
            "{name}: {msg}"
        );
    }
}

/// The same part as GLB and as STL (no labels), both given the inspected face by region
/// id, renders the identical image.
#[test]
fn glb_and_stl_render_the_same_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let part = testbody(Variant::B);
    export_mesh(&part, &d.join("part.glb")).unwrap();
    let mut f = std::fs::File::create(d.join("part.stl")).unwrap();
    stl_io::write_stl(&mut f, stl_triangles(&part).iter()).unwrap();
    drop(f);
    let regions = synosis::scene::planar_regions(&part, &Default::default());
    let a = regions.iter().find(|r| r.face == 1).unwrap().id;
    let ctx = common::gpu();
    let tables = EnergyTables::compute();
    for backend in common::BACKENDS {
        let mut images = Vec::new();
        for file in ["part.glb", "part.stl"] {
            let text = format!(
                "[object]\npath = {:?}\nunit = \"mm\"\ninspect = [\"region:{a}\"]\n[camera]\nview = \"A10\"\n[render]\nspp = 4\nbatch_spp = 4\nseed = 5\n",
                d.join(file)
            );
            let mut cfg = SceneConfig::parse(&text).expect("scene");
            cfg.set_resolution(48, 40).unwrap();
            let object = load_object(&cfg).expect("object");
            let scene = RenderScene::assemble(&object, &cfg).expect("scene");
            let img =
                path_trace(&ctx, &scene, &cfg, backend, &tables, None, |_| {}).expect("render");
            assert!(img.data.iter().any(|&v| v > 0.0));
            images.push((scene.view.camera, img.data));
        }
        common::assert_clean(&ctx);
        assert_eq!(images[0].0, images[1].0, "the same camera");
        assert!(
            images[0].1 == images[1].1,
            "{}: the same image",
            backend.name()
        );
    }
}
