//! Ray throughput of both backends and of obvhs on the CPU, for the same rays.
//! `cargo run --release --example bench_trace` (docs/benchmarks.md has the results).

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use synosis::render::raycast::{benchmark_rays, trace_rays, traversal_work, wide_traversal_work};
use synosis::scene::procedural::bumpy_sphere;
use synosis::trace::software_bvh::{
    DEFAULT_BVH_QUALITY, build_bvh, build_wide_with, cpu_closest_hit, flatten_wide, obvhs_triangles,
};
use synosis::trace::{Backend, TraceScene};
use synosis::vk::{Context, ContextOptions};

fn main() -> anyhow::Result<()> {
    let mesh = bumpy_sphere(316, 159, 10.0, 0.05);
    let n_side = 1024u32;
    let (primary, random) = benchmark_rays(&mesh, n_side);
    let ctx = Context::new(&ContextOptions {
        validation: false,
        ray_query: true,
    })?;
    println!(
        "device: {} ({}), {} triangles, {} rays per set",
        ctx.info.name,
        ctx.info.driver_info,
        mesh.triangles.len(),
        primary.len()
    );
    println!();
    println!("| tracer | build ms | primary Mrays/s | random Mrays/s |");
    println!("|---|---|---|---|");
    for backend in [Backend::RayQuery, Backend::Software, Backend::SoftwareWide] {
        if backend == Backend::RayQuery && !ctx.info.ray_query_enabled {
            continue;
        }
        let scene = TraceScene::build(&ctx, &mesh, backend, None)?;
        let mut rates = Vec::new();
        for rays in [&primary, &random] {
            trace_rays(&ctx, &scene, &rays[..4096], None)?; // first dispatch compiles the shader
            let best = (0..3)
                .map(|_| trace_rays(&ctx, &scene, rays, None).map(|(_, t)| t.gpu_ms))
                .collect::<Result<Vec<_>, _>>()?
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            rates.push(rays.len() as f64 / best / 1e3);
        }
        println!(
            "| {} (GPU pass time) | {:.1} | {:.2} | {:.2} |",
            backend.name(),
            scene.build_ms,
            rates[0],
            rates[1]
        );
    }
    let tris = obvhs_triangles(&mesh.positions, &mesh.triangles);
    let t = Instant::now();
    let bvh = build_bvh(&tris);
    let build = t.elapsed().as_secs_f64() * 1e3;
    let threads = rayon::current_num_threads();
    let mut obvhs_rates = Vec::new();
    let mut ours_rates = Vec::new();
    for rays in [&primary, &random] {
        let t = Instant::now();
        let hits = rays
            .par_iter()
            .filter(|r| {
                let ray = obvhs::ray::Ray::new(
                    Vec3::from(r.origin).into(),
                    Vec3::from(r.dir).into(),
                    r.tmin,
                    r.tmax,
                );
                let mut hit = obvhs::ray::RayHit::none();
                bvh.ray_traverse(ray, &mut hit, |ray, id| {
                    tris[bvh.primitive_indices[id] as usize].intersect(ray)
                })
            })
            .count();
        obvhs_rates.push(rays.len() as f64 / t.elapsed().as_secs_f64() / 1e6);
        let t = Instant::now();
        let hits2 = rays
            .par_iter()
            .filter(|r| {
                cpu_closest_hit(&bvh, &tris, r.origin.into(), r.dir.into(), r.tmin, r.tmax)
                    .is_some()
            })
            .count();
        ours_rates.push(rays.len() as f64 / t.elapsed().as_secs_f64() / 1e6);
        std::hint::black_box((hits, hits2));
    }
    println!(
        "| obvhs CPU `ray_traverse` (Moeller), {threads} threads | {build:.1} | {:.2} | {:.2} |",
        obvhs_rates[0], obvhs_rates[1]
    );
    println!(
        "| our CPU reference (watertight), {threads} threads | {build:.1} | {:.2} | {:.2} |",
        ours_rates[0], ours_rates[1]
    );
    // Work per ray of the software traversal (CPU mirrors that visit nodes in the
    // shaders' order), to say where the time goes: the wide layout the shader traverses
    // and the BVH2 it is collapsed from.
    let (wide_nodes, wide_tris) = flatten_wide(&build_wide_with(&tris, DEFAULT_BVH_QUALITY), &tris)
        .map_err(anyhow::Error::msg)?;
    println!();
    println!("| rays | layout | nodes loaded / ray | box tests / ray | triangle tests / ray |");
    println!("|---|---|---|---|---|");
    for (name, rays) in [("primary", &primary), ("random", &random)] {
        let (boxes, triangles, loads) = wide_traversal_work(&wide_nodes, &wide_tris, rays, 16);
        println!("| {name} | wide (8 children) | {loads:.1} | {boxes:.1} | {triangles:.1} |");
        let (boxes, triangles) = traversal_work(&bvh, &tris, rays, 16);
        println!(
            "| {name} | BVH2 | {:.1} | {boxes:.1} | {triangles:.1} |",
            boxes / 2.0
        );
    }
    Ok(())
}
