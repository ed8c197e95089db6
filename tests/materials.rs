//! Materials per region (`[[material.region]]`, docs/scene-format.md): each region
//! renders with its own BSDF (a Lambertian region against the irradiance integral, a
//! conductor preset against the Rust BSDF and its normal-incidence Fresnel against the
//! n, k formula), scenes without entries (or with entries equal to `[material]`) render
//! bit for bit as before, `finish = "none"` removes the slope map, and glTF material
//! names reach the selection. Both backends, lavapipe, validation on.

mod common;

use glam::Vec3;
use synosis::render::path_trace::{RenderScene, load_object};
use synosis::scene::config::SceneConfig;
use synosis::scene::materials::Preset;
use synosis::scene::mesh::{FACE_A, FACE_B};
use synosis::scene::{Mesh, TriLabel};
use synosis::trace::Backend;

fn render(cfg: &SceneConfig, object: &Mesh, backend: Backend) -> Vec<f32> {
    let scene = RenderScene::assemble(object, cfg).expect("scene");
    common::path_trace_shared(&scene, cfg, backend).data
}

/// A 200 mm plate at z = 10: the half x < 0 labelled A, the half x > 0 labelled B (one
/// planar region).
fn plate() -> Mesh {
    let mut m = Mesh::default();
    for (x, y) in [
        (-100.0, -100.0),
        (0.0, -100.0),
        (0.0, 100.0),
        (-100.0, 100.0),
        (100.0, -100.0),
        (100.0, 100.0),
    ] {
        m.positions.push(Vec3::new(x, y, 10.0));
    }
    m.triangles = vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]];
    let l = |face| TriLabel {
        face,
        ..Default::default()
    };
    m.labels = vec![l(FACE_A), l(FACE_A), l(FACE_B), l(FACE_B)];
    m
}

/// Straight above the plate's centre, direct light only, no energy compensation.
fn plate_cfg(materials: &str) -> SceneConfig {
    let text = format!(
        "[camera]\nlook_at = {{ eye = [0, 0, 100], target = [0, 0, 10], up = [0, 1, 0] }}\n\
         [material]\nenergy_compensation = false\n{materials}\
         [render]\nspp = 512\nbatch_spp = 512\nmax_bounces = 1\nseed = 5\n"
    );
    let mut cfg = SceneConfig::parse(&text).expect("plate scene");
    cfg.set_resolution(16, 12).expect("size");
    cfg
}

/// Integral over the ring light of radiance * g(wi) * cos_l / r^2 dA at p (normal +z),
/// 36 nodes per light triangle.
fn light_integral(s: &RenderScene, p: Vec3, g: impl Fn(Vec3) -> f64) -> f64 {
    common::light_integral(&s.view.light, p, 6, |w| g(w.as_vec3()))
}

fn f0(n: f32, k: f32) -> f64 {
    let (n, k) = (n as f64, k as f64);
    ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k)
}

