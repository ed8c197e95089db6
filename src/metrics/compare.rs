//! Dataset comparison as in the paper's table of domain similarities: per viewpoint a
//! meta-mask, linear alignment of the synthetic side, for every real image the closest
//! synthetic image of the same viewpoint per metric (one-sided Chamfer), and the
//! similarities averaged per texture type and over all real images.
//!
//! Synthetic images are streamed (each decoded once per pass) while the few real images
//! of the current viewpoint stay prepared in memory, so memory stays bounded by
//! (real images per viewpoint + threads) images.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

use rayon::prelude::*;
use serde::Serialize;

use super::dataset::{Sample, load_dir, texture_of};
use super::{
    Alignment, GrayImage, Histogram, Lpips, LpipsFeatures, Mask, MetricsError, Moments, Ssim,
    SsimPrep, paper_defaults,
};

/// Which synthetic images are candidates for a real one (always the same viewpoint).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MatchBy {
    /// Same texture type (e.g. "parallel").
    Texture,
    /// Same finish string (e.g. "parallel-d4-ae0.5").
    Finish,
    Any,
}

/// Which face masks form a viewpoint's meta-mask.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum FaceSelect {
    /// The face the viewpoint looks at, named by its first letter ("A20" -> face A).
    Observed,
    /// Every face: per face the intersection over images, then their union.
    All,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum AlignMode {
    /// Synthetic images are used as they are (already post-processed, or synthetic
    /// against synthetic).
    None,
    /// Fixed (factor, bias) per texture type; [`paper_defaults`] by default.
    Table(BTreeMap<String, Alignment>),
    /// Fitted per texture type by moment matching inside the meta-masks; types without
    /// real images fall back to the table.
    Fit(BTreeMap<String, Alignment>),
}

/// The passes of a comparison over the images, reported to [`compare_with_progress`]'s
/// callback with the images done and the pass's total.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ComparePhase {
    /// Every image's face masks decoded into the viewpoints' meta-masks.
    MetaMasks,
    /// Every image's moments inside the meta-masks (`AlignMode::Fit` only).
    Alignment,
    /// Every synthetic image against its viewpoint's real images.
    Matching,
}

impl ComparePhase {
    /// A few words for a progress bar.
    pub fn describe(self) -> &'static str {
        match self {
            ComparePhase::MetaMasks => "meta-masks",
            ComparePhase::Alignment => "alignment fit",
            ComparePhase::Matching => "matching",
        }
    }
}

/// A pass's count of images done, reported after each (from any thread).
struct Tally<'a> {
    phase: ComparePhase,
    total: usize,
    done: std::sync::atomic::AtomicUsize,
    report: &'a (dyn Fn(ComparePhase, usize, usize) + Sync),
}

impl<'a> Tally<'a> {
    fn start(
        phase: ComparePhase,
        total: usize,
        report: &'a (dyn Fn(ComparePhase, usize, usize) + Sync),
    ) -> Self {
        report(phase, 0, total);
        Tally {
            phase,
            total,
            done: Default::default(),
            report,
        }
    }

    fn tick(&self) {
        let done = self.done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        (self.report)(self.phase, done, self.total);
    }
}

#[derive(Clone, Debug)]
pub struct CompareConfig {
    pub real_dir: PathBuf,
    pub synthetic_dir: PathBuf,
    /// Face names, id 1 first (LabelMe labels and face-id values).
    pub face_labels: Vec<String>,
    pub faces: FaceSelect,
    pub match_by: MatchBy,
    pub align: AlignMode,
    /// LPIPS too (the paper's fourth row), with these weights; `None`: the three
    /// handcrafted metrics only.
    pub lpips: Option<Arc<Lpips>>,
}

impl CompareConfig {
    pub fn new(real_dir: PathBuf, synthetic_dir: PathBuf) -> Self {
        Self {
            real_dir,
            synthetic_dir,
            face_labels: vec!["A".into(), "B".into(), "C".into()],
            faces: FaceSelect::Observed,
            match_by: MatchBy::Texture,
            align: AlignMode::Table(paper_defaults()),
            lpips: None,
        }
    }
}

