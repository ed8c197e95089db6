//! obvhs's BVH build presets side by side: CPU build time (BVH2 and its flattening into
//! the GPU layout) and the software backend's ray throughput on the Vulkan device present,
//! for the 100 k-triangle bumpy sphere of `bench_trace` and a defected test body with the
//! paper's defect specification (seed 1). Also checks that every preset gives the same
//! hits (the closest hit does not depend on the tree).
//! `cargo run --release --example bench_bvh` (docs/benchmarks.md, "BVH build presets").

use std::time::Instant;

use synosis::defect::{DefectSpec, imprint_with_stats, sample_defects};
use synosis::render::raycast::{benchmark_rays, trace_rays, traversal_work};
use synosis::scene::Mesh;
use synosis::scene::procedural::bumpy_sphere;
use synosis::scene::testbody::{Variant, testbody};
use synosis::trace::software_bvh::{BvhQuality, build_bvh_with, flatten, obvhs_triangles};
use synosis::trace::{Backend, TraceScene};
use synosis::vk::{Context, ContextOptions};

fn main() -> anyhow::Result<()> {
    let ctx = Context::new(&ContextOptions {
        validation: false,
        ray_query: false,
    })?;
    let body = testbody(Variant::B);
    let defected = imprint_with_stats(&body, &sample_defects(&body, &DefectSpec::paper(), 1)?)?.0;
    let meshes: [(&str, Mesh); 2] = [
        ("bumpy sphere", bumpy_sphere(316, 159, 10.0, 0.05)),
        ("defected test body (paper spec, seed 1)", defected),
    ];
    println!(
        "device: {} ({}), {} CPU threads",
        ctx.info.name,
        ctx.info.driver_info,
        rayon::current_num_threads()
    );
    println!();
    println!(
        "| mesh | triangles | preset | build ms (BVH2 + flatten) | GPU nodes | box + triangle tests / ray, primary | same, random | primary Mrays/s | random Mrays/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, mesh) in &meshes {
        let (primary, random) = benchmark_rays(mesh, 512);
        let tris = obvhs_triangles(&mesh.positions, &mesh.triangles);
        let mut reference: Option<Vec<Vec<u32>>> = None;
        for q in BvhQuality::ALL {
            // CPU build: the best of three.
            let mut build = f64::INFINITY;
            let mut nodes = 0;
            let mut bvh = None;
            for _ in 0..3 {
                let t = Instant::now();
                let b = build_bvh_with(&tris, q);
                let (n, _) = flatten(&b, &tris);
                build = build.min(t.elapsed().as_secs_f64() * 1e3);
                nodes = n.len();
                bvh = Some(b);
            }
            let bvh = bvh.expect("built");
            let work = |rays: &[synosis::render::raycast::RayIn]| {
                let (boxes, triangles) = traversal_work(&bvh, &tris, rays, 8);
                format!("{boxes:.1} + {triangles:.1}")
            };
            let (wp, wr) = (work(&primary), work(&random));
            let scene = TraceScene::build_with(&ctx, mesh, Backend::Software, q, None)?;
            let mut rates = Vec::new();
            let mut prims = Vec::new();
            for rays in [&primary, &random] {
                trace_rays(&ctx, &scene, &rays[..4096], None)?; // compiles the shader once
                let mut best = f64::INFINITY;
                for _ in 0..3 {
                    let (hits, t) = trace_rays(&ctx, &scene, rays, None)?;
                    best = best.min(t.gpu_ms);
                    if prims.len() < 2 {
                        prims.push(hits.iter().map(|h| h.prim).collect::<Vec<u32>>());
                    }
                }
                rates.push(rays.len() as f64 / best / 1e3);
            }
            match &reference {
                None => reference = Some(prims),
                Some(r) => anyhow::ensure!(*r == prims, "{name}: {} hits differ", q.name()),
            }
            println!(
                "| {name} | {} | {} | {build:.0} | {nodes} | {wp} | {wr} | {:.2} | {:.2} |",
                mesh.triangles.len(),
                q.name(),
                rates[0],
                rates[1]
            );
        }
    }
    Ok(())
}
