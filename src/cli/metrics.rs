//! `synosis metrics` (one pair) and `synosis compare` (real against synthetic sets).

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use synosis::metrics::{
    self, Alignment, GrayImage, Mask,
    compare::{AlignMode, CompareConfig, FaceSelect, MatchBy},
};

#[derive(Args)]
pub struct MetricsArgs {
    /// First image (8- or 16-bit grey PNG, TIFF, BMP or JPEG; a grey image stored as colour
    /// is read as grey).
    pub a: PathBuf,
    /// Second image, same size.
    pub b: PathBuf,
    /// Mask PNG: metrics only where it is non-zero.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Significant bits of the first image's 16-bit codes (8 to 16; e.g. 12 for a 12-bit
    /// camera's frames saved as 16-bit): codes scaled by 255 / (2^N - 1). Default 16.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(8..=16))]
    pub bit_depth_a: Option<u32>,
    /// As --bit-depth-a, for the second image.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(8..=16))]
    pub bit_depth_b: Option<u32>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also LPIPS (AlexNet, v0.1; the paper's fourth metric). Needs the weights that
    /// tools/lpips-weights writes.
    #[arg(long)]
    pub lpips: bool,
    /// The LPIPS weights file (default: $SYNOSIS_LPIPS_WEIGHTS, else
    /// ~/.cache/synosis/lpips-alex-v0.1.safetensors).
    #[arg(long, value_name = "FILE", requires = "lpips")]
    pub lpips_weights: Option<PathBuf>,
    /// Also write LPIPS's map (where the two images differ, the reference's
    /// `spatial=True`) as a one-channel float EXR of the images' size.
    #[arg(long, value_name = "FILE.exr", requires = "lpips")]
    pub lpips_map: Option<PathBuf>,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum MatchArg {
    Texture,
    Finish,
    Any,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum FacesArg {
    Observed,
    All,
}

#[derive(Args)]
pub struct CompareArgs {
    /// Real set: LabelMe JSON + index.csv (or a synthetic layout, for synthetic vs synthetic).
    #[arg(long)]
    pub real: PathBuf,
    /// Synthetic set: manifest.jsonl + images + face-id PNGs.
    #[arg(long)]
    pub synthetic: PathBuf,
    /// Write similarities.md, similarities.csv, matches.csv and report.json here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Fit (factor, bias) per texture type by moment matching instead of the paper's values.
    #[arg(long, conflicts_with = "no_align")]
    pub fit_alignment: bool,
    /// Compare synthetic images as they are (already post-processed, or synthetic vs synthetic).
    #[arg(long)]
    pub no_align: bool,
    /// Override or add an alignment: TYPE=FACTOR,BIAS (repeatable), e.g. spiral=1.5,30.
    #[arg(long, value_name = "TYPE=FACTOR,BIAS")]
    pub align: Vec<String>,
    /// Face labels, face id 1 first (LabelMe labels and face-id PNG values).
    #[arg(long, value_delimiter = ',', default_value = "A,B,C")]
    pub face_labels: Vec<String>,
    /// Meta-mask from the viewpoint's observed face or from all faces.
    #[arg(long, value_enum, default_value = "observed")]
    pub faces: FacesArg,
    /// Candidates for a real image: same texture type, same finish, or any.
    #[arg(long = "match", value_enum, default_value = "texture")]
    pub match_by: MatchArg,
    /// Also LPIPS (AlexNet, v0.1; the paper's "1-LPIPS" row): a network's run per
    /// image, about 0.3 s for a 1224 x 1025 image on 2 cores, and the meta-mask's share
    /// of 52 MB of features per real image of a viewpoint. Needs the weights that
    /// tools/lpips-weights writes.
    #[arg(long)]
    pub lpips: bool,
    /// The LPIPS weights file (default: $SYNOSIS_LPIPS_WEIGHTS, else
    /// ~/.cache/synosis/lpips-alex-v0.1.safetensors).
    #[arg(long, value_name = "FILE", requires = "lpips")]
    pub lpips_weights: Option<PathBuf>,
}

pub fn run_metrics(a: MetricsArgs) -> anyhow::Result<()> {
    let ia = GrayImage::load_codes(&a.a, a.bit_depth_a)?;
    let ib = GrayImage::load_codes(&a.b, a.bit_depth_b)?;
    let mask = a.mask.as_deref().map(Mask::load).transpose()?;
    let context = || format!("comparing {} and {}", a.a.display(), a.b.display());
    let mut m = metrics::pair_metrics(&ia, &ib, mask.as_ref()).with_context(context)?;
    if a.lpips {
        let net = metrics::Lpips::load(a.lpips_weights.as_deref())?;
        if let Some(path) = &a.lpips_map {
            let (d, map) = net
                .pair_and_map(&ia, &ib, mask.as_ref())
                .with_context(context)?;
            m = m.with_lpips(d);
            synosis::image_io::write_exr_f32(path, map.width, map.height, "Y", &map.data)
                .with_context(|| format!("writing {}", path.display()))?;
        } else {
            m = m.with_lpips(net.pair(&ia, &ib, mask.as_ref()).with_context(context)?);
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&m)?);
    } else {
        println!("pixels        {}", m.pixels);
        println!(
            "hist_wd       {:.6}  (similarity {:.6})",
            m.hist_wd, m.hist_wd_similarity
        );
        println!(
            "mae           {:.6}  (similarity {:.6})",
            m.mae, m.mae_similarity
        );
        println!(
            "ssim          {:.6}  (similarity {:.6})",
            m.ssim, m.ssim_similarity
        );
        if let (Some(d), Some(s)) = (m.lpips, m.lpips_similarity) {
            println!("lpips         {d:.6}  (similarity {s:.6})");
        }
    }
    Ok(())
}

fn parse_align(s: &str) -> anyhow::Result<(String, Alignment)> {
    let err = || format!("--align {s:?}: expected TYPE=FACTOR,BIAS, e.g. spiral=1.526,33");
    let (t, fb) = s.split_once('=').with_context(err)?;
    let (f, b) = fb.split_once(',').with_context(err)?;
    let factor: f32 = f.trim().parse().with_context(err)?;
    let bias: f32 = b.trim().parse().with_context(err)?;
    if !factor.is_finite() || !bias.is_finite() {
        bail!("{}", err());
    }
    Ok((metrics::dataset::texture_of(t), Alignment { factor, bias }))
}

pub fn run_compare(a: CompareArgs) -> anyhow::Result<()> {
    let mut table: BTreeMap<String, Alignment> = metrics::paper_defaults();
    for s in &a.align {
        let (t, al) = parse_align(s)?;
        table.insert(t, al);
    }
    let mut cfg = CompareConfig::new(a.real.clone(), a.synthetic.clone());
    if a.lpips {
        cfg.lpips = Some(std::sync::Arc::new(metrics::Lpips::load(
            a.lpips_weights.as_deref(),
        )?));
    }
    cfg.face_labels = a.face_labels.iter().map(|s| s.trim().to_string()).collect();
    cfg.faces = match a.faces {
        FacesArg::Observed => FaceSelect::Observed,
        FacesArg::All => FaceSelect::All,
    };
    cfg.match_by = match a.match_by {
        MatchArg::Texture => MatchBy::Texture,
        MatchArg::Finish => MatchBy::Finish,
        MatchArg::Any => MatchBy::Any,
    };
    cfg.align = if a.no_align {
        AlignMode::None
    } else if a.fit_alignment {
        AlignMode::Fit(table)
    } else {
        AlignMode::Table(table)
    };
    // A bar on stderr (hidden where stderr is not a terminal), one pass at a time.
    let bar = super::dataset::styled_bar(
        "{msg:14} {bar:40} {pos}/{len} images, {elapsed} elapsed, ETA {eta}",
        false,
    );
    let progress = |phase: metrics::compare::ComparePhase, done: usize, total: usize| {
        // Each pass starts at 0; its images finish on several threads, in any order.
        if done == 0 {
            bar.set_message(phase.describe());
            bar.set_length(total as u64);
            bar.reset();
        } else {
            bar.inc(1);
        }
    };
    // The viewpoints' lines above the bar (a hidden bar prints nothing: then stderr).
    let note = |line: &str| {
        if bar.is_hidden() {
            eprintln!("{line}");
        } else {
            bar.println(line);
        }
    };
    let result = metrics::compare::compare_with_progress(&cfg, &progress, &note);
    bar.finish_and_clear();
    let report = result.with_context(|| {
        format!(
            "comparing {} with {}",
            a.real.display(),
            a.synthetic.display()
        )
    })?;
    print!("{}", report.table.markdown());
    for (t, al) in &report.alignments {
        eprintln!(
            "alignment {t}: factor {:.4}, bias {:.3}",
            al.factor, al.bias
        );
    }
    if let Some(out) = &a.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let files = [
            ("similarities.md", report.table.markdown()),
            ("similarities.csv", report.table.csv()),
            ("matches.csv", report.matches_csv()),
            ("report.json", serde_json::to_string_pretty(&report)?),
        ];
        for (name, text) in files {
            let p = out.join(name);
            // Write then rename so an interrupted run leaves no half-written report.
            let tmp = out.join(format!(".{name}.tmp"));
            std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
            std::fs::rename(&tmp, &p).with_context(|| format!("writing {}", p.display()))?;
        }
    }
    Ok(())
}
