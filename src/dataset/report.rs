//! The realism report (`synosis dataset report DIR`, `synosis dataset preview JOB`): one
//! self-contained HTML page (inline SVG charts, PNG examples beside it) with, per finish,
//! example images with their labels overlaid, the intensity histogram of the object's
//! pixels, the milling marks' visibility in the image spectrum, and the defects'
//! visibility distribution with the fraction the filter kept. docs/dataset.md, "Realism
//! report".

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rustfft::FftPlanner;
use rustfft::num_complex::Complex32;

use super::error::{DatasetError, Result};
use super::job::{Finish, FinishKind, Job};
use super::post::PostStep;
use super::runner::{self, LineAt, ManifestEntry, ReadMode};
use crate::scene::config::CameraConfig;

/// Visibility histogram: bins of this width (visibility units, fraction of 255).
const VIS_BIN: f64 = 0.01;
const VIS_BINS: usize = 30;

/// The milling marks in one image: power of the image spectrum at the projected tool
/// path spacing against the noise floor.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureVisibility {
    /// Projected path spacing rho on the image, pixels (at normal view; the tilted view
    /// shortens it by down to cos(angle) along the tilt).
    pub rho_px: f64,
    /// Crop side used for the spectrum, pixels.
    pub crop: usize,
    /// Largest radially averaged power in the band of rho over the median power of the
    /// band from 1.5 x its highest frequency to Nyquist (the noise floor), in dB.
    pub peak_over_floor_db: f64,
}

/// Everything the report shows for one finish.
#[derive(Clone, Debug, Default)]
pub struct FinishReport {
    pub name: String,
    pub kind: Option<FinishKind>,
    pub images: usize,
    /// Object pixels of the post-processed images per grey level.
    pub histogram: Vec<u64>,
    /// 1st and 99th percentile of the object's grey levels.
    pub p01_p99: (u8, u8),
    /// Milled finishes: per image (index, visibility).
    pub texture: Vec<(usize, TextureVisibility)>,
    /// Per defect: class, visibility, kept.
    pub defects: Vec<(u8, f64, bool)>,
    /// Per defect spec entry ("big dent", ...; from the manifest): kept, all.
    pub kinds: BTreeMap<String, (usize, usize)>,
    /// Example PNGs (relative to the report).
    pub examples: Vec<String>,
}

impl FinishReport {
    /// Kept / all defects of a class (1 dent, 2 scratch).
    pub fn kept(&self, class: u8) -> (usize, usize) {
        let all: Vec<&(u8, f64, bool)> = self.defects.iter().filter(|d| d.0 == class).collect();
        (all.iter().filter(|d| d.2).count(), all.len())
    }
}

fn read_gray(dir: &Path, rel: &str) -> Result<(usize, usize, Vec<u8>)> {
    let path = dir.join(rel);
    let img = image::open(&path)
        .map_err(|e| DatasetError::io(&path, std::io::Error::other(e)))?
        .into_luma8();
    let (w, h) = img.dimensions();
    Ok((w as usize, h as usize, img.into_raw()))
}

/// image.png in 8-bit units: 8-bit codes as they are, the 16-bit PNG of a deeper sensor
/// (`bit_depth` 10, 12, 16: codes unscaled) as round(code * 255 / (2^bit_depth - 1)).
fn read_image8(dir: &Path, rel: &str, bit_depth: Option<u32>) -> Result<(usize, usize, Vec<u8>)> {
    let Some(bits) = bit_depth.filter(|&b| b > 8) else {
        return read_gray(dir, rel);
    };
    let path = dir.join(rel);
    let img = image::open(&path)
        .map_err(|e| DatasetError::io(&path, std::io::Error::other(e)))?
        .into_luma16();
    let (w, h) = img.dimensions();
    let top = ((1u64 << bits.min(16)) - 1) as f64;
    let data = img
        .into_raw()
        .into_iter()
        .map(|c| (c as f64 * 255.0 / top).round().min(255.0) as u8)
        .collect();
    Ok((w as usize, h as usize, data))
}

