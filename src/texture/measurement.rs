//! Loading measured height maps: Alicona ASCII xyz exports (lines `x y z`) and
//! one-channel float EXR images.

use std::io::{BufRead, BufReader};
use std::path::Path;

use super::error::{Result, TextureError, check};
use super::maps::HeightMap;

/// Units of an xyz export's coordinates. Alicona writes metres by default.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum XyzUnit {
    M,
    Mm,
    Um,
}

impl XyzUnit {
    fn to_um(self) -> f64 {
        match self {
            Self::M => 1e6,
            Self::Mm => 1e3,
            Self::Um => 1.0,
        }
    }
}

/// Reads an ASCII xyz point list on a regular grid. Lines that do not start with a
/// number (headers, comments) are skipped; a numeric line that is not three numbers is
/// an error. Points missing from the grid (Alicona drops invalid ones) get the mean.
pub fn read_xyz(path: &Path, unit: XyzUnit) -> Result<HeightMap> {
    let io = |source| TextureError::Io {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let scale = unit.to_um();
    let mut pts: Vec<[f64; 3]> = Vec::new();
    for (n, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(io)?;
        let t = line.trim();
        let starts_numeric = t
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_digit() || c == '-' || c == '+' || c == '.');
        if !starts_numeric {
            continue;
        }
        let f: Vec<&str> = t
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|s| !s.is_empty())
            .collect();
        let parsed: Option<Vec<f64>> = f.iter().map(|s| s.parse::<f64>().ok()).collect();
        match parsed {
            Some(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
                pts.push([v[0] * scale, v[1] * scale, v[2] * scale])
            }
            Some(v) if v.len() == 3 => {} // NaN height: invalid point, filled below
            _ => {
                return Err(TextureError::Parse {
                    path: path.to_owned(),
                    line: n + 1,
                    message: format!("expected `x y z` (three numbers), got `{t}`"),
                });
            }
        }
    }
    grid_from_points(path, &pts)
}

fn axis_step(vals: &mut Vec<f64>) -> Option<f64> {
    vals.sort_by(f64::total_cmp);
    let span = vals.last()? - vals.first()?;
    let tol = span.abs() * 1e-9 + 1e-12;
    vals.dedup_by(|a, b| (*a - *b).abs() <= tol);
    let step = vals
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    step.is_finite().then_some(step)
}

fn grid_from_points(path: &Path, pts: &[[f64; 3]]) -> Result<HeightMap> {
    let bad = |reason: &str| TextureError::BadExemplar {
        what: path.display().to_string(),
        reason: reason.into(),
    };
    if pts.len() < 4 {
        return Err(bad("fewer than 4 valid points"));
    }
    let mut xs: Vec<f64> = pts.iter().map(|p| p[0]).collect();
    let mut ys: Vec<f64> = pts.iter().map(|p| p[1]).collect();
    let (dx, dy) = match (axis_step(&mut xs), axis_step(&mut ys)) {
        (Some(a), Some(b)) => (a, b),
        _ => return Err(bad("points do not span a 2D grid")),
    };
    if (dx - dy).abs() > 0.01 * dx.max(dy) {
        return Err(bad("x and y spacings differ by more than 1 %")); // square pixels only
    }
    let (x0, y0) = (xs[0], ys[0]);
    let w = ((xs[xs.len() - 1] - x0) / dx).round() as usize + 1;
    let h = ((ys[ys.len() - 1] - y0) / dy).round() as usize + 1;
    if w.saturating_mul(h) > 400_000_000 {
        return Err(bad("grid larger than 400 Mpixel (irregular spacing?)"));
    }
    let mut data = vec![f32::NAN; w * h];
    for p in pts {
        let i = ((p[0] - x0) / dx).round() as usize;
        let j = ((p[1] - y0) / dy).round() as usize;
        data[j.min(h - 1) * w + i.min(w - 1)] = p[2] as f32;
    }
    fill_invalid(&mut data);
    Ok(HeightMap {
        width: w,
        height: h,
        spacing_um: dx,
        data,
    })
}

/// Non-finite samples (invalid measurement points) become the mean of the valid ones;
/// false when there is no finite sample at all.
fn fill_invalid(data: &mut [f32]) -> bool {
    let (s, n) = data
        .iter()
        .filter(|v| v.is_finite())
        .fold((0.0f64, 0usize), |(s, n), &v| (s + v as f64, n + 1));
    let mean = if n > 0 { (s / n as f64) as f32 } else { 0.0 };
    for v in data.iter_mut().filter(|v| !v.is_finite()) {
        *v = mean;
    }
    n > 0
}

/// Reads a float EXR height map (micrometres, channel `Y`) with the given spacing. The
/// header is checked against `limits::MAX_IMAGE_SIDE` before any pixel is read; a file
/// without a `Y` channel, or without a single finite sample, is refused.
pub fn read_exr(path: &Path, spacing_um: f64) -> Result<HeightMap> {
    check(
        spacing_um > 0.0,
        "exemplar_spacing_um",
        spacing_um,
        "> 0 um",
    )?;
    let err = |message: String| TextureError::Exr {
        path: path.to_owned(),
        message,
    };
    let (w, h, mut data) = crate::image_io::read_exr_channel(path, Some("Y"))
        .map_err(|e| err(format!("{e}; write the height map (µm) as channel Y")))?;
    if !fill_invalid(&mut data) {
        return Err(err(
            "no finite sample (all NaN or infinite): refused rather than rendered flat".into(),
        ));
    }
    Ok(HeightMap {
        width: w,
        height: h,
        spacing_um,
        data,
    })
}

/// Loads a measurement by extension: `.xyz`/`.txt`/`.asc` as Alicona ASCII, `.exr` as
/// float image (then `exr_spacing_um` is its spacing).
pub fn load_height_map(path: &Path, unit: XyzUnit, exr_spacing_um: f64) -> Result<HeightMap> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "exr" => read_exr(path, exr_spacing_um),
        _ => read_xyz(path, unit),
    }
}
