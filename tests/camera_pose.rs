//! Camera poses (docs/scene-format.md, `[camera]`): a look-at pose equal to a
//! face-relative view gives the identical camera and image; a 4 x 4 matrix gives the
//! same camera; OpenCV rvec/tvec projects known points to the pixels OpenCV's pinhole
//! formula gives; several poses at once are refused naming them all.

mod common;

use glam::DVec3;
use synosis::render::energy::EnergyTables;
use synosis::render::path_trace::{RenderScene, load_object, path_trace};
use synosis::scene::config::SceneConfig;
use synosis::scene::{Camera, Variant, face_frames, testbody};

fn cfg(camera: &str) -> SceneConfig {
    let text = format!("[camera]\n{camera}\n[render]\nspp = 4\nbatch_spp = 4\nseed = 9\n");
    let mut c = SceneConfig::parse(&text).unwrap_or_else(|e| panic!("{camera}: {e}"));
    c.set_resolution(48, 40).unwrap();
    c
}

fn f64s(v: DVec3) -> String {
    format!("[{:?}, {:?}, {:?}]", v.x, v.y, v.z)
}

#[test]
fn look_at_and_matrix_equal_to_a_view_give_the_same_image() {
    // View A20 by its definition: tilted 20 degrees from the normal of face A towards
    // its u axis, at the working distance (90 mm) from its centre, image up the tilted u.
    let frame = face_frames(&testbody(Variant::B))[0];
    let th = 20f64.to_radians();
    let (n, u) = (frame.normal.as_dvec3(), frame.u.as_dvec3());
    let dir = n * th.cos() + u * th.sin();
    let eye = frame.centre.as_dvec3() + dir * 90.0;
    let up = (u * th.cos() - n * th.sin()).normalize();
    let look = cfg(&format!(
        "look_at = {{ eye = {}, target = {}, up = {} }}",
        f64s(eye),
        f64s(frame.centre.as_dvec3()),
        f64s(up)
    ));
    let view = cfg("view = \"A20\"");
    // World-from-camera: columns right, up, back (-forward), eye.
    let fwd = -dir.normalize();
    let right = fwd.cross(up).normalize();
    let row = |i: usize| format!("[{:?}, {:?}, {:?}, {:?}]", right[i], up[i], -fwd[i], eye[i]);
    let matrix = cfg(&format!(
        "matrix = [{}, {}, {}, [0.0, 0.0, 0.0, 1.0]]",
        row(0),
        row(1),
        row(2)
    ));
    let ctx = common::gpu();
    let tables = EnergyTables::compute();
    let mut cams = Vec::new();
    let mut imgs = Vec::new();
    for (k, c) in [&view, &look, &matrix].into_iter().enumerate() {
        let object = load_object(c).unwrap();
        let scene = RenderScene::assemble(&object, c).unwrap();
        cams.push(scene.view.camera);
        if k < 2 {
            // Every backend: [view's, then look_at's, in BACKENDS order].
            for backend in common::BACKENDS {
                let img = path_trace(&ctx, &scene, c, backend, &tables, None, |_| {}).unwrap();
                assert!(img.data.iter().any(|&v| v > 0.0));
                imgs.push(img.data);
            }
        }
    }
    common::assert_clean(&ctx);
    assert_eq!(cams[0], cams[1], "look_at gives the view's camera exactly");
    let n = common::BACKENDS.len();
    for (k, b) in common::BACKENDS.iter().enumerate() {
        assert!(
            imgs[k] == imgs[n + k],
            "and the identical image ({})",
            b.name()
        );
    }
    let (a, m): (Camera, Camera) = (cams[0], cams[2]);
    for (x, y) in [
        (a.eye, m.eye),
        (a.forward, m.forward),
        (a.up, m.up),
        (a.right, m.right),
    ] {
        assert!((x - y).length() < 1e-5 * x.length().max(1.0), "{x} vs {y}");
    }
}

/// exp([r]x) by its power series: a rotation matrix computed without Rodrigues' formula.
fn rotation_by_series(r: [f64; 3]) -> [[f64; 3]; 3] {
    let k = [[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]];
    let mul = |a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]| {
        let mut c = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|l| a[i][l] * b[l][j]).sum();
            }
        }
        c
    };
    let mut sum = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut term = sum;
    for n in 1..40 {
        term = mul(&term, &k);
        for row in term.iter_mut() {
            for x in row.iter_mut() {
                *x /= n as f64;
            }
        }
        for i in 0..3 {
            for j in 0..3 {
                sum[i][j] += term[i][j];
            }
        }
    }
    sum
}

