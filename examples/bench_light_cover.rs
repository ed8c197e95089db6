//! CPU time of one view's light cover (`scene::light_cover::light_cover`, issue 15): the
//! default ring light (96 x 16 segments, 3,072 triangles, 30 / 5 mm) 250 mm above a box
//! like the demo's seen part of the stage, and a tilted ring close to a wide object
//! (much of it hidden by itself). Prints the time per call, the marked cells and a hash
//! of the masks (the same masks give the same hash).
//!
//! cargo run --release --example bench_light_cover
//! Env: BENCH_REPEAT (calls timed, default 10). The calls run on `on_render_pool`, as a
//! render's do.

use std::time::Instant;

use glam::Vec3;
use synosis::render::cpu::on_render_pool;
use synosis::scene::camera::ring_light;
use synosis::scene::config::LightConfig;
use synosis::scene::light_cover::light_cover;
use synosis::trace::TriangleSoup;

fn ring(cfg: &LightConfig, centre: Vec3, axis: Vec3) -> TriangleSoup {
    let (positions, triangles) = ring_light(centre, axis.normalize(), cfg);
    TriangleSoup {
        positions,
        triangles,
    }
}

fn main() {
    let repeat: usize = std::env::var("BENCH_REPEAT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    let default = LightConfig::default();
    let tilted = LightConfig {
        major_radius_mm: 40.0,
        minor_radius_mm: 12.0,
        ..LightConfig::default()
    };
    let cases = [
        (
            "default ring 250 mm above the part",
            ring(&default, Vec3::new(0.0, 0.0, 250.0), Vec3::Z),
            [Vec3::new(-60.0, -45.0, -1.0), Vec3::new(60.0, 45.0, 40.0)],
        ),
        (
            "tilted fat ring close to a wide object",
            ring(
                &tilted,
                Vec3::new(10.0, -5.0, 60.0),
                Vec3::new(0.3, 0.1, 1.0),
            ),
            [Vec3::new(-80.0, -60.0, -20.0), Vec3::new(70.0, 90.0, 30.0)],
        ),
    ];
    println!(
        "light cover, {} threads on the render threads' pool, {repeat} calls each\n",
        on_render_pool(rayon::current_num_threads)
    );
    println!("| case | triangles | ms per call | cells marked | masks hash |");
    println!("|---|---:|---:|---:|---|");
    for (name, lights, object) in cases {
        let mut ms = Vec::new();
        let mut cover = None;
        for _ in 0..repeat {
            let t = Instant::now();
            cover = Some(on_render_pool(|| light_cover(&lights, Some(object))));
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let cover = cover.expect("at least one call");
        let marked: u32 = cover.masks.iter().map(|m| m.count_ones()).sum();
        // FNV-1a over the masks.
        let hash = cover.masks.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, m| {
            m.to_le_bytes()
                .iter()
                .fold(h, |h, b| (h ^ *b as u64).wrapping_mul(0x100_0000_01b3))
        });
        ms.sort_by(f64::total_cmp);
        println!(
            "| {name} | {} | {:.1} (median; {:.1} to {:.1}) | {marked} of {} | {hash:016x} |",
            lights.triangles.len(),
            ms[ms.len() / 2],
            ms[0],
            ms[ms.len() - 1],
            cover.masks.len() * 8,
        );
    }
}