/// The closest synthetic image to one real image, per metric.
#[derive(Clone, Debug, Serialize)]
pub struct RealResult {
    pub id: String,
    pub viewpoint: String,
    pub finish: String,
    pub texture: String,
    pub candidates: usize,
    pub hist_wd: f64,
    pub hist_wd_match: String,
    pub mae: f64,
    pub mae_match: String,
    pub ssim: f64,
    pub ssim_match: String,
    pub hist_wd_similarity: f64,
    pub mae_similarity: f64,
    pub ssim_similarity: f64,
    /// With `CompareConfig::lpips` only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips_match: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips_similarity: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct SimilarityTable {
    /// Texture types, then "All".
    pub columns: Vec<String>,
    pub images: Vec<usize>,
    /// ("1-HistWD" | "1-MAE" | "SSIM" | "1-LPIPS", one mean per column).
    pub rows: Vec<(String, Vec<f64>)>,
}

#[derive(Clone, Debug, Serialize)]
pub struct CompareReport {
    /// Alignment applied per synthetic texture type.
    pub alignments: BTreeMap<String, Alignment>,
    /// Meta-mask size per viewpoint, pixels.
    pub meta_mask_pixels: BTreeMap<String, usize>,
    pub results: Vec<RealResult>,
    pub table: SimilarityTable,
}

struct ViewpointData {
    mask: Mask,
    indices: Vec<u32>,
}

pub fn compare(cfg: &CompareConfig) -> Result<CompareReport, MetricsError> {
    compare_with_progress(cfg, &|_, _, _| (), &|line| eprintln!("{line}"))
}

/// [`compare`], calling `progress(phase, images done, images in the pass)` as each pass
/// starts and after each image (from the worker threads; a run over thousands of images
/// takes minutes, docs/benchmarks/metrics.md), and `note` with a line on each viewpoint
/// as its matching starts (its real and synthetic images and meta-mask; [`compare`]
/// writes them to stderr).
pub fn compare_with_progress(
    cfg: &CompareConfig,
    progress: &(dyn Fn(ComparePhase, usize, usize) + Sync),
    note: &dyn Fn(&str),
) -> Result<CompareReport, MetricsError> {
    if cfg.face_labels.is_empty() || cfg.face_labels.len() > 255 {
        return Err(MetricsError::param(
            "face_labels",
            format!("{} labels, need 1..=255", cfg.face_labels.len()),
        ));
    }
    let real = load_dir(&cfg.real_dir)?;
    let synth = load_dir(&cfg.synthetic_dir)?;

    let mut viewpoints: BTreeMap<&str, (Vec<&Sample>, Vec<&Sample>)> = BTreeMap::new();
    for s in &real {
        viewpoints.entry(&s.viewpoint).or_default().0.push(s);
    }
    for s in &synth {
        if let Some(v) = viewpoints.get_mut(s.viewpoint.as_str()) {
            v.1.push(s);
        }
    }

    let images: usize = viewpoints.values().map(|(r, s)| r.len() + s.len()).sum();
    let mut vdata = BTreeMap::new();
    let masks = Tally::start(ComparePhase::MetaMasks, images, progress);
    for (&vp, (r, s)) in &viewpoints {
        let faces = selected_faces(cfg, vp)?;
        let all: Vec<&Sample> = r.iter().chain(s).copied().collect();
        let mask = meta_mask(cfg, &faces, &all, &masks)?;
        let indices = mask.indices();
        if indices.is_empty() {
            return Err(MetricsError::EmptyMask {
                what: format!(
                    "meta-mask of viewpoint {vp:?} (intersection of {} images)",
                    all.len()
                ),
            });
        }
        vdata.insert(vp, ViewpointData { mask, indices });
    }

    let alignments = resolve_alignment(cfg, &viewpoints, &vdata, images, progress)?;
    let ssim = Ssim::default();
    let mut results = Vec::new();
    let synthetic: usize = viewpoints.values().map(|(_, s)| s.len()).sum();
    let matching = Tally::start(ComparePhase::Matching, synthetic, progress);
    for (&vp, (reals, synths)) in &viewpoints {
        let vd = &vdata[vp];
        note(&format!(
            "viewpoint {vp}: {} real x {} synthetic, meta-mask {} px",
            reals.len(),
            synths.len(),
            vd.indices.len()
        ));
        results.extend(match_viewpoint(
            cfg,
            &ssim,
            vd,
            (reals, synths),
            &alignments,
            &matching,
        )?);
    }
    let table = SimilarityTable::from_results(&results);
    Ok(CompareReport {
        alignments,
        meta_mask_pixels: vdata
            .iter()
            .map(|(k, v)| (k.to_string(), v.indices.len()))
            .collect(),
        results,
        table,
    })
}

