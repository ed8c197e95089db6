//! `synosis raycast` end to end and the two backends' images against each other.

mod common;

use std::process::Command;

use glam::Vec3;
use synosis::render::raycast::raycast;
use synosis::scene::Camera;
use synosis::scene::procedural::bumpy_sphere;
use synosis::scene::{Mesh, TriLabel, export_mesh};
use synosis::trace::{Backend, TraceScene};
use synosis::vk::{LaneWidth, lanes};

/// A bumpy sphere standing on a thin slab: depth edges, grazing silhouettes, a plane.
fn test_mesh() -> Mesh {
    let mut m = bumpy_sphere(96, 48, 10.0, 0.05);
    for p in &mut m.positions {
        p.z += 11.0;
    }
    let (lo, hi) = (Vec3::new(-20.0, -15.0, 0.0), Vec3::new(20.0, 15.0, 1.0));
    let base = m.positions.len() as u32;
    for i in 0..8 {
        m.positions.push(Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        ));
    }
    for f in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        m.triangles.push([base + f[0], base + f[1], base + f[2]]);
        m.triangles.push([base + f[0], base + f[2], base + f[3]]);
        m.labels.extend([TriLabel::default(); 2]);
    }
    m
}

// Lavapipe compiles for the vector width vk::lanes chose, or the user's: its device name
// ends in "(LLVM x, N bits)". Fails if the width was set after the driver had loaded.
#[test]
fn lavapipe_runs_at_the_chosen_lane_width() {
    let ctx = common::gpu();
    if !ctx.info.is_cpu {
        return;
    }
    let name = &ctx.info.name;
    match &ctx.info.cpu_lanes {
        LaneWidth::Wide => assert!(name.contains(", 512 bits)"), "{name}"),
        LaneWidth::User(v) => assert!(name.contains(&format!(", {v} bits)")), "{name}"),
        LaneWidth::Driver => assert!(!name.contains(", 512 bits)"), "{name}"),
    }
}

