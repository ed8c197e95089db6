//! The annotation pass on both backends: exact occlusion, projected areas, consistent
//! masks, agreement between backends.

mod common;

use glam::Vec3;
use synosis::render::annotate::{Annotation, annotate};
use synosis::scene::Camera;
use synosis::scene::{Mesh, TriLabel};
use synosis::trace::TraceScene;

/// A 20 x 20 mm plane (face A) at z = 0 in 0.5 mm cells, with three labelled regions:
/// dent 1 on [2,4]^2, scratch 2 on [-6,-3]^2, dent 3 on [5,8]x[-8,-5] hidden under an
/// occluding quad at z = 5.
fn scene() -> Mesh {
    use common::region as r;
    common::labelled_plane(
        20.0,
        0.0,
        &[
            r([2.0, 4.0], [2.0, 4.0], 1, 1),
            r([-6.0, -3.0], [-6.0, -3.0], 2, 2),
            r([5.0, 8.0], [-8.0, -5.0], 1, 3),
        ],
        [
            Vec3::new(4.0, -9.0, 5.0),
            Vec3::new(9.0, -9.0, 5.0),
            Vec3::new(9.0, -4.0, 5.0),
            Vec3::new(4.0, -4.0, 5.0),
        ],
    )
}

fn camera() -> Camera {
    Camera::look(Vec3::new(0.0, 0.0, 50.0), -Vec3::Z, Vec3::Y, 30.0, W, W)
}

const W: u32 = 200;

/// Side of a pixel's footprint on the plane z = 0, in mm.
fn pixel_mm() -> f32 {
    2.0 * 50.0 * (15f32).to_radians().tan() / W as f32
}

fn run(backend: synosis::trace::Backend) -> Annotation {
    let ctx = common::gpu();
    let mesh = scene();
    let ts = TraceScene::build(&ctx, &mesh, backend, None).unwrap();
    let (a, t) = annotate(&ctx, &ts, &mesh, &camera(), 4, None).unwrap();
    assert!(t.gpu_ms.is_finite());
    common::assert_clean(&ctx);
    a
}

#[test]
fn annotation_is_exact_and_consistent_on_both_backends() {
    let anns: Vec<Annotation> = common::BACKENDS.iter().map(|&b| run(b)).collect();
    let px = pixel_mm();
    for (a, backend) in anns.iter().zip(common::BACKENDS) {
        let vis = a.visible_defects();
        let get = |i: u16| {
            vis.iter()
                .find(|v| v.instance == i)
                .map(|v| v.pixels)
                .unwrap_or(0)
        };
        // Projected areas: 4 mm^2 and 9 mm^2; the pixel-centre rule can miss or add at most
        // the pixels along the border (perimeter / pixel / 2).
        for (inst, area, perimeter) in [(1u16, 4.0f32, 8.0f32), (2, 9.0, 12.0)] {
            let expected = area / (px * px);
            let tol = perimeter / px / 2.0;
            let got = get(inst) as f32;
            eprintln!(
                "{}: instance {inst}: {got} px, projected {expected:.1} (tolerance {tol:.1})",
                backend.name()
            );
            assert!(
                (got - expected).abs() <= tol,
                "{}: instance {inst} has {got} px, expected {expected}",
                backend.name()
            );
            // Soft mask: the coverage integrates the same area more finely.
            let cov: f32 = a
                .coverage
                .iter()
                .enumerate()
                .filter(|(i, _)| {
                    let (x, y) = ((*i as u32 % W) as f32, (*i as u32 / W) as f32);
                    // World position of the pixel centre on z = 0 (row 0 at the top, +Y up).
                    let wx = (x + 0.5 - W as f32 / 2.0) * px;
                    let wy = (W as f32 / 2.0 - y - 0.5) * px;
                    (wx - if inst == 1 { 3.0 } else { -4.5 }).abs() < 2.5
                        && (wy - if inst == 1 { 3.0 } else { -4.5 }).abs() < 2.5
                })
                .map(|(_, c)| c)
                .sum();
            assert!(
                (cov - expected).abs() <= expected * 0.03,
                "{}: coverage sum {cov} vs {expected}",
                backend.name()
            );
        }
        // Hidden under the occluder: no pixels, no coverage.
        assert_eq!(
            get(3),
            0,
            "{}: the hidden defect is visible",
            backend.name()
        );
        // Masks agree with each other.
        for i in 0..a.class.len() {
            assert_eq!(
                a.class[i] != 0,
                a.instance[i] != 0,
                "pixel {i}: class and instance disagree"
            );
            if a.class[i] != 0 {
                assert_eq!(a.face[i], 1, "pixel {i}: defect pixel not on face A");
                assert!(
                    a.coverage[i] > 0.0,
                    "pixel {i}: defect centre but zero coverage"
                );
            }
            let expect_class = match a.instance[i] {
                0 => 0,
                1 | 3 => 1,
                _ => 2,
            };
            assert_eq!(a.class[i], expect_class);
        }
        // Background (beyond the plane) is face 0, the plane is face A.
        assert_eq!(a.face[0], 0);
        assert_eq!(a.face[(W / 2 * W + W / 2) as usize], 1);
    }
    let diff = |f: fn(&Annotation) -> Vec<u32>| {
        f(&anns[0])
            .iter()
            .zip(f(&anns[1]))
            .filter(|(x, y)| **x != *y)
            .count()
    };
    let inst_diff = diff(|a| a.instance.iter().map(|&v| v as u32).collect());
    let face_diff = diff(|a| a.face.iter().map(|&v| v as u32).collect());
    let cov_diff = anns[0]
        .coverage
        .iter()
        .zip(&anns[1].coverage)
        .filter(|(x, y)| x != y)
        .count();
    eprintln!(
        "backends: instance differences {inst_diff}, face differences {face_diff}, coverage differences {cov_diff}"
    );
    // Measured: 0 / 0 / 0 (region borders are grid edges, not pixel centres).
    assert!(
        inst_diff <= 2 && face_diff <= 2 && cov_diff <= 4,
        "backends disagree"
    );
}

