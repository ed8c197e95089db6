//! `[render] texture_filter` (issue 15): LEAN-filtered slope maps on both trace backends,
//! validation on. Small images (64 x 48 of the paper camera's field, face A head-on).

mod common;

use synosis::scene::config::SceneConfig;
use synosis::trace::Backend;

/// Face A seen head-on (view A0) at 64 x 48 (pixels of about 0.47 mm on the face), test
/// grooves of `period_mm` in texels of `spacing_um`, the given filter and seed.
fn cfg(spacing_um: f32, period_mm: f32, filter: &str, seed: u32, spp: u32) -> SceneConfig {
    let text = format!(
        "[camera]\nwidth = 1224\nheight = 1025\nview = \"A0\"\n[material]\nalpha = 0.05\n\
         [render]\nspp = {spp}\nbatch_spp = 16\nseed = {seed}\ntexture_filter = \"{filter}\"\n\
         [texture]\nkind = \"test-grooves\"\nspacing_um = {spacing_um}\n\
         groove_period_mm = {period_mm}\ngroove_max_slope_deg = 20.0\nrotation_deg = [25.0, 0.0, 0.0]\n"
    );
    let mut cfg = SceneConfig::parse(&text).expect("test scene");
    cfg.set_resolution(64, 48).expect("size");
    cfg
}

/// Radiance and the pixels of face A (3 x 3 neighbourhood all A: no edge pixels).
fn render(cfg: &SceneConfig, backend: Backend) -> (Vec<f32>, Vec<usize>) {
    let (img, face) = common::render_faces(cfg, backend);
    let inner = common::interior(&face, 64, 48);
    assert!(inner.len() > 400, "{} pixels of face A", inner.len());
    (img.data, inner)
}

fn mean(img: &[f32], px: &[usize]) -> f64 {
    px.iter().map(|&i| img[i] as f64).sum::<f64>() / px.len() as f64
}

/// Where the footprint is under a texel (1 mm texels, pixels of 0.47 mm) "lean" reads
/// level 0 with no spread: face A renders bit for bit as with "none". With 20 µm texels
/// (about 24 x 24 under a pixel) it must differ, so the test can fail.
#[test]
fn lean_below_a_texel_is_none_bit_for_bit() {
    for backend in common::BACKENDS {
        let (none, px) = render(&cfg(1000.0, 20.0, "none", 3, 4), backend);
        let (lean, _) = render(&cfg(1000.0, 20.0, "lean", 3, 4), backend);
        let differ = px.iter().filter(|&&i| none[i] != lean[i]).count();
        assert_eq!(differ, 0, "{}: {differ} face pixels differ", backend.name());
        let (none, _) = render(&cfg(20.0, 0.2, "none", 3, 4), backend);
        let (lean, _) = render(&cfg(20.0, 0.2, "lean", 3, 4), backend);
        let differ = px.iter().filter(|&&i| none[i] != lean[i]).count();
        assert!(differ > px.len() / 2, "{}: {differ}", backend.name());
    }
}

/// Grooves of 0.2 mm (about 2.4 periods under a pixel): point samples of the map make
/// each pixel's 4-sample estimate noisy; LEAN folds the slopes under the footprint into
/// the roughness, so two seeds' images agree far better (mean |difference| on face A at
/// most a third of "none"'s), and its mean on face A stays near the unfiltered 64-spp
/// mean (within 10 %: the bias of the Gaussian slope model on sinusoidal grooves).
#[test]
fn lean_removes_subpixel_texture_noise() {
    for backend in common::BACKENDS {
        let diff = |filter: &str| {
            let (a, px) = render(&cfg(20.0, 0.2, filter, 1, 4), backend);
            let (b, _) = render(&cfg(20.0, 0.2, filter, 2, 4), backend);
            let d = px.iter().map(|&i| (a[i] - b[i]).abs() as f64).sum::<f64>() / px.len() as f64;
            (d / mean(&a, &px), mean(&a, &px))
        };
        let (d_none, _) = diff("none");
        let (d_lean, m_lean) = diff("lean");
        let (reference, px) = render(&cfg(20.0, 0.2, "none", 7, 64), backend);
        let m_ref = mean(&reference, &px);
        println!(
            "{}: relative mean |seed difference| at 4 spp: none {d_none:.4}, lean {d_lean:.4}; face A mean lean {m_lean:.5}, none at 64 spp {m_ref:.5}",
            backend.name()
        );
        assert!(
            d_lean < d_none / 3.0,
            "{}: {d_lean} vs {d_none}",
            backend.name()
        );
        assert!(
            (m_lean / m_ref - 1.0).abs() < 0.1,
            "{}: lean mean {m_lean}, reference {m_ref}",
            backend.name()
        );
    }
}
