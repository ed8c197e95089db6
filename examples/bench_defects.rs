//! Times defect sampling + imprinting on the test body with the paper's specification:
//! one object, then `N` objects (default 100) with seeds 0 .. N, single-threaded.
//! Scratches meshed anisotropically (the default), or as before issue 15 with `isotropic`.
//! Run: cargo run --release --example bench_defects [-- N [isotropic]]

use std::time::Instant;

use synosis::defect::{
    DefectSpec, ImprintOptions, ScratchMesh, imprint_with_options, sample_defects,
};
use synosis::scene::testbody::{Variant, testbody};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(100);
    let options = ImprintOptions {
        scratch_mesh: match std::env::args().nth(2).as_deref() {
            None | Some("anisotropic") => ScratchMesh::Anisotropic,
            Some("isotropic") => ScratchMesh::Isotropic,
            Some(other) => return Err(format!("mesh {other:?}: anisotropic or isotropic").into()),
        },
    };
    println!("scratch mesh: {:?}", options.scratch_mesh);
    let body = testbody(Variant::B);
    let spec = DefectSpec::paper();

    let t = Instant::now();
    let set = sample_defects(&body, &spec, 1)?;
    let t_sample = t.elapsed();
    let t = Instant::now();
    let (_, stats) = imprint_with_options(&body, &set, options)?;
    let t_imprint = t.elapsed();
    println!(
        "one object (seed 1): {} defects, sample {:.2} ms, imprint {:.1} ms, {} -> {} triangles ({} labelled)",
        set.defects.len(),
        t_sample.as_secs_f64() * 1e3,
        t_imprint.as_secs_f64() * 1e3,
        stats.triangles_in,
        stats.triangles_out,
        stats.triangles_labelled
    );

    let t = Instant::now();
    let mut tris = Vec::new();
    let mut worst = 0.0f64;
    for seed in 0..n {
        let s = Instant::now();
        let set = sample_defects(&body, &spec, seed)?;
        let (_, stats) = imprint_with_options(&body, &set, options)?;
        worst = worst.max(s.elapsed().as_secs_f64());
        tris.push(stats.triangles_out);
    }
    let total = t.elapsed().as_secs_f64();
    tris.sort_unstable();
    println!(
        "{n} objects: {:.2} s total, {:.1} ms per object (worst {:.1} ms); triangles min {} / median {} / max {}",
        total,
        total / n as f64 * 1e3,
        worst * 1e3,
        tris[0],
        tris[tris.len() / 2],
        tris[tris.len() - 1]
    );
    Ok(())
}