/// The spectrum measure of [`TextureVisibility`] on the pixels of `face` in `image`.
/// The crop is the largest square of side 2^k (16 ..= 512) around the face's pixel
/// centroid that lies at least 98 % on the face; the crop is levelled (best-fit plane
/// removed, so smooth shading does not leak into low frequencies), Hann-windowed and
/// transformed; non-face pixels take the crop's face mean. None if no crop fits or the
/// band of rho lies outside the crop's frequencies.
pub fn texture_visibility(
    w: usize,
    h: usize,
    image: &[u8],
    faces: &[u8],
    face: u8,
    rho_px: f64,
    cos_tilt: f64,
) -> Option<TextureVisibility> {
    let (mut sx, mut sy, mut n) = (0.0f64, 0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            if faces[y * w + x] == face {
                sx += x as f64;
                sy += y as f64;
                n += 1;
            }
        }
    }
    if n == 0 {
        return None;
    }
    let (cx, cy) = ((sx / n as f64) as i64, (sy / n as f64) as i64);
    let mut side = 512usize;
    let crop = loop {
        if side < 16 {
            return None;
        }
        let (x0, y0) = (cx - side as i64 / 2, cy - side as i64 / 2);
        if x0 >= 0 && y0 >= 0 && x0 as usize + side <= w && y0 as usize + side <= h {
            let on = (0..side * side)
                .filter(|k| faces[(y0 as usize + k / side) * w + x0 as usize + k % side] == face)
                .count();
            if on as f64 >= 0.98 * (side * side) as f64 {
                break (x0 as usize, y0 as usize);
            }
        }
        side /= 2;
    };
    let n = side;
    let mut m = crate::texture::HeightMap::new(n, n, 1.0);
    for y in 0..n {
        for x in 0..n {
            let k = (crop.1 + y) * w + crop.0 + x;
            m.data[y * n + x] = if faces[k] == face {
                image[k] as f32
            } else {
                f32::NAN
            };
        }
    }
    crate::texture::remove_form(&mut m, crate::texture::FormRemoval::Plane);
    let hann = |i: usize| 0.5 - 0.5 * (std::f32::consts::TAU * i as f32 / n as f32).cos();
    let mut buf: Vec<Complex32> = (0..n * n)
        .map(|k| Complex32::new(m.data[k] * hann(k % n) * hann(k / n), 0.0))
        .collect();
    let fft = FftPlanner::new().plan_fft_forward(n);
    for row in buf.chunks_mut(n) {
        fft.process(row);
    }
    let mut col = vec![Complex32::new(0.0, 0.0); n];
    for x in 0..n {
        for y in 0..n {
            col[y] = buf[y * n + x];
        }
        fft.process(&mut col);
        for y in 0..n {
            buf[y * n + x] = col[y];
        }
    }
    // Radially averaged power per integer radius (cycles per crop).
    let half = n / 2;
    let mut sum = vec![0.0f64; half + 1];
    let mut cnt = vec![0usize; half + 1];
    for y in 0..n {
        for x in 0..n {
            let fx = if x <= half {
                x as f64
            } else {
                x as f64 - n as f64
            };
            let fy = if y <= half {
                y as f64
            } else {
                y as f64 - n as f64
            };
            let r = (fx * fx + fy * fy).sqrt().round() as usize;
            if r <= half {
                sum[r] += buf[y * n + x].norm_sqr() as f64;
                cnt[r] += 1;
            }
        }
    }
    let p: Vec<f64> = sum
        .iter()
        .zip(&cnt)
        .map(|(s, c)| s / (*c).max(1) as f64)
        .collect();
    // Band of rho: periods from 0.9 cos(tilt) rho to 1.1 rho.
    let r_lo = (n as f64 / (1.1 * rho_px)).floor().max(1.0) as usize;
    let r_hi = (n as f64 / (0.9 * cos_tilt * rho_px)).ceil() as usize;
    let f_lo = ((1.5 * r_hi as f64).ceil() as usize).max(r_hi + 1);
    if r_hi >= half || f_lo + 2 > half {
        return None;
    }
    let peak = p[r_lo..=r_hi].iter().cloned().fold(0.0, f64::max);
    let mut floor: Vec<f64> = p[f_lo..=half].to_vec();
    floor.sort_by(f64::total_cmp);
    let med = floor[floor.len() / 2].max(1e-30);
    Some(TextureVisibility {
        rho_px,
        crop: n,
        peak_over_floor_db: 10.0 * (peak.max(1e-30) / med).log10(),
    })
}