fn selected_faces(cfg: &CompareConfig, viewpoint: &str) -> Result<Vec<usize>, MetricsError> {
    match cfg.faces {
        FaceSelect::All => Ok((0..cfg.face_labels.len()).collect()),
        FaceSelect::Observed => {
            // Longest label that prefixes the viewpoint, so labels like "A" and "AB" work.
            cfg.face_labels
                .iter()
                .enumerate()
                .filter(|(_, l)| {
                    viewpoint.len() >= l.len() && viewpoint[..l.len()].eq_ignore_ascii_case(l)
                })
                .max_by_key(|(_, l)| l.len())
                .map(|(i, _)| vec![i])
                .ok_or_else(|| {
                    MetricsError::param(
                        "viewpoint",
                        format!(
                            "{viewpoint:?} does not start with a face label ({}); use --faces all",
                            cfg.face_labels.join(", ")
                        ),
                    )
                })
        }
    }
}

fn meta_mask(
    cfg: &CompareConfig,
    faces: &[usize],
    samples: &[&Sample],
    tally: &Tally,
) -> Result<Mask, MetricsError> {
    let per_face = samples
        .par_iter()
        .map(|s| {
            let masks = s.face_masks(&cfg.face_labels, faces)?;
            tally.tick();
            Ok::<_, MetricsError>((s.id.clone(), masks))
        })
        .try_reduce_with(|(ida, mut a), (idb, b)| {
            if a[0].size() != b[0].size() {
                return Err(MetricsError::SizeMismatch {
                    a: format!("faces of {ida}"),
                    a_size: a[0].size(),
                    b: format!("faces of {idb}"),
                    b_size: b[0].size(),
                });
            }
            for (x, y) in a.iter_mut().zip(&b) {
                x.and_assign(y);
            }
            Ok((ida, a))
        })
        .expect("a viewpoint has at least one real image")?
        .1;
    let mut it = per_face.into_iter();
    let mut mask = it.next().expect("at least one face");
    for m in it {
        mask.or_assign(&m);
    }
    Ok(mask)
}

