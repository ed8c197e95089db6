//! Times one texture synthesis (library only, no file output) and prints one line.
//! Usage: bench_texture milled|sandblasted SIZE [SPACING_UM]
//! Peak memory is measured from outside (tools/bench-texture uses /usr/bin/time -v).

use std::time::Instant;

use synosis::texture::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let kind = args.get(1).map(String::as_str).unwrap_or("milled");
    let size: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1024);
    let spacing: f64 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(6.1);
    let t0 = Instant::now();
    let (map, setup) = match kind {
        "milled" => {
            let p = MilledParams::default();
            (
                generate_milled(&p, size, size, spacing, 1, &NoProgress)?,
                0.0,
            )
        }
        "sandblasted" => {
            let ex = StandInExemplar::default().generate(1)?;
            let setup = t0.elapsed().as_secs_f64();
            let p = SandblastParams::default();
            (
                generate_sandblasted(&ex, &p, size, size, spacing, 1, &NoProgress)?,
                setup,
            )
        }
        other => anyhow::bail!("unknown kind {other}: milled | sandblasted"),
    };
    let synth = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let slopes = map.slopes();
    let slope_s = t1.elapsed().as_secs_f64();
    let m = map.moments();
    println!(
        "{kind:<11} {size:>6}^2 @ {spacing} um: synthesis {synth:7.2} s (of which stand-in exemplar {setup:.2} s), slopes {slope_s:6.2} s, Sq {:.3} um, {} slope px",
        m.sq_um,
        slopes.data.len()
    );
    Ok(())
}