/// Fraction of a disc of radius r left of the line at offset x, box-filtered over one
/// pixel (the pixel jitter): the edge spread function of the thin lens's blur.
fn disc_esf(x: f64, r: f64) -> f64 {
    let a = |t: f64| {
        let t = t.clamp(-1.0, 1.0);
        (std::f64::consts::PI - t.acos() + t * (1.0 - t * t).sqrt()) / std::f64::consts::PI
    };
    let n = 200;
    (0..n)
        .map(|i| a((x + (i as f64 + 0.5) / n as f64 - 0.5) / r))
        .sum::<f64>()
        / n as f64
}

/// Distance between the 10 % and 90 % crossings of a rising profile sampled at
/// positions `xs` (linear interpolation).
fn width_10_90(xs: &[f64], ys: &[f64]) -> f64 {
    let cross = |level: f64| {
        for i in 1..xs.len() {
            if ys[i - 1] < level && ys[i] >= level {
                let t = (level - ys[i - 1]) / (ys[i] - ys[i - 1]);
                return xs[i - 1] + t * (xs[i] - xs[i - 1]);
            }
        }
        f64::NAN
    };
    cross(0.9) - cross(0.1)
}

/// A thin lens blurs a labelled step edge off focus by the circle of confusion
/// `2 R fx |1/z - 1/z_f|` pixels (the labels follow the path tracer's lens samples); in
/// focus the edge stays sharp. Both backends.
#[test]
fn thin_lens_blurs_an_edge_by_the_circle_of_confusion() {
    let ctx = common::gpu();
    // The plane z = 0: defect (class 1) for x > 0.3 mm, plain for x < 0.3 mm.
    let mut mesh = Mesh::default();
    for (x0, x1, class) in [(-100.0, 0.3, 0u8), (0.3, 100.0, 1u8)] {
        let b = mesh.positions.len() as u32;
        mesh.positions.extend([
            Vec3::new(x0, -100.0, 0.0),
            Vec3::new(x1, -100.0, 0.0),
            Vec3::new(x1, 100.0, 0.0),
            Vec3::new(x0, 100.0, 0.0),
        ]);
        mesh.triangles
            .extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
        let label = TriLabel {
            face: 1,
            class,
            instance: class as u16,
        };
        mesh.labels.extend([label; 2]);
    }
    let w = 64u32;
    let fx = w as f64 / 2.0 / (15f64).to_radians().tan();
    for b in common::BACKENDS {
        let ts = TraceScene::build(&ctx, &mesh, b, None).unwrap();
        for (focus, radius) in [(30.0f32, 4.0f32), (50.0, 4.0)] {
            let mut cam = Camera::look(Vec3::new(0.0, 0.0, 50.0), -Vec3::Z, Vec3::Y, 30.0, w, w);
            cam.lens_radius_mm = radius;
            cam.focus_distance_mm = focus;
            let (a, _) = annotate(&ctx, &ts, &mesh, &cam, 16, None).unwrap();
            // Mean coverage over the middle rows, per column.
            let rows = 24..40u32;
            let xs: Vec<f64> = (0..w).map(|x| x as f64 + 0.5).collect();
            let ys: Vec<f64> = (0..w)
                .map(|x| {
                    rows.clone()
                        .map(|y| a.coverage[(y * w + x) as usize] as f64)
                        .sum::<f64>()
                        / rows.len() as f64
                })
                .collect();
            let got = width_10_90(&xs, &ys);
            let coc = 2.0 * radius as f64 * fx * (1.0 / 50.0 - 1.0 / focus as f64).abs();
            // The edge's image: x = 0.3 mm at 50 mm is 0.006 fx pixels right of centre.
            let edge = 32.0 + 0.3 / 50.0 * fx;
            let model: Vec<f64> = xs
                .iter()
                .map(|&x| disc_esf(x - edge, coc.max(1e-6) / 2.0))
                .collect();
            let expect = width_10_90(&xs, &model);
            eprintln!(
                "{}: focus {focus} mm: circle of confusion {coc:.2} px, 10-90 % edge width {got:.2} px (model {expect:.2})",
                b.name()
            );
            assert!(
                (got - expect).abs() <= 0.05 * expect + 0.2,
                "{}: edge width {got} vs {expect}",
                b.name()
            );
            // Labels of blurred pixels: the majority class of the samples.
            let mid = (32 * w) as usize;
            assert_eq!(a.class[mid + 2] as f64, if ys[2] > 0.5 { 1.0 } else { 0.0 });
        }
    }
    common::assert_clean(&ctx);
}