fn resolve_alignment(
    cfg: &CompareConfig,
    viewpoints: &BTreeMap<&str, (Vec<&Sample>, Vec<&Sample>)>,
    vdata: &BTreeMap<&str, ViewpointData>,
    images: usize,
    progress: &(dyn Fn(ComparePhase, usize, usize) + Sync),
) -> Result<BTreeMap<String, Alignment>, MetricsError> {
    let synth_types: std::collections::BTreeSet<String> = viewpoints
        .values()
        .flat_map(|(_, s)| s.iter().map(|s| s.texture()))
        .collect();
    let (table, fit) = match &cfg.align {
        AlignMode::None => {
            return Ok(synth_types
                .into_iter()
                .map(|t| (t, Alignment::IDENTITY))
                .collect());
        }
        AlignMode::Table(t) => (t, false),
        AlignMode::Fit(t) => (t, true),
    };
    let mut out = BTreeMap::new();
    if fit {
        let tally = Tally::start(ComparePhase::Alignment, images, progress);
        let mut real_m: BTreeMap<String, Moments> = BTreeMap::new();
        let mut synth_m: BTreeMap<String, Moments> = BTreeMap::new();
        for (vp, (r, s)) in viewpoints {
            let ix = &vdata[vp].indices;
            for (side, acc) in [(r, &mut real_m), (s, &mut synth_m)] {
                let per: Vec<(String, Moments)> = side
                    .par_iter()
                    .map(|smp| {
                        let img = smp.load_image()?;
                        check_size(&img, &vdata[vp].mask, smp)?;
                        let mut m = Moments::default();
                        for &i in ix {
                            m.add(img.data[i as usize]);
                        }
                        tally.tick();
                        Ok((smp.texture(), m))
                    })
                    .collect::<Result<_, MetricsError>>()?;
                for (t, m) in per {
                    let e = acc.entry(t).or_default();
                    *e = e.merge(m);
                }
            }
        }
        for (t, sm) in &synth_m {
            if let Some(a) = real_m.get(t).and_then(|rm| Alignment::fit(rm, sm)) {
                out.insert(t.clone(), a);
            }
        }
    }
    for t in synth_types {
        if out.contains_key(&t) {
            continue;
        }
        let a = table.get(&t).copied().ok_or_else(|| {
            MetricsError::param(
                "alignment",
                format!(
                    "no (factor, bias) for texture type {t:?} (known: {}); pass --align {t}=FACTOR,BIAS, --fit-alignment or --no-align",
                    table.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            )
        })?;
        out.insert(t, a);
    }
    Ok(out)
}

fn check_size(img: &GrayImage, mask: &Mask, s: &Sample) -> Result<(), MetricsError> {
    if img.size() != mask.size() {
        return Err(MetricsError::SizeMismatch {
            a: format!("image {}", s.image.display()),
            a_size: img.size(),
            b: format!("meta-mask of viewpoint {}", s.viewpoint),
            b_size: mask.size(),
        });
    }
    Ok(())
}

struct Prepared {
    img: GrayImage,
    prep: SsimPrep,
    hist: Histogram,
    /// The (aligned) image's LPIPS features, with `CompareConfig::lpips`.
    lpips: Option<LpipsFeatures>,
}

fn prepare(
    cfg: &CompareConfig,
    ssim: &Ssim,
    vd: &ViewpointData,
    s: &Sample,
    align: Alignment,
) -> Result<Prepared, MetricsError> {
    let raw = s.load_image()?;
    check_size(&raw, &vd.mask, s)?;
    let hist = Histogram::of(&raw, Some(&vd.indices)).aligned(align);
    let img = if align == Alignment::IDENTITY {
        raw
    } else {
        raw.aligned(align)
    };
    let rect = vd.mask.bbox().expect("meta-mask checked non-empty");
    let lpips = cfg
        .lpips
        .as_ref()
        .map(|net| net.features(&img, Some(&vd.mask)))
        .transpose()?;
    Ok(Prepared {
        prep: ssim.prepare(&img, rect),
        img,
        hist,
        lpips,
    })
}

/// Best value and index of the synthetic image giving it, per metric.
#[derive(Clone, Copy)]
struct Best {
    wd: (f64, usize),
    mae: (f64, usize),
    ssim: (f64, usize),
    lpips: (f64, usize),
    n: usize,
}

impl Best {
    const NONE: Best = Best {
        wd: (f64::INFINITY, usize::MAX),
        mae: (f64::INFINITY, usize::MAX),
        ssim: (f64::NEG_INFINITY, usize::MAX),
        lpips: (f64::INFINITY, usize::MAX),
        n: 0,
    };

    // Ties go to the lower synthetic index so the result does not depend on scheduling.
    fn merge(self, o: Best) -> Best {
        let lo = |a: (f64, usize), b: (f64, usize)| if (b.0, b.1) < (a.0, a.1) { b } else { a };
        let hi = |a: (f64, usize), b: (f64, usize)| {
            if b.0 > a.0 || (b.0 == a.0 && b.1 < a.1) {
                b
            } else {
                a
            }
        };
        Best {
            wd: lo(self.wd, o.wd),
            mae: lo(self.mae, o.mae),
            ssim: hi(self.ssim, o.ssim),
            lpips: lo(self.lpips, o.lpips),
            n: self.n + o.n,
        }
    }
}

fn is_candidate(cfg: &CompareConfig, real: &Sample, synth: &Sample) -> bool {
    // Synthetic against synthetic: an image is never its own closest sample.
    if real.image == synth.image {
        return false;
    }
    match cfg.match_by {
        MatchBy::Any => true,
        MatchBy::Texture => texture_of(&real.finish) == synth.texture(),
        MatchBy::Finish => real.finish == synth.finish,
    }
}

fn match_viewpoint(
    cfg: &CompareConfig,
    ssim: &Ssim,
    vd: &ViewpointData,
    (reals, synths): (&[&Sample], &[&Sample]),
    alignments: &BTreeMap<String, Alignment>,
    tally: &Tally,
) -> Result<Vec<RealResult>, MetricsError> {
    let real_prep: Vec<Prepared> = reals
        .par_iter()
        .map(|s| prepare(cfg, ssim, vd, s, Alignment::IDENTITY))
        .collect::<Result<_, _>>()?;
    let bests = synths
        .par_iter()
        .enumerate()
        .map(|(si, s)| -> Result<Vec<Best>, MetricsError> {
            let mut out = vec![Best::NONE; reals.len()];
            let wanted: Vec<usize> = (0..reals.len())
                .filter(|&ri| is_candidate(cfg, reals[ri], s))
                .collect();
            if wanted.is_empty() {
                tally.tick();
                return Ok(out);
            }
            let sp = prepare(cfg, ssim, vd, s, alignments[&s.texture()])?;
            for ri in wanted {
                let rp = &real_prep[ri];
                let wd = rp.hist.wasserstein(&sp.hist);
                // The meta-mask's pixels, both metrics from one pass over the pair.
                let (ss, m) = ssim.mean_and_mae_prepared(
                    &rp.img,
                    &rp.prep,
                    &sp.img,
                    &sp.prep,
                    Some(&vd.mask),
                );
                let lpips = match (&cfg.lpips, &rp.lpips, &sp.lpips) {
                    (Some(net), Some(a), Some(b)) => net.distance(a, b)?,
                    _ => f64::INFINITY,
                };
                out[ri] = Best {
                    wd: (wd, si),
                    mae: (m, si),
                    ssim: (ss, si),
                    lpips: (lpips, si),
                    n: 1,
                };
            }
            tally.tick();
            Ok(out)
        })
        .try_reduce(
            || vec![Best::NONE; reals.len()],
            |a, b| Ok(a.into_iter().zip(b).map(|(x, y)| x.merge(y)).collect()),
        )?;
    reals
        .iter()
        .zip(bests)
        .map(|(r, b)| {
            if b.n == 0 {
                return Err(MetricsError::param(
                    "synthetic",
                    format!(
                        "no synthetic image of viewpoint {:?} matches real image {} (finish {:?}, match by {:?})",
                        r.viewpoint, r.id, r.finish, cfg.match_by
                    ),
                ));
            }
            let name = |i: usize| synths[i].id.clone();
            let lpips = cfg.lpips.as_ref().map(|_| b.lpips.0);
            Ok(RealResult {
                id: r.id.clone(),
                viewpoint: r.viewpoint.clone(),
                finish: r.finish.clone(),
                texture: r.texture(),
                candidates: b.n,
                hist_wd: b.wd.0,
                hist_wd_match: name(b.wd.1),
                mae: b.mae.0,
                mae_match: name(b.mae.1),
                ssim: b.ssim.0,
                ssim_match: name(b.ssim.1),
                hist_wd_similarity: super::distance_similarity(b.wd.0),
                mae_similarity: super::distance_similarity(b.mae.0),
                ssim_similarity: super::ssim_similarity(b.ssim.0),
                lpips,
                lpips_match: lpips.map(|_| name(b.lpips.1)),
                lpips_similarity: lpips.map(super::lpips_similarity),
            })
        })
        .collect()
}

/// Paper order first, anything else alphabetically after.
fn texture_order(t: &str) -> (usize, String) {
    let rank = ["sandblasted", "parallel", "spiral"]
        .iter()
        .position(|&p| p == t)
        .unwrap_or(3);
    (rank, t.to_string())
}

impl SimilarityTable {
    /// Means of the per-image similarities per texture type; "All" averages over every
    /// real image (so types weigh by their image count, as in the paper's table).
    pub fn from_results(results: &[RealResult]) -> Self {
        let mut types: Vec<String> = results.iter().map(|r| r.texture.clone()).collect();
        types.sort_by_key(|t| texture_order(t));
        types.dedup();
        let groups: Vec<Vec<&RealResult>> = types
            .iter()
            .map(|t| results.iter().filter(|r| &r.texture == t).collect())
            .chain(std::iter::once(results.iter().collect()))
            .collect();
        let mean = |g: &[&RealResult], f: fn(&RealResult) -> f64| {
            g.iter().map(|r| f(r)).sum::<f64>() / g.len().max(1) as f64
        };
        type Row = (&'static str, fn(&RealResult) -> f64);
        let mut metrics: Vec<Row> = vec![
            ("1-HistWD", |r| r.hist_wd_similarity),
            ("1-MAE", |r| r.mae_similarity),
            ("SSIM", |r| r.ssim_similarity),
        ];
        if results.iter().all(|r| r.lpips_similarity.is_some()) && !results.is_empty() {
            metrics.push(("1-LPIPS", |r| r.lpips_similarity.unwrap_or(f64::NAN)));
        }
        let rows: Vec<(String, Vec<f64>)> = metrics
            .into_iter()
            .map(|(name, f)| {
                (
                    name.to_string(),
                    groups.iter().map(|g| mean(g, f)).collect(),
                )
            })
            .collect();
        let mut columns = types;
        columns.push("All".into());
        Self {
            columns,
            images: groups.iter().map(Vec::len).collect(),
            rows,
        }
    }

    pub fn markdown(&self) -> String {
        let mut s = String::from("| Method |");
        for c in &self.columns {
            let _ = write!(s, " {c} |");
        }
        s.push_str("\n|---|");
        s.push_str(&"---:|".repeat(self.columns.len()));
        s.push('\n');
        for (name, vals) in &self.rows {
            let _ = write!(s, "| {name} |");
            for v in vals {
                let _ = write!(s, " {v:.3} |");
            }
            s.push('\n');
        }
        s.push_str("| images |");
        for n in &self.images {
            let _ = write!(s, " {n} |");
        }
        s.push('\n');
        s
    }

    pub fn csv(&self) -> String {
        let mut s = String::from("method");
        for c in &self.columns {
            let _ = write!(s, ",{c}");
        }
        s.push('\n');
        for (name, vals) in &self.rows {
            s.push_str(name);
            for v in vals {
                let _ = write!(s, ",{v:.6}");
            }
            s.push('\n');
        }
        s.push_str("images");
        for n in &self.images {
            let _ = write!(s, ",{n}");
        }
        s.push('\n');
        s
    }
}

impl CompareReport {
    /// One row per real image: the best value per metric and which synthetic gave it.
    pub fn matches_csv(&self) -> String {
        let lpips = !self.results.is_empty() && self.results.iter().all(|r| r.lpips.is_some());
        let mut s = String::from(
            "real,viewpoint,finish,texture,candidates,hist_wd,hist_wd_match,mae,mae_match,ssim,ssim_match",
        );
        s.push_str(if lpips { ",lpips,lpips_match\n" } else { "\n" });
        for r in &self.results {
            let _ = write!(
                s,
                "{},{},{},{},{},{:.6},{},{:.6},{},{:.6},{}",
                r.id,
                r.viewpoint,
                r.finish,
                r.texture,
                r.candidates,
                r.hist_wd,
                r.hist_wd_match,
                r.mae,
                r.mae_match,
                r.ssim,
                r.ssim_match
            );
            if let (true, Some(d), Some(m)) = (lpips, r.lpips, &r.lpips_match) {
                let _ = write!(s, ",{d:.6},{m}");
            }
            s.push('\n');
        }
        s
    }
}