/// Pixel footprint on a face at normal view, mm: the default camera's pitch (scaled to
/// the image width, as `--width` keeps the sensor size) times distance / focal length.
pub fn pixel_mm(width: u32) -> f64 {
    let c = CameraConfig::default();
    c.pixel_um as f64 * 1e-3 * (c.width as f64 / width.max(1) as f64) * c.working_distance_mm as f64
        / c.focal_mm as f64
}

/// Builds the report of the images in `entries` (files under `dir`) into `out_dir`
/// (`report.html` plus example PNGs). Returns the per-finish numbers.
pub fn write_report(
    dir: &Path,
    job: &Job,
    entries: &[ManifestEntry],
    examples_per_finish: usize,
    out_dir: &Path,
) -> Result<Vec<FinishReport>> {
    let keyed = entries
        .iter()
        .enumerate()
        .filter_map(|(k, e)| keyed_item(job, k, e))
        .collect();
    let items = ordered(keyed, job.finishes.len(), examples_per_finish);
    let fetch = |batch: &[Item<usize>]| Ok(batch.iter().map(|i| entries[i.src].clone()).collect());
    report_items(dir, job, &items, fetch, out_dir, None)
}

/// [`write_report`] of a dataset folder's images (those of [`folder_entries`]), read from
/// their manifest lines a batch at a time so that a whole job's entries (about 10 KiB an
/// image in memory) are never held at once; the images' files are read on all cores.
/// `progress`: (images read, images to read). An error if the folder lists no image.
pub fn write_folder_report(
    dir: &Path,
    job: &Job,
    examples_per_finish: usize,
    out_dir: &Path,
    progress: Option<&mut dyn FnMut(usize, usize)>,
) -> Result<Vec<FinishReport>> {
    let (mut keyed, mut listed) = (Vec::new(), 0);
    let manifests = folder_lines(dir, |at, e| {
        listed += 1;
        keyed.extend(keyed_item(job, at, &e));
        Ok(())
    })?;
    if listed == 0 {
        return Err(DatasetError::layout(
            dir,
            "no finished images (no manifest lines)",
        ));
    }
    let items = ordered(keyed, job.finishes.len(), examples_per_finish);
    let fetch = |batch: &[Item<LineAt>]| {
        let lines: Vec<LineAt> = batch.iter().map(|i| i.src).collect();
        runner::read_lines(&manifests, &lines)
    };
    report_items(dir, job, &items, fetch, out_dir, progress)
}

/// An image of the report, in the report's order, and where its entry is (`src`).
struct Item<S> {
    src: S,
    /// Its finish's position in the job.
    finish: usize,
    /// One of its finish's example images.
    example: bool,
}

/// The report's place of entry `e` (defective images first, then by index) and its
/// item; None for a finish the job does not have (left out of the report).
fn keyed_item<S>(job: &Job, src: S, e: &ManifestEntry) -> Option<((bool, usize), Item<S>)> {
    let finish = job.finishes.iter().position(|f| f.name == e.finish)?;
    Some((
        (e.defects.is_empty(), e.index),
        Item {
            src,
            finish,
            example: false,
        },
    ))
}

/// The report's images in its order (the order that picks the examples: the first
/// `examples_per_finish` of each of the `finishes`).
fn ordered<S>(
    mut keyed: Vec<((bool, usize), Item<S>)>,
    finishes: usize,
    examples_per_finish: usize,
) -> Vec<Item<S>> {
    keyed.sort_by_key(|(k, _)| *k);
    let mut shown = vec![0usize; finishes];
    keyed
        .into_iter()
        .map(|(_, mut item)| {
            item.example = shown[item.finish] < examples_per_finish;
            shown[item.finish] += item.example as usize;
            item
        })
        .collect()
}

/// What the report takes from one image's files.
struct ImageStats {
    /// The object's pixels per grey level.
    histogram: Vec<u64>,
    texture: Option<TextureVisibility>,
    /// The example PNG's name, if the image is one.
    example: Option<String>,
}

