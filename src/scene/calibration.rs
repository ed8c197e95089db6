//! Camera intrinsics: the pinhole matrix and the lens distortion of OpenCV's model
//! (Brown-Conrady: radial k1, k2, k3 and tangential p1, p2), read from the calibration
//! files `cv::FileStorage` and common calibration tools write (YAML or JSON).
//!
//! Conventions are OpenCV's: a camera-frame point (X, Y, Z) (x right, y down, z along
//! the view) has normalised coordinates x' = X / Z, y' = Y / Z; with r^2 = x'^2 + y'^2
//!
//! ```text
//! x'' = x' (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x' y' + p2 (r^2 + 2 x'^2)
//! y'' = y' (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y'^2) + 2 p2 x' y'
//! u = fx x'' + cx,  v = fy y'' + cy
//! ```
//!
//! and (u, v) = (0, 0) is the centre of the top-left pixel. The rational model (k4..k6),
//! the thin-prism (s1..s4) and tilted-sensor (tau) terms and the fisheye model are not
//! supported: a file with any of them non-zero is refused (docs/scene-format.md).

use std::path::{Path, PathBuf};

use serde_yaml::Value;

/// Iterations of Newton's method that invert the distortion (camera rays from pixels).
/// The same count runs in glsl/common/camera.glsl.
pub const UNDISTORT_ITERATIONS: u32 = 8;

/// What is wrong with a calibration file.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("cannot read camera calibration {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("camera calibration {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

/// Radial (k1, k2, k3) and tangential (p1, p2) distortion coefficients, OpenCV's order
/// k1, k2, p1, p2, k3.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    pub k1: f32,
    pub k2: f32,
    pub p1: f32,
    pub p2: f32,
    pub k3: f32,
}

impl Distortion {
    /// All coefficients zero: the ideal pinhole.
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|&k| k == 0.0)
    }

    /// Normalised undistorted (x', y') -> distorted (x'', y''), OpenCV's formula.
    pub fn distort(&self, x: f32, y: f32) -> (f32, f32) {
        let (x2, y2, xy) = (x * x, y * y, x * y);
        let r2 = x2 + y2;
        let rad = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            x * rad + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x2),
            y * rad + self.p1 * (r2 + 2.0 * y2) + 2.0 * self.p2 * xy,
        )
    }

    /// Determinant of the Jacobian of [`Distortion::distort`] at (x', y'): how much the
    /// distortion stretches a small area.
    pub fn jacobian_det(&self, x: f32, y: f32) -> f32 {
        let (k1, k2, p1, p2, k3) = (self.k1, self.k2, self.p1, self.p2, self.k3);
        let (x2, y2, xy) = (x * x, y * y, x * y);
        let r2 = x2 + y2;
        let rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let j00 = rad + 2.0 * x2 * drad + 2.0 * p1 * y + 6.0 * p2 * x;
        let j01 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y;
        let j11 = rad + 2.0 * y2 * drad + 6.0 * p1 * y + 2.0 * p2 * x;
        j00 * j11 - j01 * j01
    }

    /// Distorted (x'', y'') -> undistorted (x', y'): [`UNDISTORT_ITERATIONS`] steps of
    /// Newton's method from (x'', y''), the same arithmetic as `undistort` in
    /// glsl/common/camera.glsl.
    pub fn undistort(&self, xd: f32, yd: f32) -> (f32, f32) {
        let (k1, k2, p1, p2, k3) = (self.k1, self.k2, self.p1, self.p2, self.k3);
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let (x2, y2, xy) = (x * x, y * y, x * y);
            let r2 = x2 + y2;
            let rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
            let fx = x * rad + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) - xd;
            let fy = y * rad + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy - yd;
            let j00 = rad + 2.0 * x2 * drad + 2.0 * p1 * y + 6.0 * p2 * x;
            let j01 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y;
            let j11 = rad + 2.0 * y2 * drad + 6.0 * p1 * y + 2.0 * p2 * x;
            let det = j00 * j11 - j01 * j01;
            if det.abs() < 1e-12 {
                break;
            }
            x -= (j11 * fx - j01 * fy) / det;
            y -= (j00 * fy - j01 * fx) / det;
        }
        (x, y)
    }
}

/// A calibrated pinhole camera: focal lengths and principal point in pixels (OpenCV
/// convention: pixel centres at integer coordinates), image size and distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
    pub distortion: Distortion,
}