/// Left half steel (alpha 0.3), right half Lambertian (albedo 0.6), in one image: each
/// against its own analytic value; then the left half as aluminium: the ratio of the two
/// renders is the ratio of the presets' Fresnel (same random numbers, same pdfs).
#[test]
fn each_region_renders_with_its_own_bsdf() {
    use synosis::render::bsdf::{Conductor, Fresnel, fresnel_conductor};
    let object = plate();
    let entries = |metal: &str| {
        format!(
            "[[material.region]]\nselect = [\"A\"]\npreset = \"{metal}\"\nalpha = 0.3\n\
             [[material.region]]\nselect = [\"B\"]\nkind = \"diffuse\"\nalbedo = 0.6\n"
        )
    };
    let steel_cfg = plate_cfg(&entries("steel"));
    let al_cfg = plate_cfg(&entries("aluminium"));
    let scene = RenderScene::assemble(&object, &steel_cfg).expect("scene");
    let cam = scene.view.camera;
    let (n, k) = Preset::Steel.ior();
    for p in Preset::ALL {
        let (n, k) = p.ior();
        let f = fresnel_conductor(1.0, n, k) as f64;
        assert!(
            (f - f0(n, k)).abs() < 1e-5,
            "{}: {f} vs {}",
            p.name(),
            f0(n, k)
        );
    }
    let steel = Conductor::new(0.3, Fresnel::Conductor { n, k }, None);
    for backend in common::BACKENDS {
        let a = render(&steel_cfg, &object, backend);
        let b = render(&al_cfg, &object, backend);
        let (mut worst_c, mut worst_d, mut worst_r) = (0.0f64, 0.0f64, 0.0f64);
        // 2 x 2 pixel blocks on each half, away from the seam at x = 0.
        for (cx, cy) in [(2u32, 2u32), (4, 6), (2, 9), (12, 2), (10, 6), (12, 9)] {
            let (mut got, mut got_al, mut expect_c, mut expect_d) = (0.0, 0.0, 0.0, 0.0);
            let mut side = 0.0f32;
            for px in cx..cx + 2 {
                for py in cy..cy + 2 {
                    let i = (py * cam.width + px) as usize;
                    got += a[i] as f64 / 4.0;
                    got_al += b[i] as f64 / 4.0;
                    for (sa, sb) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                        let d = cam.dir(px as f32 + sa, py as f32 + sb);
                        let p = cam.eye + d * ((10.0 - cam.eye.z) / d.z);
                        side += p.x.signum();
                        expect_c +=
                            light_integral(&scene, p, |wi| steel.eval_cos(-d, wi) as f64) / 16.0;
                        expect_d += light_integral(&scene, p, |wi| wi.z as f64) * 0.6
                            / std::f64::consts::PI
                            / 16.0;
                    }
                }
            }
            assert!(side.abs() == 16.0, "block ({cx}, {cy}) straddles the seam");
            if side < 0.0 {
                let rel = got / expect_c - 1.0;
                let ratio = (got / got_al)
                    / (f0(n, k) / f0(Preset::Aluminium.ior().0, Preset::Aluminium.ior().1))
                    - 1.0;
                println!(
                    "{} steel ({cx}, {cy}): {got:.5} vs {expect_c:.5} ({:+.2} %), steel/aluminium vs F0 ratio {:+.3} %",
                    backend.name(),
                    100.0 * rel,
                    100.0 * ratio
                );
                worst_c = worst_c.max(rel.abs());
                worst_r = worst_r.max(ratio.abs());
            } else {
                let rel = got / expect_d - 1.0;
                println!(
                    "{} diffuse ({cx}, {cy}): {got:.5} vs {expect_d:.5} ({:+.2} %)",
                    backend.name(),
                    100.0 * rel
                );
                worst_d = worst_d.max(rel.abs());
                // The diffuse half does not depend on the other half's metal.
                assert!((got - got_al).abs() <= 1e-3 * got, "{got} vs {got_al}");
            }
        }
        assert!(
            worst_c < 0.03,
            "{}: conductor off by {worst_c}",
            backend.name()
        );
        assert!(
            worst_d < 0.03,
            "{}: diffuse off by {worst_d}",
            backend.name()
        );
        assert!(
            worst_r < 0.01,
            "{}: Fresnel ratio off by {worst_r}",
            backend.name()
        );
    }
}

/// The test body at 64 x 48: entries equal to `[material]` (no preset, no roughness: they
/// inherit it) on every face render bit for bit as no entries; `finish = "none"` on every
/// region renders bit for bit as no texture.
#[test]
fn entries_equal_to_material_and_bare_finishes_change_nothing() {
    let cfg = |extra: &str, texture: &str| {
        let text = format!(
            "[camera]\nwidth = 1224\nheight = 1025\nview = \"A20\"\n{extra}[texture]\nkind = \"{texture}\"\n[render]\nspp = 4\nbatch_spp = 4\nseed = 3\n"
        );
        let mut c = SceneConfig::parse(&text).expect("scene");
        c.set_resolution(64, 48).expect("size");
        c
    };
    let same = "[[material.region]]\nselect = [\"A\", \"B\"]\n[[material.region]]\nselect = [\"C\", { normal = [0, 0, 1] }]\npreset = \"aluminium\"\n";
    let bare = "[[material.region]]\nselect = [\"A\", \"B\", \"C\"]\nfinish = \"none\"\n[[material.region]]\nselect = [{ normal = [0, 0, 1], tolerance_deg = 90 }, { normal = [0, 0, -1], tolerance_deg = 90 }]\nfinish = \"none\"\n";
    let plain = cfg("", "flat");
    let object = load_object(&plain).expect("object");
    for backend in common::BACKENDS {
        let base = render(&plain, &object, backend);
        assert!(base.iter().any(|&v| v > 0.0));
        let with = render(&cfg(same, "flat"), &object, backend);
        assert!(
            base == with,
            "{}: entries equal to [material] changed the image",
            backend.name()
        );
        let grooves = render(&cfg("", "test-grooves"), &object, backend);
        assert!(base != grooves, "the grooves must show");
        let grooves_bare = render(&cfg(bare, "test-grooves"), &object, backend);
        assert!(
            base == grooves_bare,
            "{}: finish = \"none\" still shows the map",
            backend.name()
        );
    }
}