/// The report of `items` (in order), their entries fetched a batch at a time, each
/// batch's images read on all cores.
fn report_items<S: Sync>(
    dir: &Path,
    job: &Job,
    items: &[Item<S>],
    mut fetch: impl FnMut(&[Item<S>]) -> Result<Vec<ManifestEntry>>,
    out_dir: &Path,
    mut progress: Option<&mut dyn FnMut(usize, usize)>,
) -> Result<Vec<FinishReport>> {
    use rayon::prelude::*;
    std::fs::create_dir_all(out_dir).map_err(|e| DatasetError::io(out_dir, e))?;
    let threshold = job.postprocess.iter().find_map(|s| match s {
        PostStep::VisibilityFilter { threshold } => Some(*threshold),
        _ => None,
    });
    let mut reports: Vec<FinishReport> = job
        .finishes
        .iter()
        .map(|f| FinishReport {
            name: f.name.clone(),
            kind: Some(f.kind),
            histogram: vec![0; 256],
            ..Default::default()
        })
        .collect();
    let mut done = 0;
    for batch in items.chunks(runner::VERIFY_CHUNK) {
        let entries = fetch(batch)?;
        let stats: Vec<Result<ImageStats>> = batch
            .par_iter()
            .zip(&entries)
            .map(|(item, e)| {
                let finish = &job.finishes[item.finish];
                image_stats(dir, finish, e, item.example.then_some(out_dir))
            })
            .collect();
        // In the report's order, so the first error is the first image's that fails.
        for ((item, e), st) in batch.iter().zip(&entries).zip(stats) {
            let st = st?;
            let fr = &mut reports[item.finish];
            fr.images += 1;
            for (h, n) in fr.histogram.iter_mut().zip(&st.histogram) {
                *h += n;
            }
            for d in &e.defects {
                fr.defects.push((d.class, d.visibility, d.kept));
                if let Some(k) = &d.kind {
                    let c = fr.kinds.entry(k.clone()).or_insert((0, 0));
                    c.0 += d.kept as usize;
                    c.1 += 1;
                }
            }
            if let Some(t) = st.texture {
                fr.texture.push((e.index, t));
            }
            fr.examples.extend(st.example);
        }
        done += batch.len();
        if let Some(p) = progress.as_deref_mut() {
            p(done, items.len());
        }
    }
    for fr in &mut reports {
        fr.p01_p99 = percentiles(&fr.histogram);
    }
    let html = render_html(job, &reports, threshold);
    let path = out_dir.join("report.html");
    crate::util::write_atomic(&path, html.as_bytes()).map_err(|e| DatasetError::io(&path, e))?;
    Ok(reports)
}

/// One image's share of its finish's report: the object's grey levels, the milling marks'
/// visibility (milled finishes), and with `example_dir` its example PNG (the image with
/// its defects' masks tinted: dents red, scratches blue) written there.
fn image_stats(
    dir: &Path,
    finish: &Finish,
    e: &ManifestEntry,
    example_dir: Option<&Path>,
) -> Result<ImageStats> {
    let base = Path::new(&e.image).parent().unwrap_or(Path::new("."));
    let (w, h, img) = read_image8(dir, &e.image, e.bit_depth)?;
    let (_, _, object) = read_gray(dir, &base.join("object.png").to_string_lossy())?;
    let (_, _, faces) = read_gray(dir, &e.faces)?;
    let mut histogram = vec![0u64; 256];
    for (v, o) in img.iter().zip(&object) {
        if *o > 0 {
            histogram[*v as usize] += 1;
        }
    }
    let mut texture = None;
    if finish.kind == FinishKind::Milled
        && let Ok(p) =
            toml::Value::Table(finish.params.clone()).try_into::<crate::texture::MilledParams>()
        && let Some((face, deg)) = super::job::parse_view(&e.viewpoint)
    {
        // The footprint of a pixel at the working distance: from the image's recorded
        // camera (the job's `[camera]`), else the default camera at this width.
        // (Records written before the working distance was recorded read 0: the
        // default camera's distance then.)
        let footprint = e.camera.as_ref().map_or_else(
            || pixel_mm(e.width),
            |c| {
                let wd = if c.working_distance_mm > 0.0 {
                    c.working_distance_mm
                } else {
                    CameraConfig::default().working_distance_mm
                };
                wd as f64 / c.fx.max(1e-9)
            },
        );
        let rho_px = p.rho_mm() / footprint;
        texture = texture_visibility(w, h, &img, &faces, face, rho_px, deg.to_radians().cos());
    }
    let mut example = None;
    if let Some(out_dir) = example_dir {
        let (_, _, mask) = read_gray(dir, &base.join("mask.png").to_string_lossy())?;
        let name = format!("{}-{}.png", sanitize(&e.finish), e.id);
        let mut rgb = Vec::with_capacity(3 * img.len());
        for (&g8, &m) in img.iter().zip(&mask) {
            let g = g8 as f32;
            rgb.extend(match m {
                1 => [(0.5 * g + 127.0) as u8, (0.5 * g) as u8, (0.5 * g) as u8],
                2 => [
                    (0.5 * g) as u8,
                    (0.5 * g + 60.0) as u8,
                    (0.5 * g + 127.0) as u8,
                ],
                _ => [g8; 3],
            });
        }
        let path = out_dir.join(&name);
        crate::image_io::write_png_rgb8(&path, w as u32, h as u32, &rgb)
            .map_err(|err| DatasetError::io(&path, err))?;
        example = Some(name);
    }
    Ok(ImageStats {
        histogram,
        texture,
        example,
    })
}

