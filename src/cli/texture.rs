//! `synosis texture`: synthesise a milled or sandblasted height map and write the EXR
//! height, the 16-bit normal map and a preview beside it, all or nothing.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Deserialize;
use synosis::texture::{
    HeightMap, MilledParams, Moments, Progress, SandblastParams, StandInExemplar, ToolPath,
    XyzUnit, generate_milled, generate_sandblasted, load_height_map, sandblast_default_moments,
    write_exr_height, write_normal_png16, write_preview_png,
};

#[derive(Clone, Copy, ValueEnum)]
pub enum Finish {
    Milled,
    Sandblasted,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum PathArg {
    Parallel,
    Spiral,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum UnitArg {
    M,
    Mm,
    Um,
}

/// Boxed so the `Command` enum stays small (clippy::large_enum_variant).
#[derive(Args)]
pub struct TextureArgs {
    #[command(flatten)]
    opts: Box<TextureOpts>,
}

#[derive(Args)]
pub struct TextureOpts {
    /// Surface finish to synthesise.
    pub finish: Finish,
    /// Width in pixels (square unless --height is given).
    #[arg(long, default_value_t = 4096)]
    pub size: usize,
    /// Height in pixels (default: --size).
    #[arg(long)]
    pub height: Option<usize>,
    /// Pixel spacing in micrometres.
    #[arg(long, default_value_t = 6.1)]
    pub spacing_um: f64,
    /// Random seed (same seed, same texture).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output EXR (heights in um); FILE.normal.png and FILE.preview.png go beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// TOML with sections [milled], [sandblast], [stand_in], [exemplar]; flags override.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Moment-match to this measurement's mean and Sq (xyz or EXR).
    #[arg(long)]
    pub measurement: Option<PathBuf>,
    /// Target Sq in um (overrides the finish's default; ignored with --measurement).
    #[arg(long)]
    pub sq_um: Option<f64>,
    /// Milled: milling head diameter d, mm.
    #[arg(long)]
    pub head_diameter_mm: Option<f64>,
    /// Milled: radial depth of cut a_e in (0, 1).
    #[arg(long)]
    pub radial_depth: Option<f64>,
    /// Milled: tool path.
    #[arg(long, value_enum)]
    pub path: Option<PathArg>,
    /// Milled: ring centre spacing along the path delta, mm.
    #[arg(long)]
    pub delta_mm: Option<f64>,
    /// Milled: draw the remaining parameters from the paper's variation sets (by seed).
    #[arg(long)]
    pub variation: bool,
    /// Sandblasted: measured exemplar (Alicona xyz or one-channel EXR in um).
    #[arg(long)]
    pub exemplar: Option<PathBuf>,
    /// Units of xyz coordinates (Alicona exports metres).
    #[arg(long, value_enum)]
    pub exemplar_unit: Option<UnitArg>,
    /// Spacing of an EXR exemplar or measurement, um.
    #[arg(long)]
    pub exemplar_spacing_um: Option<f64>,
    /// Sandblasted without --exemplar: pressure of the stand-in crater generator, bar.
    #[arg(long)]
    pub pressure_bar: Option<f64>,
    /// Sandblasted without --exemplar: grain size of the stand-in generator, um.
    #[arg(long)]
    pub grain_size_um: Option<f64>,
    /// Longest side of the preview PNG, pixels.
    #[arg(long, default_value_t = 1024)]
    pub preview_size: usize,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct ParamsFile {
    milled: MilledParams,
    sandblast: SandblastParams,
    stand_in: StandInExemplar,
    exemplar: ExemplarFile,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ExemplarFile {
    unit: XyzUnit,
    exr_spacing_um: f64,
}

impl Default for ExemplarFile {
    fn default() -> Self {
        Self {
            unit: XyzUnit::M,
            exr_spacing_um: 1.75,
        }
    }
}

struct Bar(ProgressBar);

impl Progress for Bar {
    fn start(&self, stage: &str, total: u64) {
        self.0.set_length(total);
        self.0.set_position(0);
        self.0.set_message(stage.to_owned());
    }
    fn advance(&self, n: u64) {
        self.0.inc(n);
    }
}

pub fn run(a: TextureArgs) -> Result<()> {
    let a = *a.opts;
    // Before any work: the output name and folder.
    if !a
        .out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
    {
        bail!("--out must end in .exr, got {}", a.out.display());
    }
    let dir = a.out.parent().unwrap_or(Path::new("."));
    synosis::util::check_writable_dir(dir).with_context(|| format!("--out {}", a.out.display()))?;
    let mut file = match &a.params {
        Some(p) => {
            let text = synosis::limits::read_text(p)
                .with_context(|| format!("reading parameter file {}", p.display()))?;
            toml::from_str::<ParamsFile>(&text)
                .with_context(|| format!("parsing parameter file {}", p.display()))?
        }
        None => ParamsFile::default(),
    };
    if let Some(u) = a.exemplar_unit {
        file.exemplar.unit = match u {
            UnitArg::M => XyzUnit::M,
            UnitArg::Mm => XyzUnit::Mm,
            UnitArg::Um => XyzUnit::Um,
        };
    }
    if let Some(s) = a.exemplar_spacing_um {
        file.exemplar.exr_spacing_um = s;
    }
    let measured = match &a.measurement {
        Some(m) => {
            let map = load_height_map(m, file.exemplar.unit, file.exemplar.exr_spacing_um)
                .with_context(|| format!("loading measurement {}", m.display()))?;
            Some(map.moments())
        }
        None => None,
    };
    let target = |default: Moments| -> Moments {
        measured.unwrap_or(Moments {
            sq_um: a.sq_um.unwrap_or(default.sq_um),
            ..default
        })
    };
    let (w, h) = (a.size, a.height.unwrap_or(a.size));
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template("{msg:>22} [{elapsed_precise}] {wide_bar} {pos}/{len}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let bar = Bar(bar);
    let map = match a.finish {
        Finish::Milled => {
            let mut p = file.milled;
            if let Some(v) = a.head_diameter_mm {
                p.head_diameter_mm = v;
            }
            if let Some(v) = a.radial_depth {
                p.radial_depth = v;
            }
            if let Some(v) = a.path {
                p.path = match v {
                    PathArg::Parallel => ToolPath::Parallel,
                    PathArg::Spiral => ToolPath::Spiral,
                };
            }
            if let Some(v) = a.delta_mm {
                p.delta_mm = v;
            }
            if a.variation {
                let mut rng = rand_pcg::Pcg64Mcg::new(a.seed as u128 ^ 0x5eed_u128 << 64);
                p = p.sample_variation(&mut rng);
            }
            p.moments = target(p.moments);
            generate_milled(&p, w, h, a.spacing_um, a.seed, &bar)?
        }
        Finish::Sandblasted => {
            let mut p = file.sandblast;
            let exemplar = match &a.exemplar {
                Some(e) => load_height_map(e, file.exemplar.unit, file.exemplar.exr_spacing_um)
                    .with_context(|| format!("loading exemplar {}", e.display()))?,
                None => {
                    let mut s = file.stand_in;
                    if let Some(v) = a.pressure_bar {
                        s.pressure_bar = v;
                    }
                    if let Some(v) = a.grain_size_um {
                        s.grain_size_um = v;
                    }
                    if p.moments.is_none() {
                        p.moments = Some(sandblast_default_moments(s.pressure_bar));
                    }
                    bar.start("stand-in exemplar", 1);
                    s.generate(a.seed ^ 0xE8E3_91A8)?
                }
            };
            if measured.is_some() || a.sq_um.is_some() {
                let base = p.moments.unwrap_or_else(|| exemplar.moments());
                p.moments = Some(target(base));
            }
            generate_sandblasted(&exemplar, &p, w, h, a.spacing_um, a.seed, &bar)?
        }
    };
    bar.0.finish_and_clear();
    write_all(&map, &a.out, a.preview_size)
}

/// Writes the three files under temporary names, then renames them; on any failure the
/// temporaries are removed and no output file is left half-written.
fn write_all(map: &HeightMap, out: &Path, preview_size: usize) -> Result<()> {
    let base = match out.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("exr") => out.with_extension(""),
        _ => bail!("--out must end in .exr, got {}", out.display()),
    };
    let with = |suffix: &str| {
        let mut s = base.clone().into_os_string();
        s.push(suffix);
        PathBuf::from(s)
    };
    let finals = [out.to_owned(), with(".normal.png"), with(".preview.png")];
    let temps: Vec<PathBuf> = finals
        .iter()
        .map(|f| {
            let name = f.file_name().map(|n| n.to_string_lossy().into_owned());
            let tmp = format!(".{}.tmp-{}", name.unwrap_or_default(), std::process::id());
            let ext = f.extension().and_then(|e| e.to_str()).unwrap_or("");
            f.with_file_name(format!("{tmp}.{ext}"))
        })
        .collect();
    // Errors name the user's path, not the temporary one.
    let user = |i: usize, e: synosis::texture::TextureError| {
        anyhow::anyhow!(
            "{}",
            e.to_string().replace(
                &temps[i].display().to_string(),
                &finals[i].display().to_string()
            )
        )
    };
    let result = (|| -> Result<()> {
        write_exr_height(map, &temps[0]).map_err(|e| user(0, e))?;
        write_normal_png16(map, &temps[1]).map_err(|e| user(1, e))?;
        write_preview_png(map, &temps[2], preview_size).map_err(|e| user(2, e))?;
        for (t, f) in temps.iter().zip(&finals) {
            std::fs::rename(t, f).with_context(|| format!("writing {}", f.display()))?;
        }
        Ok(())
    })();
    if result.is_err() {
        for t in &temps {
            let _ = std::fs::remove_file(t);
        }
    }
    result?;
    println!(
        "wrote {} ({} x {} at {} um), Sq {:.3} um",
        finals[0].display(),
        map.width,
        map.height,
        map.spacing_um,
        map.moments().sq_um
    );
    Ok(())
}