// vk::lanes' own choice where the environment leaves the width to it: 512 bits on an
// Intel CPU with AVX-512F and on an AMD Zen 5 or later with it, the driver's default
// elsewhere. tools/test runs the suite at the driver's 256 bits
// (LP_NATIVE_VECTOR_WIDTH=256: half the cold compiles' time), so this test is what
// checks the choice there: a process without the variable (no pipeline compiled).
#[test]
fn lavapipe_runs_at_the_lane_width_chosen_for_this_cpu() {
    if !common::gpu().info.is_cpu {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = synosis()
        .args(["info", "--json"])
        .env_remove(lanes::WIDTH_VAR)
        .env(lanes::CACHE_VAR, dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let name = info["name"].as_str().unwrap();
    let wide = lanes::preferred_here();
    assert_eq!(
        info["cpu_lanes"],
        if wide { "wide" } else { "driver" },
        "{info}"
    );
    assert_eq!(name.contains(", 512 bits)"), wide, "{name}");
    if wide {
        assert_eq!(
            info["cpu_shader_cache"]
                .as_str()
                .map(std::path::PathBuf::from),
            Some(dir.path().join("lavapipe-lanes-512")),
            "{info}"
        );
    }
}

#[test]
fn backends_give_the_same_raycast_image() {
    let ctx = common::gpu();
    let mesh = test_mesh();
    let cam = Camera::framing(&mesh, 320, 240);
    let imgs: Vec<_> = [Backend::RayQuery, Backend::Software]
        .iter()
        .map(|&b| {
            let scene = TraceScene::build(&ctx, &mesh, b, None).unwrap();
            raycast(&ctx, &scene, &cam, None).unwrap()
        })
        .collect();
    let (a, b) = (&imgs[0], &imgs[1]);
    let hits = a.depth.iter().filter(|&&d| d > 0.0).count();
    // The framing camera fits the box's top; the slab 20 mm lower fills about 40 %.
    assert!(
        hits > 320 * 240 * 3 / 10,
        "the mesh should fill much of the frame ({hits} hits)"
    );
    let mask_diff = a
        .depth
        .iter()
        .zip(&b.depth)
        .filter(|(x, y)| (**x > 0.0) != (**y > 0.0))
        .count();
    let depth_diff = a
        .depth
        .iter()
        .zip(&b.depth)
        .filter(|(x, y)| **x > 0.0 && **y > 0.0 && (**x - **y).abs() > 1e-4 * x.max(1.0))
        .count();
    let normal_diff = a
        .normals
        .iter()
        .zip(&b.normals)
        .filter(|(x, y)| x != y)
        .count();
    eprintln!(
        "raycast 320x240: hit-mask differences {mask_diff}, depth differences {depth_diff}, normal differences {normal_diff}"
    );
    // Measured on lavapipe: 0 mask, 0 depth and 9 normal differences of 76,800 pixels;
    // the normals differ where a ray passes exactly through an edge and each backend
    // reports one of the two triangles at the same distance. Bounds: 3 mask or depth
    // pixels, 0.05 % (38) normal pixels.
    assert!(
        mask_diff <= 3 && depth_diff <= 3,
        "backends disagree: {mask_diff} mask, {depth_diff} depth pixels"
    );
    assert!(
        normal_diff <= 38,
        "backends disagree on {normal_diff} normals"
    );
    common::assert_clean(&ctx);
}

fn synosis() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_synosis"));
    c.env("SYNOSIS_VALIDATION", "1");
    c
}

#[test]
fn cli_raycast_writes_depth_normals_and_profile_for_gltf_and_glb() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = test_mesh();
    for (ext, accel) in [("glb", "ray-query"), ("gltf", "software")] {
        let m = dir.path().join(format!("mesh.{ext}"));
        export_mesh(&mesh, &m).unwrap();
        let out = dir.path().join(format!("out-{ext}"));
        let prof = dir.path().join(format!("prof-{ext}.json"));
        let st = synosis()
            .args([
                "raycast",
                m.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--accel",
                accel,
            ])
            .args([
                "--width",
                "64",
                "--height",
                "48",
                "--profile",
                prof.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(
            st.status.success(),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
        let (w, h, depth) = synosis::image_io::read_exr_f32(&out.join("depth.exr")).unwrap();
        assert_eq!((w, h), (64, 48));
        // The camera sits above the slab's top (z = 1) and the sphere's top (z = 21).
        let max = depth.iter().cloned().fold(0.0f32, f32::max);
        let min_hit = depth
            .iter()
            .cloned()
            .filter(|&d| d > 0.0)
            .fold(f32::INFINITY, f32::min);
        assert!(
            min_hit > 0.0 && max > min_hit + 15.0,
            "depth range {min_hit}..{max}"
        );
        let normals = image::open(out.join("normals.png")).unwrap().to_rgba8();
        assert_eq!(normals.dimensions(), (64, 48));
        // Pixel (14, 24) sees the slab's top face between the sphere and the slab's edge:
        // normal exactly +Z, encoded (128, 128, 255); the corner sees nothing.
        assert_eq!(normals.get_pixel(14, 24).0, [128, 128, 255, 255]);
        assert_eq!(normals.get_pixel(0, 0).0, [0, 0, 0, 0]);
        let trace: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&prof).unwrap()).unwrap();
        let names: Vec<String> = trace["traceEvents"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["ph"] == "X")
            .map(|e| {
                format!(
                    "{}:{}",
                    e["cat"].as_str().unwrap(),
                    e["name"].as_str().unwrap()
                )
            })
            .collect();
        assert!(names.contains(&"gpu:raycast".to_string()), "{names:?}");
        assert!(names.iter().any(|n| n == "cpu:readback"), "{names:?}");
        let build = if accel == "software" {
            "cpu:BVH build (obvhs)"
        } else {
            "cpu:AS build (BLAS+TLAS)"
        };
        assert!(names.iter().any(|n| n == build), "{names:?}");
    }
}

#[test]
fn cli_bad_inputs_fail_clearly_and_leave_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let malformed = dir.path().join("malformed.gltf");
    std::fs::write(&malformed, b"{\"asset\": 7").unwrap();
    let empty = dir.path().join("empty.gltf");
    std::fs::write(
        &empty,
        br#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[]}],"scene":0}"#,
    )
    .unwrap();
    let degenerate = dir.path().join("degenerate.glb");
    let mut m = test_mesh();
    m.triangles.push([0, 0, 1]);
    m.labels.push(TriLabel::default());
    export_mesh(&m, &degenerate).unwrap();
    let missing = dir.path().join("missing.glb");
    for (path, expect) in [
        (&malformed, "not a valid glTF"),
        (&missing, "file not found"),
        (&empty, "no triangles"),
        (&degenerate, "degenerate"),
    ] {
        let out = dir.path().join("out");
        let r = synosis()
            .args([
                "raycast",
                path.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{}: should fail", path.display());
        assert!(
            err.contains(expect),
            "{}: error should say {expect:?}, got {err}",
            path.display()
        );
        assert!(
            err.contains(path.file_name().unwrap().to_str().unwrap()),
            "error names the file: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            !out.exists(),
            "no output may be left behind for {}",
            path.display()
        );
    }
    // With --drop-degenerate the same mesh renders.
    let out = dir.path().join("out");
    let r = synosis()
        .args([
            "raycast",
            degenerate.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--drop-degenerate",
        ])
        .args(["--width", "32", "--height", "24"])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.join("depth.exr").exists());
}

/// A calibrated camera with strong distortion and an off-centre principal point: the
/// depth of every pixel on a tilted plane, on both backends, is the CPU camera model's
/// (`Camera::dir`, the reference for every pass's `camera_dir`).
#[test]
fn distorted_camera_rays_match_the_cpu_model_on_both_backends() {
    use synosis::scene::{Distortion, Intrinsics};
    let ctx = common::gpu();
    // The plane z = 0.2 x, far larger than the view.
    let plane = |x: f32, y: f32| Vec3::new(x, y, 0.2 * x);
    let mesh = Mesh {
        positions: vec![
            plane(-200.0, -200.0),
            plane(200.0, -200.0),
            plane(200.0, 200.0),
            plane(-200.0, 200.0),
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        labels: vec![TriLabel::default(); 2],
    };
    let k = Intrinsics {
        fx: 60.0,
        fy: 62.0,
        cx: 35.2,
        cy: 20.7,
        width: 64,
        height: 48,
        distortion: Distortion {
            k1: -0.2,
            k2: 0.05,
            p1: 2.0e-3,
            p2: -1.0e-3,
            k3: 0.0,
        },
    };
    let base = Camera::look(Vec3::new(0.0, 0.0, 50.0), -Vec3::Z, Vec3::Y, 40.0, 64, 48);
    let cam = base.with_intrinsics(&k);
    let undistorted = base.with_intrinsics(&Intrinsics {
        distortion: Distortion::default(),
        ..k
    });
    let expect = |c: &Camera, px: u32, py: u32| {
        let d = c.pixel_dir(px, py);
        // eye + t d on z = 0.2 x.
        (0.2 * c.eye.x - c.eye.z) / (d.z - 0.2 * d.x)
    };
    for b in [Backend::RayQuery, Backend::Software] {
        let scene = TraceScene::build(&ctx, &mesh, b, None).unwrap();
        let img = raycast(&ctx, &scene, &cam, None).unwrap();
        let (mut worst, mut moved) = (0.0f32, 0usize);
        for py in 0..48 {
            for px in 0..64 {
                let got = img.depth[(py * 64 + px) as usize];
                let want = expect(&cam, px, py);
                worst = worst.max((got - want).abs() / want);
                // Without the distortion the depth would differ.
                moved += ((expect(&undistorted, px, py) - want).abs() / want > 1e-3) as usize;
            }
        }
        eprintln!(
            "{}: worst relative depth error {worst:e}; {moved} of 3072 pixels move with the distortion",
            b.name()
        );
        assert!(
            worst < 1e-4,
            "{}: GPU rays differ from the CPU camera ({worst})",
            b.name()
        );
        assert!(moved > 1000, "the test distortion is too weak ({moved})");
    }
    common::assert_clean(&ctx);
}

// Processes at different lavapipe lane widths, one after the other, on one shader-cache
// folder: each compiles into its own width's folder (vk::lanes). Mesa keys lavapipe's
// cached texel-fetch functions by the texture's format alone, so without the folders a
// shader compiled at one width (here: the other backend's raycast, not yet cached) calls
// the functions another width compiled: measured with Mesa 25.0.7, the second run below
// (128 bits after 256) died of a segmentation fault, and at 512 bits after 256 a raycast
// missed every triangle without an error. 128 and 256 bits run on every x86-64 CPU with
// AVX. The two backends' depths are the same bytes; each run under a deadline.
#[test]
fn lane_widths_one_after_another_share_a_cache_folder() {
    if !common::gpu().info.is_cpu || !cfg!(target_arch = "x86_64") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("body.glb");
    let st = synosis()
        .args(["testbody", "--out"])
        .arg(&mesh)
        .status()
        .unwrap();
    assert!(st.success());
    let cache = dir.path().join("cache");
    let mut depths = Vec::new();
    let runs = [
        ("256", "software"),
        ("128", "software-wide"),
        ("256", "software-wide"),
    ];
    for (i, (bits, accel)) in runs.into_iter().enumerate() {
        let out = dir.path().join(format!("out{i}"));
        let mut child = synosis()
            .args([
                "raycast", "--width", "48", "--height", "32", "--accel", accel,
            ])
            .arg("--out")
            .arg(&out)
            .arg(&mesh)
            .env(lanes::WIDTH_VAR, bits)
            .env(lanes::CACHE_VAR, &cache)
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if start.elapsed() > std::time::Duration::from_secs(300) {
                child.kill().unwrap();
                panic!("run {i} ({accel} at {bits} bits) hung");
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        };
        assert!(
            status.success(),
            "run {i} ({accel} at {bits} bits): {status}"
        );
        assert!(
            cache.join(format!("lavapipe-lanes-{bits}")).is_dir(),
            "no cache folder of {bits} bits"
        );
        depths.push(std::fs::read(out.join("depth.exr")).unwrap());
    }
    assert!(depths.iter().all(|d| *d == depths[0]), "the depths differ");
}