fn sanitize(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn percentiles(hist: &[u64]) -> (u8, u8) {
    let total: u64 = hist.iter().sum();
    if total == 0 {
        return (0, 0);
    }
    let at = |q: f64| {
        let target = (q * total as f64).ceil().max(1.0) as u64;
        let mut acc = 0;
        for (v, c) in hist.iter().enumerate() {
            acc += c;
            if acc >= target {
                return v as u8;
            }
        }
        255
    };
    (at(0.01), at(0.99))
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Bars as an inline SVG (values scaled to the tallest), with an optional vertical line.
fn svg_bars(values: &[f64], w: f64, h: f64, line_at: Option<f64>, label: &str) -> String {
    let max = values.iter().cloned().fold(0.0, f64::max).max(1e-30);
    let bw = w / values.len().max(1) as f64;
    let mut s = format!(
        "<svg width=\"{w}\" height=\"{}\" xmlns=\"http://www.w3.org/2000/svg\"><rect width=\"{w}\" height=\"{h}\" fill=\"#f4f4f4\"/>",
        h + 14.0
    );
    for (i, v) in values.iter().enumerate() {
        let bh = h * v / max;
        let _ = write!(
            s,
            "<rect x=\"{:.2}\" y=\"{:.2}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"#446\"/>",
            i as f64 * bw,
            h - bh,
            bw.max(0.5),
            bh
        );
    }
    if let Some(x) = line_at {
        let _ = write!(
            s,
            "<line x1=\"{0:.1}\" x2=\"{0:.1}\" y1=\"0\" y2=\"{h}\" stroke=\"#c00\"/>",
            x * w
        );
    }
    let _ = write!(
        s,
        "<text x=\"0\" y=\"{}\" font-size=\"11\">{}</text></svg>",
        h + 12.0,
        esc(label)
    );
    s
}

fn render_html(job: &Job, reports: &[FinishReport], threshold: Option<f64>) -> String {
    let mut s = String::from(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>synosis realism report</title>\
         <style>body{font-family:sans-serif;margin:1em}td,th{padding:2px 8px;text-align:right}\
         img{max-width:420px;margin:2px}h2{margin-top:1.5em}</style></head><body>",
    );
    let _ = write!(
        s,
        "<h1>Realism report</h1><p>Job {}: {} x {} px, {}. Per finish: examples \
         (dents red, scratches blue), the object's grey-level histogram, the milling marks' \
         spectral peak at the projected path spacing rho over the noise floor, and the \
         defects' visibility (|mean inside - mean of the ring| / 255) with the filter's \
         threshold {}.</p>",
        esc(&job.origin),
        job.render.width,
        job.render.height,
        match job.render.noise_target {
            // Each image's own spp is in the manifest.
            Some(t) => format!(
                "up to {} spp (noise target {t}, {:?} estimate)",
                job.render.spp,
                job.render.noise_estimate.unwrap_or_default()
            )
            .to_lowercase(),
            None => format!("{} spp", job.render.spp),
        },
        threshold.map_or("(none)".into(), |t| format!("{t}"))
    );
    s.push_str(
        "<table><tr><th>finish</th><th>images</th><th>grey p1..p99</th><th>rho peak / floor (dB, median)</th>\
         <th>dents kept</th><th>scratches kept</th></tr>",
    );
    for r in reports {
        let tex = median_db(&r.texture).map_or("-".into(), |d| format!("{d:.1}"));
        let (dk, dn) = r.kept(1);
        let (sk, sn) = r.kept(2);
        let _ = write!(
            s,
            "<tr><td style=\"text-align:left\"><a href=\"#{}\">{}</a></td><td>{}</td><td>{}..{}</td><td>{}</td><td>{dk}/{dn}</td><td>{sk}/{sn}</td></tr>",
            sanitize(&r.name),
            esc(&r.name),
            r.images,
            r.p01_p99.0,
            r.p01_p99.1,
            tex
        );
    }
    s.push_str("</table>");
    for r in reports {
        let _ = write!(s, "<h2 id=\"{}\">{}</h2>", sanitize(&r.name), esc(&r.name));
        for e in &r.examples {
            let _ = write!(s, "<a href=\"{0}\"><img src=\"{0}\"></a>", esc(e));
        }
        let hist: Vec<f64> = r.histogram.iter().map(|&c| c as f64).collect();
        s.push_str("<p>");
        s.push_str(&svg_bars(
            &hist,
            512.0,
            100.0,
            None,
            &format!(
                "object grey levels 0..255 (p1 {}, p99 {})",
                r.p01_p99.0, r.p01_p99.1
            ),
        ));
        let mut vis = vec![0.0; VIS_BINS];
        for d in &r.defects {
            vis[((d.1 / VIS_BIN) as usize).min(VIS_BINS - 1)] += 1.0;
        }
        s.push(' ');
        s.push_str(&svg_bars(
            &vis,
            300.0,
            100.0,
            threshold.map(|t| t / (VIS_BIN * VIS_BINS as f64)),
            &format!(
                "defect visibility 0..{:.2} (red: threshold)",
                VIS_BIN * VIS_BINS as f64
            ),
        ));
        s.push_str("</p>");
        let (dk, dn) = r.kept(1);
        let (sk, sn) = r.kept(2);
        let _ = write!(
            s,
            "<p>Kept by the filter: dents {dk} of {dn}, scratches {sk} of {sn}{}.</p>",
            kinds_text(&r.kinds)
        );
        if !r.texture.is_empty() {
            s.push_str("<p>Milling marks (spectral peak at rho over the noise floor): ");
            for (i, t) in &r.texture {
                let _ = write!(
                    s,
                    "image {i}: {:.1} dB (rho {:.0} px, crop {}); ",
                    t.peak_over_floor_db, t.rho_px, t.crop
                );
            }
            s.push_str("</p>");
        }
    }
    s.push_str("</body></html>\n");
    s
}

/// "big dent 2/3, flat scratch 1/2" (kept / all per defect spec entry).
pub fn kinds_list(kinds: &BTreeMap<String, (usize, usize)>) -> String {
    kinds
        .iter()
        .map(|(k, (kept, all))| format!("{k} {kept}/{all}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// "; by spec entry: big dent 2/3, ..." (empty without spec entries).
fn kinds_text(kinds: &BTreeMap<String, (usize, usize)>) -> String {
    if kinds.is_empty() {
        return String::new();
    }
    format!("; by spec entry: {}", kinds_list(kinds))
}

fn median_db(t: &[(usize, TextureVisibility)]) -> Option<f64> {
    let mut v: Vec<f64> = t.iter().map(|x| x.1.peak_over_floor_db).collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// The images of a dataset folder: `manifest.jsonl`, else the shard manifests, else
/// `preview.jsonl` (written by `dataset preview`). A half last line of a shard manifest
/// (a run still appending to it) is left out.
pub fn folder_entries(dir: &Path) -> Result<Vec<ManifestEntry>> {
    let mut out = Vec::new();
    folder_lines(dir, |_, e| {
        out.push(e);
        Ok(())
    })?;
    Ok(out)
}

/// Calls `each` with every image line of a dataset folder (as [`folder_entries`] lists
/// them) and where it is: the manifest's position in the returned list and its bytes.
fn folder_lines(
    dir: &Path,
    mut each: impl FnMut(LineAt, ManifestEntry) -> Result<()>,
) -> Result<Vec<PathBuf>> {
    let finished = dir.join("manifest.jsonl");
    let mut read = |manifests: Vec<PathBuf>, mode: ReadMode| -> Result<(Vec<PathBuf>, usize)> {
        let mut n_lines = 0;
        for (mi, m) in manifests.iter().enumerate() {
            runner::manifest_lines(m, mode, |n, offset, line| {
                n_lines += 1;
                let at = LineAt {
                    manifest: mi,
                    offset,
                    len: line.len(),
                };
                each(at, runner::parse_entry(m, n, line)?)
            })?;
        }
        Ok((manifests, n_lines))
    };
    if finished.is_file() {
        return Ok(read(vec![finished], ReadMode::Strict)?.0);
    }
    let shards = if dir.join("manifests").is_dir() {
        runner::shard_manifests(dir)?
    } else {
        Vec::new()
    };
    let (shards, n) = read(shards, ReadMode::DropPartial)?;
    let preview = dir.join("preview.jsonl");
    if n == 0 && preview.is_file() {
        return Ok(read(vec![preview], ReadMode::DropPartial)?.0);
    }
    Ok(shards)
}

/// Items for a preview: per finish, up to `n` images, defective instances first, the
/// views cycling so the sample shows several of them.
pub fn preview_items(prep: &super::runner::Prepared, n: usize) -> Vec<usize> {
    let plan = &prep.plan;
    let views = prep.job.viewpoints().len().max(1);
    let mut out = Vec::new();
    for fi in 0..prep.job.finishes.len() {
        let mut picked = 0;
        let mut k = 0usize;
        let insts: Vec<usize> = {
            let mut v: Vec<usize> = (0..plan.instances.len())
                .filter(|&i| plan.instances[i].finish == fi)
                .collect();
            v.sort_by_key(|&i| (plan.instances[i].defect_set.is_none(), i));
            v
        };
        while picked < n && k < insts.len() * views {
            let inst = insts[k % insts.len()];
            let view = (k / insts.len() + k) % views;
            if let Some(item) = plan
                .items
                .iter()
                .find(|it| it.instance == inst && it.view == view)
                && !out.contains(&item.index)
            {
                out.push(item.index);
                picked += 1;
            }
            k += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Stripes of period rho on a face: a clear peak; the same face with noise only (or
    /// stripes at another period): none.
    #[test]
    fn spectrum_peak_at_rho_against_the_floor() {
        let (w, h) = (300usize, 260usize);
        let faces: Vec<u8> = (0..w * h)
            .map(|k| {
                if (20..280).contains(&(k % w)) && (10..250).contains(&(k / w)) {
                    1
                } else {
                    0
                }
            })
            .collect();
        let mut rng = 12345u64;
        let mut noise = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 20.0
        };
        let img = |period: f64, amp: f64, noise: &mut dyn FnMut() -> f64| -> Vec<u8> {
            (0..w * h)
                .map(|k| {
                    let (x, y) = ((k % w) as f64, (k / w) as f64);
                    let u = x * 0.96 + y * 0.28; // stripes turned by 16 degrees
                    (120.0 + amp * (std::f64::consts::TAU * u / period).sin() + noise())
                        .clamp(0.0, 255.0) as u8
                })
                .collect()
        };
        let stripes = img(20.0, 15.0, &mut noise);
        let t = texture_visibility(w, h, &stripes, &faces, 1, 20.0, 1.0).expect("crop");
        assert_eq!(t.crop, 128);
        assert!(t.peak_over_floor_db > 20.0, "{t:?}");
        let flat = img(20.0, 0.0, &mut noise);
        let t0 = texture_visibility(w, h, &flat, &faces, 1, 20.0, 1.0).expect("crop");
        assert!(t0.peak_over_floor_db < 6.0, "{t0:?}");
        let other = img(7.0, 15.0, &mut noise);
        let t1 = texture_visibility(w, h, &other, &faces, 1, 20.0, 1.0).expect("crop");
        assert!(t1.peak_over_floor_db < 6.0, "{t1:?}");
        // No face pixels: nothing to measure.
        assert!(texture_visibility(w, h, &stripes, &faces, 2, 20.0, 1.0).is_none());
    }

    #[test]
    fn percentiles_of_a_histogram() {
        let mut h = vec![0u64; 256];
        h[10] = 1;
        h[100] = 98;
        h[200] = 1;
        assert_eq!(percentiles(&h), (10, 100));
        h[200] = 2;
        assert_eq!(percentiles(&h), (100, 200));
    }
}