impl Intrinsics {
    /// The same camera at another resolution (same field of view): focal lengths and
    /// the principal point scale with the image, pixel edges staying where they were.
    pub fn scaled(&self, width: u32, height: u32) -> Intrinsics {
        let (sx, sy) = (
            width as f64 / self.width as f64,
            height as f64 / self.height as f64,
        );
        Intrinsics {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
            width,
            height,
            distortion: self.distortion,
        }
    }

    /// Reads a calibration file (YAML as `cv::FileStorage` writes it, `%YAML:1.0` header
    /// and `!!opencv-matrix` tags included; ROS camera_info YAML; or JSON).
    pub fn load(path: &Path) -> Result<Intrinsics, CalibrationError> {
        let text = crate::limits::read_text(path).map_err(|source| CalibrationError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text).map_err(|message| CalibrationError::Invalid {
            path: path.to_path_buf(),
            message,
        })
    }

    /// Parses calibration text (see [`Intrinsics::load`]); the error names the field.
    pub fn parse(text: &str) -> Result<Intrinsics, String> {
        // OpenCV writes the directive as `%YAML:1.0`, which YAML 1.1/1.2 parsers reject
        // (`%YAML 1.0` would be the directive); drop it. JSON is YAML and parses as is.
        let body = match text.trim_start().strip_prefix("%YAML") {
            Some(rest) => rest.split_once('\n').map(|(_, b)| b).unwrap_or(""),
            None => text,
        };
        let root: Value =
            serde_yaml::from_str(body).map_err(|e| format!("not YAML or JSON: {e}"))?;
        let root = untag(root);
        let map = root
            .as_mapping()
            .ok_or("the top level is not a mapping of named entries")?;
        let get = |k: &str| map.get(Value::String(k.into()));
        let size = |k: &str| -> Result<u32, String> {
            let v = get(k).ok_or(format!("`{k}` missing"))?;
            let n = v
                .as_u64()
                .or_else(|| v.as_f64().filter(|f| f.fract() == 0.0).map(|f| f as u64))
                .ok_or(format!("`{k}` = {v:?} is not a whole number"))?;
            if !(1..=16384).contains(&n) {
                return Err(format!("`{k}` = {n} is out of range: allowed [1, 16384]"));
            }
            Ok(n as u32)
        };
        let width = size("image_width")?;
        let height = size("image_height")?;
        let k = matrix(get("camera_matrix").ok_or("`camera_matrix` missing")?)
            .map_err(|e| format!("`camera_matrix`: {e}"))?;
        if k.len() != 9 {
            return Err(format!(
                "`camera_matrix` has {} numbers; allowed 9 (3 x 3)",
                k.len()
            ));
        }
        let (fx, fy, cx, cy) = (k[0], k[4], k[2], k[5]);
        for (name, v) in [("fx", fx), ("fy", fy)] {
            if !(v.is_finite() && v > 0.0 && v <= 1e7) {
                return Err(format!(
                    "`camera_matrix` {name} = {v} is out of range: allowed (0, 1e7] px"
                ));
            }
        }
        for (name, v, n) in [("cx", cx, width), ("cy", cy, height)] {
            if !(v.is_finite() && v >= -0.5 && v <= n as f64 - 0.5) {
                return Err(format!(
                    "`camera_matrix` {name} = {v} is out of range: allowed [-0.5, {}] px (inside the image)",
                    n as f64 - 0.5
                ));
            }
        }
        if k[1] != 0.0 {
            return Err(format!(
                "`camera_matrix` skew = {} is not supported: allowed 0",
                k[1]
            ));
        }
        if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(format!(
                "`camera_matrix` {k:?} is not [fx 0 cx; 0 fy cy; 0 0 1]"
            ));
        }
        if let Some(m) = get("distortion_model").and_then(Value::as_str)
            && !["plumb_bob", "rational_polynomial"].contains(&m)
        {
            return Err(format!(
                "`distortion_model` = {m:?} is not supported (the fisheye / equidistant model is not): allowed \"plumb_bob\" (k1, k2, p1, p2, k3)"
            ));
        }
        let d = match get("distortion_coefficients") {
            None => Vec::new(),
            Some(v) => matrix(v).map_err(|e| format!("`distortion_coefficients`: {e}"))?,
        };
        if ![0, 4, 5, 8, 12, 14].contains(&d.len()) {
            return Err(format!(
                "`distortion_coefficients` has {} numbers; OpenCV writes 4, 5, 8, 12 or 14",
                d.len()
            ));
        }
        if let Some((i, v)) = d.iter().enumerate().skip(5).find(|(_, v)| **v != 0.0) {
            let name = ["k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y"][i - 5];
            return Err(format!(
                "`distortion_coefficients` {name} = {v} is not supported: allowed 0 (only k1, k2, p1, p2, k3 are modelled)"
            ));
        }
        let at = |i: usize| d.get(i).copied().unwrap_or(0.0);
        let distortion = Distortion {
            k1: at(0) as f32,
            k2: at(1) as f32,
            p1: at(2) as f32,
            p2: at(3) as f32,
            k3: at(4) as f32,
        };
        for (name, v) in [
            ("k1", at(0)),
            ("k2", at(1)),
            ("p1", at(2)),
            ("p2", at(3)),
            ("k3", at(4)),
        ] {
            if !(v.is_finite() && v.abs() <= 1e3) {
                return Err(format!(
                    "`distortion_coefficients` {name} = {v} is out of range: allowed [-1000, 1000]"
                ));
            }
        }
        let intr = Intrinsics {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            distortion,
        };
        intr.check_invertible()?;
        Ok(intr)
    }

    /// The distortion must be one-to-one over the image, or camera rays (pixel ->
    /// direction) are not defined: along the border and the diagonals the inverse must
    /// reproduce the pixel within 1e-3 px.
    fn check_invertible(&self) -> Result<(), String> {
        let d = self.distortion;
        if d.is_zero() {
            return Ok(());
        }
        let (w, h) = (self.width as f64, self.height as f64);
        let n = 64;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            for (u, v) in [
                (t * w - 0.5, -0.5),
                (t * w - 0.5, h - 0.5),
                (-0.5, t * h - 0.5),
                (w - 0.5, t * h - 0.5),
                (t * w - 0.5, t * h - 0.5),
                (t * w - 0.5, (1.0 - t) * h - 0.5),
            ] {
                let xd = ((u - self.cx) / self.fx) as f32;
                let yd = ((v - self.cy) / self.fy) as f32;
                let (x, y) = d.undistort(xd, yd);
                let (x2, y2) = d.distort(x, y);
                let err = ((x2 - xd) as f64 * self.fx).hypot((y2 - yd) as f64 * self.fy);
                if err.is_nan() || err > 1e-3 || !x.is_finite() || !y.is_finite() {
                    return Err(format!(
                        "`distortion_coefficients` {d:?} cannot be inverted at pixel ({u:.1}, {v:.1}) (the distortion folds over inside the image); camera rays need a one-to-one distortion"
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Drops YAML tags (`!!opencv-matrix`) at every level.
fn untag(v: Value) -> Value {
    match v {
        Value::Tagged(t) => untag(t.value),
        Value::Mapping(m) => Value::Mapping(m.into_iter().map(|(k, v)| (k, untag(v))).collect()),
        Value::Sequence(s) => Value::Sequence(s.into_iter().map(untag).collect()),
        other => other,
    }
}

/// The numbers of a matrix: an OpenCV matrix node (`rows`, `cols`, `dt`, `data`; JSON
/// adds `type_id`), or a (nested) list of numbers, row-major.
fn matrix(v: &Value) -> Result<Vec<f64>, String> {
    fn flatten(v: &Value, out: &mut Vec<f64>) -> Result<(), String> {
        match v {
            Value::Sequence(s) => s.iter().try_for_each(|e| flatten(e, out)),
            Value::Number(n) => {
                out.push(n.as_f64().ok_or("a number out of range")?);
                Ok(())
            }
            other => Err(format!("{other:?} is not a number")),
        }
    }
    let mut out = Vec::new();
    match v {
        Value::Mapping(m) => {
            let data = m
                .get(Value::String("data".into()))
                .ok_or("a matrix node needs `data`")?;
            flatten(data, &mut out)?;
            let dim = |k: &str| m.get(Value::String(k.into())).and_then(Value::as_u64);
            if let (Some(r), Some(c)) = (dim("rows"), dim("cols"))
                && (r * c) as usize != out.len()
            {
                return Err(format!(
                    "rows x cols = {r} x {c} but `data` has {} numbers",
                    out.len()
                ));
            }
        }
        other => flatten(other, &mut out)?,
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const OPENCV_YAML: &str = "%YAML:1.0
---
calibration_time: \"Mon Nov 23 10:00:00 2026\"
image_width: 1224
image_height: 1025
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 3.6e+03, 0., 615.5, 0., 3.61e+03, 508.25, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.12, 0.08, 1.0e-3, -5.0e-4, 0. ]
avg_reprojection_error: 0.21
";

    #[test]
    fn opencv_yaml_parses() {
        let i = Intrinsics::parse(OPENCV_YAML).expect("parse");
        assert_eq!((i.width, i.height), (1224, 1025));
        assert_eq!((i.fx, i.fy, i.cx, i.cy), (3600.0, 3610.0, 615.5, 508.25));
        assert_eq!(
            i.distortion,
            Distortion {
                k1: -0.12,
                k2: 0.08,
                p1: 1.0e-3,
                p2: -5.0e-4,
                k3: 0.0
            }
        );
    }

    #[test]
    fn opencv_json_and_plain_lists_parse() {
        let json = r#"{
            "image_width": 640, "image_height": 480,
            "camera_matrix": { "type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
                "data": [ 800.0, 0.0, 320.0, 0.0, 800.0, 240.0, 0.0, 0.0, 1.0 ] },
            "distortion_coefficients": { "type_id": "opencv-matrix", "rows": 5, "cols": 1,
                "dt": "d", "data": [ 0.1, 0.0, 0.0, 0.0, 0.0 ] }
        }"#;
        let i = Intrinsics::parse(json).expect("json");
        assert_eq!((i.fx, i.cx, i.distortion.k1), (800.0, 320.0, 0.1));
        let nested = "image_width: 640\nimage_height: 480\ncamera_matrix: [[800, 0, 320], [0, 810, 240], [0, 0, 1]]\n";
        let i = Intrinsics::parse(nested).expect("nested");
        assert_eq!((i.fy, i.cy), (810.0, 240.0));
        assert!(i.distortion.is_zero());
    }

    #[test]
    fn unsupported_models_are_refused_by_name() {
        let e = Intrinsics::parse(&OPENCV_YAML.replace(
            "rows: 1\n   cols: 5\n   dt: d\n   data: [ -0.12, 0.08, 1.0e-3, -5.0e-4, 0. ]",
            "rows: 1\n   cols: 8\n   dt: d\n   data: [ -0.12, 0.08, 1.0e-3, -5.0e-4, 0., 0., 0.2, 0. ]",
        ))
        .unwrap_err();
        assert!(e.contains("k5") && e.contains("not supported"), "{e}");
        let e = Intrinsics::parse(&format!("{OPENCV_YAML}distortion_model: equidistant\n"))
            .unwrap_err();
        assert!(e.contains("fisheye"), "{e}");
        let e = Intrinsics::parse(&OPENCV_YAML.replace("image_width: 1224", "")).unwrap_err();
        assert!(e.contains("image_width"), "{e}");
        let e = Intrinsics::parse(&OPENCV_YAML.replace("615.5", "2000")).unwrap_err();
        assert!(e.contains("cx") && e.contains("allowed"), "{e}");
        // Strong barrel distortion folds over inside a wide image.
        let e = Intrinsics::parse(
            &OPENCV_YAML
                .replace("3.6e+03", "300")
                .replace("3.61e+03", "300")
                .replace("0.08,", "0.,"),
        )
        .unwrap_err();
        assert!(e.contains("cannot be inverted"), "{e}");
    }

    #[test]
    fn undistort_inverts_distort() {
        let d = Distortion {
            k1: -0.25,
            k2: 0.12,
            p1: 1.5e-3,
            p2: -8.0e-4,
            k3: -0.02,
        };
        let mut worst = 0.0f32;
        for i in -10..=10 {
            for j in -10..=10 {
                let (x, y) = (i as f32 * 0.04, j as f32 * 0.03);
                let (xd, yd) = d.distort(x, y);
                let (xu, yu) = d.undistort(xd, yd);
                worst = worst.max((xu - x).abs().max((yu - y).abs()));
            }
        }
        // f32 arithmetic: a few ulps of coordinates up to 0.5.
        assert!(worst < 2e-6, "round trip error {worst}");
        assert_eq!(Distortion::default().undistort(0.3, -0.2), (0.3, -0.2));
    }

    #[test]
    fn scaling_keeps_the_field_of_view() {
        let i = Intrinsics::parse(OPENCV_YAML).unwrap();
        let s = i.scaled(612, 512);
        // The image's left edge (u = -0.5) stays at the same normalised coordinate.
        let x0 = (-0.5 - i.cx) / i.fx;
        let x1 = (-0.5 - s.cx) / s.fx;
        assert!((x0 - x1).abs() < 1e-12);
    }
}
