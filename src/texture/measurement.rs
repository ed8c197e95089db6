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
    let mut m = read_xyz_raw(path, unit)?;
    fill_invalid(&mut m.data);
    Ok(m)
}

/// [`read_xyz`] with invalid points left as NaN.
fn read_xyz_raw(path: &Path, unit: XyzUnit) -> Result<HeightMap> {
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
    let mut m = read_exr_raw(path, spacing_um)?;
    fill_invalid(&mut m.data);
    Ok(m)
}

/// [`read_exr`] with non-finite samples left as NaN.
fn read_exr_raw(path: &Path, spacing_um: f64) -> Result<HeightMap> {
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
    if !data.iter().any(|v| v.is_finite()) {
        return Err(err(
            "no finite sample (all NaN or infinite): refused rather than rendered flat".into(),
        ));
    }
    // Invalid points stay NaN here (form removal skips them); read_exr fills them.
    for v in data.iter_mut().filter(|v| !v.is_finite()) {
        *v = f32::NAN;
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

/// Form removal: the polynomial in (x, y) fitted by least squares to the valid points
/// and subtracted before a measurement is used (the part's form and tilt are not
/// texture).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FormRemoval {
    /// Subtract the mean only.
    None,
    /// Subtract the best-fit plane a + b x + c y (levelling; default).
    #[default]
    Plane,
    /// Subtract the best-fit quadric (plane + x^2, x y, y^2): also removes curvature.
    Quadratic,
}

/// Smallest fraction of valid points a measurement may have.
pub const MIN_VALID_FRACTION: f64 = 0.5;

/// Loads a measurement for texture use: by extension as [`load_height_map`], then the
/// form (`form`) is fitted to the valid points and subtracted, and invalid points
/// (missing from the xyz grid, non-finite heights or EXR samples) are set to 0, the
/// levelled mean, so they take part in nothing but the map's size. A measurement with
/// fewer than [`MIN_VALID_FRACTION`] valid points is refused naming the file.
pub fn load_measurement(
    path: &Path,
    unit: XyzUnit,
    exr_spacing_um: f64,
    form: FormRemoval,
) -> Result<HeightMap> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let mut m = match ext.as_str() {
        "exr" => read_exr_raw(path, exr_spacing_um)?,
        _ => read_xyz_raw(path, unit)?,
    };
    let valid = m.data.iter().filter(|v| v.is_finite()).count();
    let frac = valid as f64 / m.data.len().max(1) as f64;
    if frac < MIN_VALID_FRACTION {
        return Err(TextureError::BadExemplar {
            what: path.display().to_string(),
            reason: format!(
                "only {:.1} % of its {} points are valid (at least {} % needed)",
                100.0 * frac,
                m.data.len(),
                100.0 * MIN_VALID_FRACTION
            ),
        });
    }
    remove_form(&mut m, form);
    Ok(m)
}

/// Fits the form polynomial to the finite samples (least squares, coordinates scaled to
/// [-1, 1]) and subtracts it; non-finite samples become 0.
pub fn remove_form(m: &mut HeightMap, form: FormRemoval) {
    let (w, h) = (m.width, m.height);
    let sx = 2.0 / (w.max(2) - 1) as f64;
    let sy = 2.0 / (h.max(2) - 1) as f64;
    let basis = |i: usize, j: usize| -> [f64; 6] {
        let x = i as f64 * sx - 1.0;
        let y = j as f64 * sy - 1.0;
        [1.0, x, y, x * x, x * y, y * y]
    };
    let k = match form {
        FormRemoval::None => 1,
        FormRemoval::Plane => 3,
        FormRemoval::Quadratic => 6,
    };
    // Normal equations A^T A c = A^T z in f64.
    let mut ata = [[0.0f64; 6]; 6];
    let mut atz = [0.0f64; 6];
    for j in 0..h {
        for i in 0..w {
            let z = m.data[j * w + i];
            if !z.is_finite() {
                continue;
            }
            let b = basis(i, j);
            for r in 0..k {
                atz[r] += b[r] * z as f64;
                for c in 0..k {
                    ata[r][c] += b[r] * b[c];
                }
            }
        }
    }
    let coef = solve(&mut ata, &mut atz, k);
    for j in 0..h {
        for i in 0..w {
            let v = &mut m.data[j * w + i];
            if v.is_finite() {
                let b = basis(i, j);
                let f: f64 = (0..k).map(|r| coef[r] * b[r]).sum();
                *v = (*v as f64 - f) as f32;
            } else {
                *v = 0.0;
            }
        }
    }
}

/// Gaussian elimination with partial pivoting on the leading k x k block; a singular
/// direction (e.g. a single valid row for a plane) gets coefficient 0.
fn solve(a: &mut [[f64; 6]; 6], b: &mut [f64; 6], k: usize) -> [f64; 6] {
    let scale = (0..k)
        .map(|i| a[i][i].abs())
        .fold(0.0, f64::max)
        .max(1e-300);
    let mut active = [true; 6];
    for col in 0..k {
        let piv = (col..k)
            .max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))
            .unwrap_or(col);
        if a[piv][col].abs() <= 1e-12 * scale {
            active[col] = false;
            continue;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        let prow = a[col];
        for r in 0..k {
            if r != col {
                let f = a[r][col] / prow[col];
                for (x, p) in a[r][col..k].iter_mut().zip(&prow[col..k]) {
                    *x -= f * p;
                }
                b[r] -= f * b[col];
            }
        }
    }
    let mut x = [0.0; 6];
    for i in 0..k {
        if active[i] && a[i][i] != 0.0 {
            x[i] = b[i] / a[i][i];
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tilted, curved surface with a sine texture and invalid points: plane levelling
    /// removes the tilt, the quadric also the curvature, invalid points become 0 and do
    /// not bias the fit.
    #[test]
    fn form_removal_levels_and_ignores_invalid_points() {
        let (w, h) = (64, 48);
        let texture = |i: usize, j: usize| (i as f64 * 0.9).sin() * (j as f64 * 0.7).cos();
        let make = |curv: f64| {
            let mut m = HeightMap::new(w, h, 2.0);
            for j in 0..h {
                for i in 0..w {
                    let (x, y) = (i as f64, j as f64);
                    let z =
                        5.0 + 0.3 * x - 0.2 * y + curv * (x - 30.0) * (x - 30.0) + texture(i, j);
                    m.data[j * w + i] = if (i * 7 + j * 3) % 11 == 0 {
                        f32::NAN
                    } else {
                        z as f32
                    };
                }
            }
            m
        };
        let resid = |m: &HeightMap| {
            let mut worst = 0.0f64;
            for j in 0..h {
                for i in 0..w {
                    let v = m.data[j * w + i] as f64;
                    if (i * 7 + j * 3) % 11 == 0 {
                        assert_eq!(v, 0.0);
                    } else {
                        worst = worst.max((v - texture(i, j)).abs());
                    }
                }
            }
            worst
        };
        let mut plane = make(0.0);
        remove_form(&mut plane, FormRemoval::Plane);
        assert!(resid(&plane) < 0.08, "plane: {}", resid(&plane));
        let mut quad = make(0.01);
        remove_form(&mut quad, FormRemoval::Quadratic);
        assert!(resid(&quad) < 0.08, "quadric: {}", resid(&quad));
        let mut only_plane = make(0.01);
        remove_form(&mut only_plane, FormRemoval::Plane);
        assert!(resid(&only_plane) > 1.0, "a plane cannot remove curvature");
    }
}