#[test]
fn opencv_extrinsics_project_like_opencv() {
    // 1224 x 1025 px of 6.9 um, f = 25 mm: fx = fy = 25 / 0.0069 px; OpenCV's pixel
    // centres are integers, so the principal point of a centred sensor is (W-1)/2, (H-1)/2.
    let (w, h) = (1224.0, 1025.0);
    let fpx = 25.0 / 0.0069;
    let (cx, cy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
    let cases = [
        // Looking straight down from 200 mm: R = diag(1, -1, -1) (180 degrees about x).
        ([std::f64::consts::PI, 0.0, 0.0], [-10.0, 5.0, 200.0]),
        ([2.1, -0.4, 0.3], [3.0, -7.0, 150.0]),
    ];
    for (rvec, tvec) in cases {
        let r = rotation_by_series(rvec);
        let c = cfg(&format!(
            "opencv = {{ rvec = [{:?}, {:?}, {:?}], tvec = [{:?}, {:?}, {:?}] }}",
            rvec[0], rvec[1], rvec[2], tvec[0], tvec[1], tvec[2]
        ));
        let mut c = c;
        c.set_resolution(1224, 1025).unwrap();
        let object = load_object(&c).unwrap();
        let cam = RenderScene::assemble(&object, &c).unwrap().view.camera;
        // Points in front of the camera: x_cam = R x + t with z_cam in 100..250 mm.
        for xc in [
            [0.0, 0.0, 150.0],
            [12.0, -8.0, 180.0],
            [-20.0, 15.0, 120.0],
            [5.0, 30.0, 240.0],
        ] {
            // World point: R^T (x_cam - t).
            let d = [xc[0] - tvec[0], xc[1] - tvec[1], xc[2] - tvec[2]];
            let p = DVec3::new(
                (0..3).map(|i| r[i][0] * d[i]).sum(),
                (0..3).map(|i| r[i][1] * d[i]).sum(),
                (0..3).map(|i| r[i][2] * d[i]).sum(),
            );
            // OpenCV's pinhole: u = fx x / z + cx, v = fy y / z + cy.
            let u = fpx * xc[0] / xc[2] + cx;
            let v = fpx * xc[1] / xc[2] + cy;
            // synosis pixel (k) spans [k, k+1]: OpenCV u is synosis x = u + 0.5.
            let ray = cam.dir((u + 0.5) as f32, (v + 0.5) as f32);
            let to_p = (p.as_vec3() - cam.eye).normalize();
            assert!(
                ray.angle_between(to_p) < 2e-6,
                "rvec {rvec:?}: point {p} at OpenCV pixel ({u:.2}, {v:.2}): ray {ray} vs {to_p}"
            );
            // And the point is in front of the camera.
            assert!((p.as_vec3() - cam.eye).dot(cam.forward) > 0.0);
        }
    }
}

#[test]
fn poses_are_exclusive_and_checked() {
    let err = |camera: &str| {
        SceneConfig::parse(&format!("[camera]\n{camera}\n"))
            .unwrap_err()
            .to_string()
    };
    let e = err(
        "view = \"A10\"\nlook_at = { eye = [0, 0, 100], target = [0, 0, 0], up = [0, 1, 0] }\nopencv = { rvec = [0, 0, 0], tvec = [0, 0, 0] }",
    );
    assert!(
        e.contains("camera.view") && e.contains("camera.look_at") && e.contains("camera.opencv"),
        "{e}"
    );
    let e = err("look_at = { eye = [0, 0, 100], target = [0, 0, 0] }");
    assert!(
        e.contains("camera.look_at") && e.contains("parallel"),
        "{e}"
    );
    let e = err("look_at = { eye = [1, 2, 3], target = [1, 2, 3] }");
    assert!(
        e.contains("camera.look_at") && e.contains("coincide"),
        "{e}"
    );
    let e = err("matrix = [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]");
    assert!(e.contains("camera.matrix") && e.contains("rotation"), "{e}");
    let e = err("matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]");
    assert!(e.contains("camera.matrix") && e.contains("last row"), "{e}");
    let e = err("opencv = { rvec = [0, 0, 0], tvec = [0, 0, inf] }");
    assert!(e.contains("camera.opencv") && e.contains("tvec"), "{e}");
    // A free pose alone is fine; the default view still applies without one.
    SceneConfig::parse("[camera]\nlook_at = { eye = [0, -120, 80], target = [0, 0, 10] }\n")
        .unwrap();
}