/// glTF material names reach `gltf_material` selectors: two primitives of one quad with
/// materials "Body" and "Seat".
#[test]
fn gltf_material_names_select_triangles() {
    let dir = std::env::temp_dir().join(format!("synosis-materials-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let gltf = dir.join("quad.gltf");
    let json = r#"{
 "asset": {"version": "2.0", "generator": "synosis test"},
 "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
 "materials": [{"name": "Body"}, {"name": "Seat"}],
 "meshes": [{"primitives": [
   {"attributes": {"POSITION": 0}, "indices": 1, "material": 0},
   {"attributes": {"POSITION": 0}, "indices": 2, "material": 1}]}],
 "buffers": [{"byteLength": 60, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAAAgQQAAAAAAAAAAAAAgQQAAIEEAAAAAAAAAAAAAIEEAAAAAAAABAAIAAAACAAMA"}],
 "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 6}, {"buffer": 0, "byteOffset": 54, "byteLength": 6}],
 "accessors": [
   {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [10, 10, 0]},
   {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
   {"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}]
}"#;
    std::fs::write(&gltf, json).unwrap();
    let loaded = synosis::scene::load_mesh(
        &gltf,
        Some(synosis::scene::MeshUnit::Mm),
        synosis::scene::GltfUnitDefault::Spec,
        synosis::scene::Degenerates::Reject,
    )
    .expect("glTF");
    let m = loaded.imported.materials.expect("glTF materials");
    assert_eq!(m.names, ["Body", "Seat"]);
    assert_eq!(m.of_triangle, [0, 1]);
    // In a scene: the stage's triangle 1 takes the entry, triangle 0 keeps [material].
    let text = format!(
        "[object]\npath = {:?}\nunit = \"mm\"\n[camera]\nlook_at = {{ eye = [5, 5, 50], target = [5, 5, 0], up = [0, 1, 0] }}\n[[material.region]]\nselect = [{{ gltf_material = \"Seat\" }}]\nkind = \"diffuse\"\n",
        gltf.display()
    );
    let cfg = SceneConfig::parse(&text).expect("scene");
    let object = load_object(&cfg).expect("object");
    let scene = RenderScene::assemble(&object, &cfg).expect("scene");
    use synosis::render::path_trace::{MAT_CONDUCTOR, MAT_TABLE};
    assert_eq!(
        scene.stage.materials,
        [
            MAT_CONDUCTOR,
            synosis::gpu_interface::MAT_REGION_FIRST,
            MAT_TABLE,
            MAT_TABLE
        ]
    );
    let bad = text.replace("Seat", "Nut");
    let cfg = SceneConfig::parse(&bad).expect("scene");
    let e = RenderScene::assemble(&object, &cfg)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("material.region") && e.contains("Nut") && e.contains("Seat"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// scenes/flange-materials.toml: face A takes entry 0, the 96 chamfer facets entry 1
/// (without a finish), every other triangle `[material]`.
#[test]
fn flange_materials_scene_selects_face_and_chamfer() {
    use synosis::gpu_interface::MAT_REGION_FIRST;
    use synosis::render::path_trace::MAT_CONDUCTOR;
    let path = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/flange-materials.toml"
    ));
    let cfg = SceneConfig::load(path).expect("scene");
    let object = load_object(&cfg).expect("object");
    let scene = RenderScene::assemble(&object, &cfg).expect("scene");
    let st = &scene.stage;
    assert_eq!(st.surfaces.len(), 2);
    assert_eq!(st.surfaces[1].alpha, 0.02);
    let mut chamfer_regions = std::collections::BTreeSet::new();
    for t in 0..object.triangles.len() {
        let n = object.area_normal(t).normalize();
        let m = st.materials[t];
        if object.labels[t].face == FACE_A {
            assert_eq!(m, MAT_REGION_FIRST, "triangle {t} on A");
        } else if n.z > 0.5 && n.z < 0.9 {
            assert_eq!(m, MAT_REGION_FIRST + 1, "chamfer triangle {t}");
            chamfer_regions.insert(st.region_of[t]);
        } else {
            assert_eq!(m, MAT_CONDUCTOR, "triangle {t}");
        }
    }
    assert_eq!(chamfer_regions.len(), 96, "the chamfer's facets");
}

/// A dataset job's `[[object.material.region]]` entries (docs/dataset.md): an entry equal
/// to the object's own conductor (no values: aluminium, the instance's drawn alpha, the
/// finish) renders bit for bit as no entry; a diffuse face A changes face A's pixels and
/// no other (one bounce: nothing else sees A's BSDF); bad entries are refused by
/// `prepare_text`, before any rendering, naming `object[0].material.region`. Both
/// backends, validation on.
#[test]
fn job_objects_take_region_materials() {
    use synosis::dataset::gpu::GpuRenderer;
    use synosis::trace::AccelChoice;
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let base = std::fs::read_to_string(scenes.join("flange-dataset.toml"))
        .unwrap()
        .replace(
            "plan = { ring = { face = \"A\", tilt_deg = 20, count = 3 } }",
            "",
        )
        .replace("width = 64", "width = 40")
        .replace("height = 48", "height = 30")
        .replace("spp = 4", "spp = 2")
        .replace("bounces = 2", "bounces = 1")
        .replace("defect_free = 2", "defect_free = 1");
    let with = |entry: &str| base.replace("defect_free = 1", &format!("defect_free = 1\n{entry}"));
    let prep = |text: &str| synosis::dataset::prepare_text(text, "job.toml", scenes);

    // The instance's alpha reaches entries that give none; their own is kept.
    let p = prep(&with(
        "[[object.material.region]]\nselect = [\"A\"]\npreset = \"steel\"\n[[object.material.region]]\nselect = [{ normal = [0, 0, -1] }]\nalpha = 0.3\n",
    ))
    .unwrap();
    let r = p.job.objects[0].region_materials(0, 0.04, 550.0).unwrap();
    assert_eq!((r[0].material.alpha, r[1].material.alpha), (0.04, 0.3));
    assert_eq!(
        (r[0].material.ior_n, r[0].material.ior_k),
        Preset::Steel.ior()
    );

    for (entry, want) in [
        (
            "select = [\"A\"]\nalpha = 0.0",
            "job.toml: object[0].material.region: entry 0: alpha = 0 is out of range: allowed (0, 1]",
        ),
        (
            "select = [\"A\"]\nkind = \"glass\"",
            "object[0].material.region: entry 0: kind = \"glass\": allowed",
        ),
        (
            "select = [\"region:9999\"]",
            "object[0].material.region: entry 0: select region:9999: the mesh has",
        ),
        (
            "select = [{ normal = [1, 1, 1], tolerance_deg = 0 }]",
            "object[0].material.region: entry 0: select normal",
        ),
        (
            "select = [{ gltf_material = \"Steel\" }]",
            "object[0].material.region: entry 0: select gltf_material \"Steel\": the object is not a glTF file",
        ),
        ("select = [\"A\"]\nshine = 1", "shine"),
    ] {
        let e = prep(&with(&format!("[[object.material.region]]\n{entry}\n")))
            .err()
            .unwrap_or_else(|| panic!("{entry}: accepted"))
            .to_string();
        assert!(e.contains(want), "{entry}: {e}");
    }

    let same = with("[[object.material.region]]\nselect = [\"A\"]\n");
    let diffuse =
        with("[[object.material.region]]\nselect = [\"A\"]\nkind = \"diffuse\"\nalbedo = 0.9\n");
    for accel in [AccelChoice::RayQuery, AccelChoice::Software] {
        let mut r = GpuRenderer::new(accel, true).unwrap();
        let mut render = |text: &str| {
            let prep = prep(text).unwrap();
            let tmp = tempfile::tempdir().unwrap();
            let mut textures = synosis::dataset::texture_bridge::ModuleTextures::default();
            synosis::dataset::render_one(&prep, 0, tmp.path(), &mut r, &mut textures).unwrap();
            let dir = tmp.path().join("images/000000");
            let (_, _, radiance) =
                synosis::image_io::read_exr_f32(&dir.join("radiance.exr")).unwrap();
            let faces = image::open(dir.join("faces.png")).unwrap().into_luma8();
            (radiance, faces.into_raw())
        };
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
        let (plain, faces) = render(&base);
        let (same_img, _) = render(&same);
        assert_eq!(
            bits(&plain),
            bits(&same_img),
            "{accel:?}: an entry equal to the object's conductor"
        );
        let (diff_img, diff_faces) = render(&diffuse);
        assert_eq!(faces, diff_faces);
        // faces.png labels a pixel by its centre, the radiance integrates the pixel:
        // pixels next to an A pixel may hold some of A.
        let (w, h) = (40i64, 30i64);
        let near_a = |p: usize| {
            let (x, y) = (p as i64 % w, p as i64 / w);
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    (0..w).contains(&u) && (0..h).contains(&v) && faces[(v * w + u) as usize] == 1
                })
            })
        };
        let (mut a_plain, mut a_diff, mut n_a, mut n_off) = (0.0f64, 0.0f64, 0, 0);
        for p in 0..plain.len() {
            if faces[p] == 1 {
                a_plain += plain[p] as f64;
                a_diff += diff_img[p] as f64;
                n_a += 1;
            } else if !near_a(p) {
                assert_eq!(
                    plain[p].to_bits(),
                    diff_img[p].to_bits(),
                    "{accel:?}: pixel {p} is not on A"
                );
                n_off += 1;
            }
        }
        assert!(
            n_a >= 50 && n_off >= 50,
            "{accel:?}: {n_a} pixels on A, {n_off} off it"
        );
        let rel = (a_diff - a_plain).abs() / a_plain.max(1e-12);
        assert!(
            rel > 0.2,
            "{accel:?}: the diffuse face A renders as the conductor ({a_diff} vs {a_plain})"
        );
    }
}
