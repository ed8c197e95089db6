//! The largest image the scene file and the job file accept (MAX_IMAGE_PIXELS, 8192 x
//! 4096) renders on lavapipe, whose dispatches are limited to 65,535 workgroups (this
//! image has 524,288 tiles, so the renderer splits it into 9 dispatches), and one pixel
//! more is refused before rendering. The direct light is sampled, not the analytic
//! default: what is tested is the split into dispatches, and the test took 78 s instead
//! of 89 s on 2 cores (2026-11-29).

mod common;

use synosis::gpu_interface::MAX_IMAGE_PIXELS;
use synosis::render::energy::EnergyTables;
use synosis::render::path_trace::{FrameOptions, RenderScene, load_object, render_scene};
use synosis::scene::config::SceneConfig;
use synosis::trace::Backend;

#[test]
fn the_largest_documented_image_renders_in_several_dispatches() {
    let mut cfg = SceneConfig::parse(
        "[camera]\nview = \"A20\"\n[render]\nspp = 1\nbatch_spp = 1\nmax_bounces = 1\ndirect_light = \"sampled\"\n",
    )
    .unwrap();
    cfg.set_resolution(8192, 4096)
        .expect("the largest size is accepted");
    assert_eq!(8192 * 4096, MAX_IMAGE_PIXELS);
    let mut bigger = cfg.clone();
    let e = bigger.set_resolution(8192, 4097).expect_err("one row more");
    assert!(e.to_string().contains("33554432"), "{e}");

    let ctx = common::gpu();
    assert!(ctx.info.max_workgroup_count[0] < 8192 / 8 * 4096 / 8);
    let object = load_object(&cfg).unwrap();
    let scene = RenderScene::assemble(&object, &cfg).unwrap();
    let tables = EnergyTables::compute();
    let opts = FrameOptions {
        annotate_grid: None,
        profiler: None,
        noise: None,
    };
    let f =
        render_scene(&ctx, &scene, &cfg, Backend::Software, &tables, opts, |_| {}).expect("render");
    common::assert_clean(&ctx);
    let img = f.radiance;
    assert_eq!(img.data.len(), MAX_IMAGE_PIXELS as usize);
    assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0));
    // Every dispatch did its part: a skipped dispatch would leave thousands of black
    // 8 x 8 tiles scattered (scrambled) over the image; a real render has no black tile
    // whose eight neighbours are all mostly lit.
    let (tw, th) = (8192 / 8, 4096 / 8);
    let lit: Vec<f32> = (0..tw * th)
        .map(|t| {
            let (tx, ty) = (t % tw, t / tw);
            let mut n = 0;
            for y in ty * 8..ty * 8 + 8 {
                n += img.data[y * 8192 + tx * 8..y * 8192 + tx * 8 + 8]
                    .iter()
                    .filter(|v| **v > 0.0)
                    .count();
            }
            n as f32 / 64.0
        })
        .collect();
    let lit_tiles = lit.iter().filter(|&&f| f > 0.5).count();
    assert!(lit_tiles > tw * th / 20, "only {lit_tiles} lit tiles");
    let mut holes = 0;
    for ty in 1..th - 1 {
        for tx in 1..tw - 1 {
            let around = [
                (0, 1),
                (2, 1),
                (1, 0),
                (1, 2),
                (0, 0),
                (2, 2),
                (0, 2),
                (2, 0),
            ]
            .iter()
            .all(|&(dx, dy)| lit[(ty + dy - 1) * tw + tx + dx - 1] > 0.5);
            if lit[ty * tw + tx] == 0.0 && around {
                holes += 1;
            }
        }
    }
    assert_eq!(
        holes, 0,
        "black tiles inside lit regions: a dispatch was skipped"
    );
}
