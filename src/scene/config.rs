//! The render scene file (TOML): object, material, table, ring light, camera, render
//! settings. Every field has a unit, a default and an allowed range; `validate` names the
//! field and the range on error. The format is documented in docs/scene-format.md.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::trace::AccelChoice;

/// What went wrong reading a scene file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read scene file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("scene file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{field} = {value} is out of range: allowed {range}")]
    Range {
        field: &'static str,
        value: String,
        range: &'static str,
    },
    #[error("{field}: {message}")]
    Invalid {
        field: &'static str,
        message: String,
    },
    /// A field that breaks the rules a scene file shares with dataset jobs
    /// ([`NoiseFields`]).
    #[error("{} = {}: {}", .0.field, .0.value, .0.allowed)]
    Rule(FieldRule),
    /// A `[[light]]` entry (index from 0) has a bad field.
    #[error("light[{index}].{field}: {message}")]
    Light {
        index: usize,
        field: &'static str,
        message: String,
    },
    /// A `[[texture.map]]` entry (index from 0) has a bad field.
    #[error("texture.map[{index}].{field}: {message}")]
    TextureMap {
        index: usize,
        field: &'static str,
        message: String,
    },
    #[error(transparent)]
    Calibration(#[from] crate::scene::calibration::CalibrationError),
}

/// The scene file's top level.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    pub object: ObjectConfig,
    pub material: MaterialConfig,
    pub table: TableConfig,
    /// `[light]` (one ring on the camera, the old form) or `[[light]]` entries (kept in
    /// `light.list`); [`LightConfig::specs`] gives the checked lights.
    #[serde(deserialize_with = "light_section")]
    pub light: LightConfig,
    pub camera: CameraConfig,
    pub render: RenderConfig,
    pub texture: TextureConfig,
    /// EMVA 1288 sensor (docs/scene-format.md, `[sensor]`); None: the linear
    /// `camera.exposure * camera.gain` model.
    pub sensor: Option<SensorConfig>,
}

/// The inspected object: a glTF file or a built-in test body, and where it stands.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObjectConfig {
    /// glTF (.gltf/.glb) path, relative to the scene file. Exclusive with `builtin`.
    /// The old key: read in millimetres unless `unit` says otherwise.
    pub gltf: Option<PathBuf>,
    /// Mesh file (glTF/GLB, OBJ, STL or PLY), relative to the scene file; wins over
    /// `builtin`, exclusive with `gltf`.
    pub path: Option<PathBuf>,
    /// Unit of the mesh file's coordinates ("mm", "m", "in"); default: the format's
    /// (glTF metres, synosis' own glTF files and the `gltf` key millimetres; OBJ, STL,
    /// PLY millimetres). docs/mesh-format.md.
    pub unit: Option<crate::scene::mesh_io::MeshUnit>,
    /// Inspected faces: labels, region ids or normal selectors (`scene::inspect`);
    /// none = the labels A, B, C the mesh carries.
    pub inspect: Option<Vec<crate::scene::inspect::InspectEntry>>,
    /// "testbody-b" or "testbody-m". Used when `gltf` is absent.
    pub builtin: Option<String>,
    /// Translation of the object, mm (the table follows in x and y).
    pub position_mm: [f32; 3],
}

impl Default for ObjectConfig {
    fn default() -> Self {
        ObjectConfig {
            gltf: None,
            path: None,
            unit: None,
            inspect: None,
            builtin: Some("testbody-b".into()),
            position_mm: [0.0; 3],
        }
    }
}

/// Aluminium at 550 nm after Rakic (1995), via refractiveindex.info (Al, Rakic 1995
/// Lorentz-Drude model): n = 0.958, k = 6.69. The camera is grayscale, so one wavelength.
pub const AL_N_550: f32 = 0.958;
pub const AL_K_550: f32 = 6.69;

/// The object's rough conductor. Its roughness is given either as `alpha` (GGX alpha,
/// Walter 2007) or as `roughness` (appleseed / Disney convention r, alpha = r^2), never
/// both; [`MaterialConfig::alpha`] is always the GGX alpha the renderer uses.
#[derive(Clone, Debug, Deserialize)]
#[serde(try_from = "MaterialRaw")]
pub struct MaterialConfig {
    /// GGX alpha, (0, 1]; `roughness^2` when the file gave `roughness`.
    pub alpha: f32,
    /// The roughness r the file gave (alpha = r^2), if it used that convention, (0, 1].
    pub roughness: Option<f32>,
    /// Real part of the complex index of refraction, (0, 10].
    pub ior_n: f32,
    /// Imaginary part (extinction coefficient), [0, 20].
    pub ior_k: f32,
    /// Kulla-Conty multiple-scattering energy compensation.
    pub energy_compensation: bool,
    /// Materials for parts of the object (`[[material.region]]`, `scene::materials`);
    /// triangles no entry selects keep this conductor.
    pub region: Vec<crate::scene::materials::RegionMaterialConfig>,
}

impl Default for MaterialConfig {
    fn default() -> Self {
        MaterialConfig {
            alpha: 0.15,
            roughness: None,
            ior_n: AL_N_550,
            ior_k: AL_K_550,
            energy_compensation: true,
            region: Vec::new(),
        }
    }
}

/// `[material]` as written: `alpha` and `roughness` are both optional, at most one given.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct MaterialRaw {
    alpha: Option<f32>,
    roughness: Option<f32>,
    ior_n: Option<f32>,
    ior_k: Option<f32>,
    energy_compensation: Option<bool>,
    region: Vec<crate::scene::materials::RegionMaterialConfig>,
}

impl TryFrom<MaterialRaw> for MaterialConfig {
    type Error = String;
    fn try_from(r: MaterialRaw) -> Result<Self, String> {
        let d = MaterialConfig::default();
        let alpha = match (r.alpha, r.roughness) {
            (Some(a), Some(rough)) => {
                return Err(format!(
                    "material: both `alpha` = {a} and `roughness` = {rough} given; give one \
                     (`roughness` is appleseed's / Disney's r with alpha = r^2, `alpha` is GGX alpha)"
                ));
            }
            (Some(a), None) => a,
            (None, Some(rough)) => rough * rough,
            (None, None) => d.alpha,
        };
        Ok(MaterialConfig {
            alpha,
            roughness: r.roughness,
            ior_n: r.ior_n.unwrap_or(d.ior_n),
            ior_k: r.ior_k.unwrap_or(d.ior_k),
            energy_compensation: r.energy_compensation.unwrap_or(d.energy_compensation),
            region: r.region,
        })
    }
}

/// The black velvet table: a square in the plane z = 0 under the object.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TableConfig {
    /// Lambertian albedo, [0, 1].
    pub albedo: f32,
    /// Edge length, mm, [1, 100000].
    pub size_mm: f32,
}

impl Default for TableConfig {
    fn default() -> Self {
        TableConfig {
            albedo: 0.01,
            size_mm: 400.0,
        }
    }
}

/// The ring light: a diffusely emitting torus centred on the camera, axis = view axis
/// (`[light]`); or, with `list`, the scene's `[[light]]` entries.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightConfig {
    /// Distance from the torus centre to the tube centre, mm, (0, 10000].
    pub major_radius_mm: f32,
    /// Tube radius, mm, (0, major_radius_mm).
    pub minor_radius_mm: f32,
    /// Emitted radiance, W sr^-1 m^-2 (relative units; the sensor model scales), [0, 1e6].
    pub radiance: f32,
    /// Tessellation: segments around the ring [8, 1024] and around the tube [4, 256].
    pub segments_major: u32,
    pub segments_minor: u32,
    /// Next-event estimation: "facing" (default) or "uniform" (docs/rendering.md).
    pub sampling: LightSampling,
    /// The `[[light]]` entries when the file has a list instead of `[light]`; then the
    /// fields above are unused. `Some(empty)`: no lights.
    #[serde(skip)]
    pub list: Option<Vec<crate::scene::lights::LightEntry>>,
}

impl LightConfig {
    /// The lights in words, for logs: "Facing light sampling" for `[light]` (as always),
    /// else the kinds of the `[[light]]` entries.
    pub fn describe(&self) -> String {
        match &self.list {
            None => format!("{:?} light sampling", self.sampling),
            Some(list) => {
                let kinds: Vec<&str> = list.iter().map(|e| e.kind.name()).collect();
                format!("lights [{}]", kinds.join(", "))
            }
        }
    }

    /// The scene's lights, checked: the `[[light]]` entries, else the `[light]` ring on
    /// the camera.
    pub fn specs(&self) -> Result<Vec<crate::scene::lights::LightSpec>, ConfigError> {
        use crate::scene::lights::{LightSpec, resolve_all};
        match &self.list {
            Some(list) => resolve_all(list),
            None => Ok(vec![LightSpec::legacy_ring(self)]),
        }
    }
}

/// `light` as a table (`[light]`, the ring on the camera) or an array of tables
/// (`[[light]]`, kept in `LightConfig::list`); errors name the entry.
fn light_section<'de, D: serde::Deserializer<'de>>(d: D) -> Result<LightConfig, D::Error> {
    use serde::de::Error;
    match toml::Value::deserialize(d)? {
        toml::Value::Array(items) => {
            let mut list = Vec::with_capacity(items.len());
            for (i, v) in items.into_iter().enumerate() {
                list.push(
                    v.try_into()
                        .map_err(|e| D::Error::custom(format!("light[{i}]: {e}")))?,
                );
            }
            Ok(LightConfig {
                list: Some(list),
                ..LightConfig::default()
            })
        }
        v @ toml::Value::Table(_) => v
            .try_into()
            .map_err(|e| D::Error::custom(format!("light: {e}"))),
        other => Err(D::Error::custom(format!(
            "light: a table `[light]` or a list `[[light]]`, not {}",
            other.type_str()
        ))),
    }
}

/// How the path tracer picks points on the ring light (ids match path_trace.comp).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightSampling {
    /// Uniform by area over all triangles of the tessellated torus.
    Uniform = 0,
    /// A ring segment uniformly, then a triangle of it by area cos_light cos_surface / d^2
    /// from the shading point (cosines floored at 0.05).
    #[default]
    Facing = 1,
}

impl Default for LightConfig {
    fn default() -> Self {
        LightConfig {
            major_radius_mm: 30.0,
            minor_radius_mm: 5.0,
            radiance: 1.0,
            segments_major: 96,
            segments_minor: 16,
            sampling: LightSampling::Facing,
            list: None,
        }
    }
}

/// Pinhole camera, sensor model and pose.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Pixels, [1, 16384] each.
    pub width: u32,
    pub height: u32,
    /// Pixel pitch, µm, (0, 1000].
    pub pixel_um: f32,
    /// Focal length, mm, (0, 10000].
    pub focal_mm: f32,
    /// Distance from the pinhole to the viewed face centre, mm, (0, 100000].
    pub working_distance_mm: f32,
    /// Viewpoint: face letter A/B/C and the angle from the face normal in degrees,
    /// [0, 89], e.g. "A20".
    pub view: String,
    /// Sensor model: value = clamp(radiance * exposure * gain, 0, 1). Exposure (0, 1e9].
    pub exposure: f32,
    /// Gain, (0, 1e6].
    pub gain: f32,
    /// Pose instead of `view`: eye, target and up in scene mm (docs/scene-format.md).
    pub look_at: Option<LookAt>,
    /// Pose instead of `view`: 4 x 4 world-from-camera matrix, rows as written; the
    /// camera looks down its -Z, +Y is the image's up (OpenGL axes).
    pub matrix: Option<[[f64; 4]; 4]>,
    /// Pose instead of `view`: OpenCV extrinsics, world-to-camera (x right, y down, z
    /// forward): x_cam = R(rvec) x_world + tvec.
    pub opencv: Option<OpenCvPose>,
    /// OpenCV calibration file (YAML or JSON), relative to the scene file: sets the
    /// resolution, the focal lengths, the principal point and the distortion.
    pub calibration: Option<PathBuf>,
    /// The calibration's intrinsics once loaded ([`SceneConfig::load`]); None: the
    /// centred pinhole of `focal_mm` and `pixel_um`.
    #[serde(skip)]
    pub intrinsics: Option<crate::scene::calibration::Intrinsics>,
    /// Working f-number of the lens, [0.5, 1000]; None (omitted or "inf"): pinhole. Sets
    /// the image-plane irradiance of the `[sensor]` model.
    #[serde(deserialize_with = "f_number_or_inf")]
    pub f_number: Option<f64>,
    /// Distance along the view axis to the plane in focus, mm, (0, 100000]; None: the
    /// working distance (the aimed face centre). Used with `f_number`.
    pub focus_distance_mm: Option<f32>,
}

/// `look_at = { eye = [..], target = [..], up = [0, 0, 1] }`, scene millimetres.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct LookAt {
    pub eye: [f64; 3],
    pub target: [f64; 3],
    /// Image up (made orthogonal to the view direction); default +Z.
    #[serde(default = "default_up")]
    pub up: [f64; 3],
}

fn default_up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

/// OpenCV extrinsics: `rvec` a Rodrigues rotation vector (radians), `tvec` in mm.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct OpenCvPose {
    pub rvec: [f64; 3],
    pub tvec: [f64; 3],
}

/// Where the camera is: a face-relative view, or a free pose (eye, unit forward, unit
/// up orthogonal to it; scene mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pose {
    View(View),
    Free {
        eye: glam::DVec3,
        forward: glam::DVec3,
        up: glam::DVec3,
    },
}

/// Rodrigues: the rotation matrix (rows) of rotation vector `r` (axis * angle, radians).
pub fn rodrigues(r: [f64; 3]) -> [[f64; 3]; 3] {
    let v = glam::DVec3::from(r);
    let th = v.length();
    if th < 1e-300 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = v / th;
    let (s, c) = th.sin_cos();
    let kk = |i: usize, j: usize| k[i] * k[j] * (1.0 - c);
    [
        [c + kk(0, 0), kk(0, 1) - s * k.z, kk(0, 2) + s * k.y],
        [kk(1, 0) + s * k.z, c + kk(1, 1), kk(1, 2) - s * k.x],
        [kk(2, 0) - s * k.y, kk(2, 1) + s * k.x, c + kk(2, 2)],
    ]
}

const POSE_LIMIT: f64 = 1e6;

impl CameraConfig {
    /// The fields giving a free pose that are set (`look_at`, `matrix`, `opencv`).
    pub fn free_pose_fields(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        if self.look_at.is_some() {
            v.push("camera.look_at");
        }
        if self.matrix.is_some() {
            v.push("camera.matrix");
        }
        if self.opencv.is_some() {
            v.push("camera.opencv");
        }
        v
    }

    /// The camera's pose, checked: a free pose when one is given, else `view`.
    pub fn pose(&self) -> Result<Pose, ConfigError> {
        use glam::DVec3;
        let fields = self.free_pose_fields();
        if fields.len() > 1 {
            return Err(ConfigError::Invalid {
                field: "camera",
                message: format!(
                    "{} given; give exactly one of camera.view, camera.look_at, camera.matrix, camera.opencv",
                    fields.join(" and ")
                ),
            });
        }
        let bad = |field: &'static str, message: String| ConfigError::Invalid { field, message };
        let vec_ok = |v: [f64; 3]| v.iter().all(|c| c.is_finite() && c.abs() <= POSE_LIMIT);
        if let Some(l) = &self.look_at {
            for (name, v) in [("eye", l.eye), ("target", l.target), ("up", l.up)] {
                if !vec_ok(v) {
                    return Err(bad(
                        "camera.look_at",
                        format!("{name} = {v:?}: each coordinate finite, in [-1e6, 1e6] mm"),
                    ));
                }
            }
            let (eye, target) = (DVec3::from(l.eye), DVec3::from(l.target));
            let d = target - eye;
            if d.length() < 1e-6 {
                return Err(bad(
                    "camera.look_at",
                    "eye and target coincide; allowed: at least 1e-6 mm apart".into(),
                ));
            }
            let forward = d.normalize();
            let up = DVec3::from(l.up);
            let right = forward.cross(up);
            if up.length() < 1e-12 || right.length() < 1e-6 * up.length() {
                return Err(bad(
                    "camera.look_at",
                    format!(
                        "up = {:?} is zero or parallel to target - eye; allowed: any direction not along the view",
                        l.up
                    ),
                ));
            }
            let right = right.normalize();
            return Ok(Pose::Free {
                eye,
                forward,
                up: right.cross(forward).normalize(),
            });
        }
        if let Some(m) = &self.matrix {
            if !m
                .iter()
                .flatten()
                .all(|c| c.is_finite() && c.abs() <= POSE_LIMIT)
            {
                return Err(bad(
                    "camera.matrix",
                    "every entry finite, in [-1e6, 1e6]".into(),
                ));
            }
            if m[3] != [0.0, 0.0, 0.0, 1.0] {
                return Err(bad(
                    "camera.matrix",
                    format!(
                        "last row {:?}; allowed [0, 0, 0, 1] (a rigid transform)",
                        m[3]
                    ),
                ));
            }
            let col = |j: usize| DVec3::new(m[0][j], m[1][j], m[2][j]);
            let (x, y, z) = (col(0), col(1), col(2));
            let ortho = [
                x.dot(x) - 1.0,
                y.dot(y) - 1.0,
                z.dot(z) - 1.0,
                x.dot(y),
                y.dot(z),
                z.dot(x),
            ]
            .iter()
            .all(|e| e.abs() <= 1e-4);
            if !ortho || x.cross(y).dot(z) <= 0.0 {
                return Err(bad(
                    "camera.matrix",
                    "the upper 3 x 3 block must be a rotation (orthonormal within 1e-4, determinant +1)".into(),
                ));
            }
            return Ok(Pose::Free {
                eye: col(3),
                forward: -z.normalize(),
                up: y.normalize(),
            });
        }
        if let Some(o) = &self.opencv {
            if !o.rvec.iter().all(|c| c.is_finite() && c.abs() <= 1e3) {
                return Err(bad(
                    "camera.opencv",
                    format!("rvec = {:?}: each finite, in [-1000, 1000] radians", o.rvec),
                ));
            }
            if !vec_ok(o.tvec) {
                return Err(bad(
                    "camera.opencv",
                    format!("tvec = {:?}: each finite, in [-1e6, 1e6] mm", o.tvec),
                ));
            }
            let r = rodrigues(o.rvec);
            let row = |i: usize| DVec3::from(r[i]);
            let t = DVec3::from(o.tvec);
            // eye = -R^T t; camera x, y, z axes in the world are R's rows.
            let eye = -(row(0) * t.x + row(1) * t.y + row(2) * t.z);
            return Ok(Pose::Free {
                eye,
                forward: row(2),
                up: -row(1),
            });
        }
        Ok(Pose::View(parse_view(&self.view)?))
    }

    /// The pose in words, for messages and logs: the view name or the free pose's field.
    pub fn describe_pose(&self) -> String {
        match self.free_pose_fields().first() {
            Some(f) => f.trim_start_matches("camera.").to_string(),
            None => self.view.clone(),
        }
    }
}

/// `f_number`: a number, or "inf" (the pinhole: None).
fn f_number_or_inf<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Raw {
        Num(f64),
        Word(String),
    }
    match Raw::deserialize(d)? {
        Raw::Num(n) if n.is_infinite() && n > 0.0 => Ok(None),
        Raw::Num(n) => Ok(Some(n)),
        Raw::Word(w) if w == "inf" => Ok(None),
        Raw::Word(w) => Err(serde::de::Error::custom(format!(
            "camera.f_number = {w:?}: allowed a number in [0.5, 1000] or \"inf\" (pinhole)"
        ))),
    }
}

/// `[sensor] exposure`: "auto" or a fixed time.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(try_from = "ExposureRaw")]
pub enum ExposureSetting {
    /// Chosen per image from the linear radiance (`auto_statistic`, `auto_percentile`,
    /// `auto_fraction`).
    Auto(AutoExposure),
    /// A fixed exposure time, ms.
    Fixed { ms: f64 },
}

/// The "auto" word (a unit type so the variant reads as data).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AutoExposure;

#[derive(Deserialize)]
#[serde(untagged)]
enum ExposureRaw {
    Word(String),
    Table { ms: f64 },
    Num(f64),
}

impl TryFrom<ExposureRaw> for ExposureSetting {
    type Error = String;
    fn try_from(r: ExposureRaw) -> Result<Self, String> {
        match r {
            ExposureRaw::Word(w) if w == "auto" => Ok(ExposureSetting::Auto(AutoExposure)),
            ExposureRaw::Table { ms } => Ok(ExposureSetting::Fixed { ms }),
            ExposureRaw::Word(w) => Err(format!(
                "sensor.exposure = {w:?}: allowed \"auto\" or {{ ms = <time> }}"
            )),
            ExposureRaw::Num(n) => Err(format!(
                "sensor.exposure = {n}: write {{ ms = {n} }} (milliseconds) or \"auto\""
            )),
        }
    }
}

/// What auto exposure measures on the object's pixels (`[sensor] auto_statistic`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AutoStatistic {
    /// The `auto_percentile` percentile (keeps highlights below saturation).
    #[default]
    Percentile,
    /// The mean (a machine-vision camera's "target brightness": highlights may clip;
    /// unbiased under Monte Carlo noise, so the exposure does not depend on the spp).
    Mean,
}

/// Vertical blooming (CCD) or none (CMOS).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Blooming {
    #[default]
    None,
    Vertical,
}

/// The `[sensor]` section: an EMVA 1288 camera (src/render/sensor.rs). Defaults: a
/// monochrome machine-vision camera, docs/scene-format.md.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// "auto" or { ms = ... }, ms in (0, 1e6].
    pub exposure: ExposureSetting,
    /// Percentile of the object's pixels auto exposure aims at, (0, 100].
    pub auto_percentile: f64,
    /// Fraction of saturation that percentile (or the mean) reaches, (0, 1].
    pub auto_fraction: f64,
    /// "percentile" (default) or "mean": which statistic of the object's pixels auto
    /// exposure sets to `auto_fraction` of saturation.
    pub auto_statistic: AutoStatistic,
    /// Quantum efficiency at `wavelength_nm`, (0, 1].
    pub quantum_efficiency: f64,
    /// System gain K, DN per electron at `bit_depth`, (0, 1000].
    pub gain_dn_per_electron: f64,
    /// Temporal dark noise, electrons (rms), [0, 1e5].
    pub dark_noise_electrons: f64,
    /// Full-well (saturation) capacity, electrons, [1, 1e8].
    pub saturation_electrons: f64,
    /// ADC bits: 8, 10, 12 or 16.
    pub bit_depth: u32,
    /// "none" (CMOS) or "vertical" (CCD: excess charge spills along the column).
    pub blooming: Blooming,
    /// Dark offset added to every code, DN, [0, 2^bit_depth - 1).
    pub black_level_dn: f64,
    /// Dark signal non-uniformity (rms of a fixed per-pixel offset), electrons, [0, 1e5].
    pub dsnu_electrons: f64,
    /// Seed of the DSNU pattern (fixed per camera, not per image), any u64.
    pub dsnu_seed: u64,
    /// Column DSNU: rms of a fixed offset shared by each column's pixels (a CMOS
    /// sensor's column amplifiers), electrons, [0, 1e5].
    pub dsnu_column_electrons: f64,
    /// Row DSNU: rms of a fixed offset shared by each row's pixels, electrons, [0, 1e5].
    pub dsnu_row_electrons: f64,
    /// Photo-response non-uniformity (rms of a fixed per-pixel gain on the signal), % of
    /// the signal, [0, 50].
    pub prnu_percent: f64,
    /// Seed of the PRNU pattern (fixed per camera, not per image), any u64.
    pub prnu_seed: u64,
    /// Dark current, electrons per second (mean dark signal I_d t, Poisson), [0, 1e7].
    pub dark_current_electrons_per_s: f64,
    /// The camera's wavelength (photon energy), nm, [200, 2000].
    pub wavelength_nm: f64,
    /// The lens's diffraction: the radiance convolved with the Airy pattern of the working
    /// f-number at `wavelength_nm` before the sensor step (`render::optics`).
    pub diffraction: bool,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            exposure: ExposureSetting::Auto(AutoExposure),
            auto_percentile: 99.5,
            auto_fraction: 0.9,
            auto_statistic: AutoStatistic::Percentile,
            quantum_efficiency: 0.6,
            gain_dn_per_electron: 0.025,
            dark_noise_electrons: 7.0,
            saturation_electrons: 10_000.0,
            bit_depth: 8,
            blooming: Blooming::None,
            black_level_dn: 0.0,
            dsnu_electrons: 0.0,
            dsnu_seed: 0,
            dsnu_column_electrons: 0.0,
            dsnu_row_electrons: 0.0,
            prnu_percent: 0.0,
            prnu_seed: 0,
            dark_current_electrons_per_s: 0.0,
            wavelength_nm: 550.0,
            diffraction: false,
        }
    }
}

impl SensorConfig {
    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        // (A non-finite or out-of-f32 value is not finite as f32: range_f refuses it.)
        let f = |field, v: f64, lo: f64, hi: f64, lo_open: bool, range| {
            range_f(field, v as f32, lo as f32, hi as f32, lo_open, range)
        };
        if let ExposureSetting::Fixed { ms } = self.exposure {
            f("sensor.exposure.ms", ms, 0.0, 1e6, true, "(0, 1e6] ms")?;
        }
        f(
            "sensor.auto_percentile",
            self.auto_percentile,
            0.0,
            100.0,
            true,
            "(0, 100]",
        )?;
        f(
            "sensor.auto_fraction",
            self.auto_fraction,
            0.0,
            1.0,
            true,
            "(0, 1]",
        )?;
        f(
            "sensor.quantum_efficiency",
            self.quantum_efficiency,
            0.0,
            1.0,
            true,
            "(0, 1]",
        )?;
        f(
            "sensor.gain_dn_per_electron",
            self.gain_dn_per_electron,
            0.0,
            1000.0,
            true,
            "(0, 1000] DN/e-",
        )?;
        f(
            "sensor.dark_noise_electrons",
            self.dark_noise_electrons,
            0.0,
            1e5,
            false,
            "[0, 1e5] e-",
        )?;
        f(
            "sensor.saturation_electrons",
            self.saturation_electrons,
            1.0,
            1e8,
            false,
            "[1, 1e8] e-",
        )?;
        if ![8, 10, 12, 16].contains(&self.bit_depth) {
            return Err(ConfigError::Range {
                field: "sensor.bit_depth",
                value: self.bit_depth.to_string(),
                range: "8, 10, 12 or 16",
            });
        }
        let top = ((1u64 << self.bit_depth) - 1) as f64;
        if !(self.black_level_dn >= 0.0 && self.black_level_dn < top) {
            return Err(ConfigError::Range {
                field: "sensor.black_level_dn",
                value: self.black_level_dn.to_string(),
                range: "[0, 2^bit_depth - 1) DN",
            });
        }
        f(
            "sensor.dsnu_electrons",
            self.dsnu_electrons,
            0.0,
            1e5,
            false,
            "[0, 1e5] e-",
        )?;
        f(
            "sensor.dsnu_column_electrons",
            self.dsnu_column_electrons,
            0.0,
            1e5,
            false,
            "[0, 1e5] e-",
        )?;
        f(
            "sensor.dsnu_row_electrons",
            self.dsnu_row_electrons,
            0.0,
            1e5,
            false,
            "[0, 1e5] e-",
        )?;
        f(
            "sensor.prnu_percent",
            self.prnu_percent,
            0.0,
            50.0,
            false,
            "[0, 50] %",
        )?;
        f(
            "sensor.dark_current_electrons_per_s",
            self.dark_current_electrons_per_s,
            0.0,
            1e7,
            false,
            "[0, 1e7] e-/s",
        )?;
        f(
            "sensor.wavelength_nm",
            self.wavelength_nm,
            200.0,
            2000.0,
            false,
            "[200, 2000] nm",
        )?;
        Ok(())
    }
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            width: 1224,
            height: 1025,
            pixel_um: 6.9,
            focal_mm: 25.0,
            working_distance_mm: 90.0,
            view: "A20".into(),
            exposure: 1.0,
            gain: 1.0,
            look_at: None,
            matrix: None,
            opencv: None,
            calibration: None,
            intrinsics: None,
            f_number: None,
            focus_distance_mm: None,
        }
    }
}

impl CameraConfig {
    /// Reads `calibration` (if given and not yet read) into `intrinsics`; the file's
    /// image size becomes `width` x `height` and `focal_mm` becomes fx times the pixel
    /// pitch. `text` is the TOML the section came from: writing `width`, `height` or
    /// `focal_mm` next to `calibration` is an error (the file sets them).
    pub fn load_calibration(&mut self, text: &str) -> Result<(), ConfigError> {
        let Some(path) = &self.calibration else {
            return Ok(());
        };
        if self.intrinsics.is_some() {
            return Ok(());
        }
        let table: toml::Table = toml::from_str(text).unwrap_or_default();
        let written = |k: &str| table.get("camera").and_then(|c| c.get(k)).is_some();
        for (k, field) in [
            ("width", "camera.width"),
            ("height", "camera.height"),
            ("focal_mm", "camera.focal_mm"),
        ] {
            if written(k) {
                return Err(ConfigError::Invalid {
                    field,
                    message: format!(
                        "given together with `camera.calibration` ({}), which sets it (image_width, image_height, camera_matrix); remove `{k}` or the calibration",
                        path.display()
                    ),
                });
            }
        }
        let k = crate::scene::calibration::Intrinsics::load(path)?;
        pixel_count(
            "camera.calibration (image_width x image_height)",
            k.width,
            k.height,
        )?;
        self.width = k.width;
        self.height = k.height;
        self.focal_mm = (k.fx * self.pixel_um as f64 * 1e-3) as f32;
        self.intrinsics = Some(k);
        Ok(())
    }
}

/// Sampling settings.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Samples per pixel, [1, 1048576].
    pub spp: u32,
    /// Maximum number of scattering events per path, [1, 64] (1 = direct light only).
    pub max_bounces: u32,
    /// Random seed (any u32).
    pub seed: u32,
    /// Samples per pixel per dispatch, [1, 1024].
    pub batch_spp: u32,
    /// Trace backend: "auto", "ray-query", "software" (BVH2), "software-wide" (CWBVH).
    pub accel: AccelChoice,
    /// Random numbers: "sobol" (Owen-scrambled, low discrepancy) or "independent".
    pub sampler: SamplerKind,
    /// Slope-map filtering: "none" (point samples of the map) or "lean" (the slope
    /// distribution under the pixel's footprint folded into the GGX roughness;
    /// docs/rendering.md, "Filtered slope maps").
    pub texture_filter: TextureFilter,
    /// Footprint multiplier of "lean" (the mip level is log2 of the footprint in texels
    /// times this), [0.25, 4].
    pub texture_filter_scale: f32,
    /// Stop adding samples once the render noise is at most this fraction of the
    /// camera's own temporal noise (`[sensor]` needed), [0.01, 100]; `spp` is then the
    /// maximum. None: exactly `spp`. docs/dataset.md, "Samples chosen from a noise
    /// target" (src/render/noise.rs).
    pub noise_target: Option<f32>,
    /// Samples before the first noise check (with `noise_target`), [2, spp]; default 64
    /// (or `spp` when smaller).
    pub min_spp: Option<u32>,
    /// How the noise check estimates a pixel's render noise (with `noise_target`):
    /// "halves" (default) or "samples" ([`NoiseEstimator`]).
    pub noise_estimate: Option<NoiseEstimator>,
    /// Samples per pixel by the pixel's own noise (with `noise_target`), [0, 16]: after
    /// each check the pixels that have their share of the target stop, each pixel's
    /// variance taken as the mean over the (2 r + 1)^2 pixels around it. None: every
    /// pixel takes the same samples. docs/dataset.md, "Samples per pixel".
    pub adaptive_radius: Option<u32>,
    /// How the target grows with an image's mean samples (with `noise_target`), [0, 1]:
    /// the image stops at `noise_target` (mean spp / min_spp)^growth. None or 0: a fixed
    /// target; 0.5: the samples that minimise a set of images' pooled error
    /// (docs/dataset.md, "Samples chosen from a noise target").
    pub noise_target_growth: Option<f32>,
    /// Where the labels (class, instance, face, coverage) come from: "auto" (default),
    /// "pass" (the annotation pass) or "samples" (the path tracer's own first n x n
    /// camera samples); [`LabelSource`].
    pub labels: LabelSource,
    /// The direct light's estimator: "analytic" (default: next-event estimation and BSDF
    /// sampling combined by MIS, plus the ring lights' analytic control variate at the
    /// primary hit) or "sampled" (without it; [`DirectLight`]).
    pub direct_light: DirectLight,
    /// With "analytic": camera rays per sample whose primary hit adds the control
    /// variate's closed form (the sample's own and `analytic_rays - 1` more, which trace
    /// no further), [1, 64]; more of them average the sub-pixel texture's variation of the
    /// direct light (docs/rendering.md, "Analytic direct light").
    pub analytic_rays: u32,
    /// With `noise_target` and "analytic": at the first noise check the render chooses
    /// its camera rays per sample for the closed form for the samples after it, between 1
    /// and this, [analytic_rays, 64], from the variances its first samples measured
    /// (`render::noise::RayChoice`; docs/dataset.md, "The extra rays chosen per image");
    /// `analytic_rays` (at least 2) is then the first samples' count. None:
    /// `analytic_rays` throughout (as a dataset job's `[render] analytic_rays_max`).
    pub analytic_rays_max: Option<u32>,
    /// With `analytic_rays_max`: one extra ray's cost over the rest of a sample's, the
    /// choice's k, (0, 10]; default `render::noise::DEFAULT_ANALYTIC_RAY_COST`.
    pub analytic_ray_cost: Option<f32>,
    /// Light samples (each with its shadow ray) at the camera ray's first hit, [1, 64];
    /// deeper vertices take one. More of them lower the noise of shadows and of the
    /// light's sampled part where a pixel sees a partly shadowed light (docs/rendering.md,
    /// "More light and BSDF samples at the first hit").
    pub light_samples: u32,
    /// BSDF samples for the direct light at the camera ray's first hit, [1, 64] (the
    /// path's own direction and `bsdf_samples - 1` more, each traced to the light it
    /// meets; only the path's own goes on). More of them lower the noise of a glossy
    /// reflection of a partly hidden light (docs/rendering.md, "More light and BSDF
    /// samples at the first hit").
    pub bsdf_samples: u32,
    /// Each of those `bsdf_samples` directions continues as a path of its own, a branch
    /// of weight 1 / `bsdf_samples` (default false: only the path's own goes on, the
    /// others end at the light they meet). Lowers the noise of the light that reaches
    /// the first hit after a bounce, as where a face mirrors the part's own metal, at
    /// the cost of the branches' paths (docs/rendering.md, "Split paths at the first
    /// hit"). Needs `bsdf_samples` >= 2.
    pub split_paths: bool,
    /// Rays that need no traversal of the lights skip it (default true): a light
    /// sample's shadow ray toward a light triangle no other can hide tests that triangle
    /// alone (src/scene/light_cover.rs), and a ray that can meet no light is traced
    /// through the object alone or, for the direct light's extra BSDF directions, not at
    /// all (glsl/common/lights.glsl `misses_lights`). The same images; false traverses
    /// the lights for every ray (for comparison).
    pub light_shortcuts: bool,
    /// The path tracer's pipeline compiled for this render's settings (default false):
    /// the sampler, the direct light's estimator and its ray and sample counts, the
    /// bounces, the noise sums, the texture filter, the lights' counts and the shortcuts
    /// become specialization constants (src/gpu_interface.in `gpu_specs!`), so the
    /// driver drops the code they switch off and folds the loops' counts. The same
    /// images; each distinct setting is a pipeline of its own (compiled at its first use,
    /// on lavapipe then kept by the driver's shader cache). On lavapipe it measured 0.96
    /// of the path tracing's time with Mitsuba's sampling (sets from 0.91 to 1.00) and no
    /// gain on the paper job (docs/benchmarks/rendering.md, "The path tracer compiled for
    /// a render's settings"); it is for GPUs, where the code a kernel holds sets its
    /// registers, unmeasured there. Not given: false, or what `SYNOSIS_SPECIALIZE` says
    /// (`render::settings::specialize_from_env`: a whole process, a dataset job included).
    pub specialize: Option<bool>,
}

/// `[render] light_samples` and `bsdf_samples` when not given (scene files and jobs).
pub const DEFAULT_LIGHT_SAMPLES: u32 = 1;

/// `[render] batch_spp` when not given (scene files and jobs).
pub const DEFAULT_BATCH_SPP: u32 = 16;

/// `[render] analytic_rays` when not given (scene files and jobs): the sample's own ray.
pub const DEFAULT_ANALYTIC_RAYS: u32 = 1;

/// The direct light's estimator (`[render] direct_light`; docs/rendering.md, "Analytic
/// direct light").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DirectLight {
    /// Next-event estimation and BSDF sampling combined by MIS: the renderer before issue
    /// 15's control variate (the default until then).
    Sampled = 0,
    /// The same estimate plus a control variate at the primary hit of a conductor: a
    /// linearly transformed cosine shaped after the GGX lobe, integrated in closed form
    /// over each ring light's tessellated torus, minus the same lobe estimated with the
    /// very samples of the light (unbiased: its expectation is the closed form).
    #[default]
    Analytic = 1,
}

/// How `[render] noise_target` estimates the variance of a pixel's mean
/// (`[render] noise_estimate`; src/render/noise.rs, docs/dataset.md "Samples chosen from a
/// noise target").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseEstimator {
    /// From the two halves of the largest aligned power-of-two block of samples done:
    /// sees the sampler's stratification (Sobol), conservative.
    #[default]
    Halves,
    /// From the spread of single samples, as if independent (the estimate before
    /// 2026-11-24): conservative by the stratification it does not see.
    Samples,
}

/// Where a render's labels come from (`[render] labels`; docs/scene-format.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LabelSource {
    /// "samples" under a thin lens, where they are the very rays the pass traces (labels
    /// byte-identical, one trace fewer per ray); "pass" under a pinhole, whose centre ray
    /// and stratified grid are not the path tracer's jittered samples.
    #[default]
    Auto,
    /// The annotation pass (glsl/annotate.comp): a second trace of n x n + 1 rays per
    /// pixel (pinhole: centre ray + stratified grid; thin lens: the path tracer's first
    /// n x n primary rays, traced again).
    Pass,
    /// The path tracer's first n x n samples of each pixel: the label word of each
    /// primary hit, resolved as the pass resolves its thin-lens rays (majority word, ties
    /// to the earliest sample; coverage = share hitting a defect). Where the first batch
    /// holds fewer than n x n samples (`min(batch_spp, spp) < n^2`), the path tracer's
    /// first batch traces the rest of them for their labels alone (camera ray and first
    /// hit, no shading), still in place of the pass.
    Samples,
}

impl LabelSource {
    /// Whether a render labels from its samples (a thin lens or not) rather than the
    /// annotation pass.
    pub fn from_samples(self, thin_lens: bool) -> bool {
        match self {
            LabelSource::Pass => false,
            LabelSource::Samples => true,
            LabelSource::Auto => thin_lens,
        }
    }
}

/// How the path tracer reads slope maps (`[render] texture_filter`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TextureFilter {
    /// Point samples of the level-0 map (bilinear), the renderer before this option.
    #[default]
    None = 0,
    /// LEAN mapping (Olano and Baker 2010): a pyramid of slope moments looked up at the
    /// primary hit's pixel footprint; mean slope -> shading normal, slope variance ->
    /// widened GGX alpha (isotropic).
    Lean = 1,
}

/// Which sample generator the path tracer uses (ids match glsl/common/sampler.glsl).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SamplerKind {
    /// PCG hash per (pixel, sample, seed, dimension): plain Monte Carlo.
    Independent = 0,
    /// Owen-scrambled Sobol, padded per 1D/2D request (Burley 2020).
    #[default]
    Sobol = 1,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            spp: 64,
            max_bounces: 8,
            seed: 0,
            batch_spp: DEFAULT_BATCH_SPP,
            accel: AccelChoice::Auto,
            sampler: SamplerKind::Sobol,
            texture_filter: TextureFilter::None,
            texture_filter_scale: 1.0,
            noise_target: None,
            min_spp: None,
            noise_estimate: None,
            adaptive_radius: None,
            noise_target_growth: None,
            labels: LabelSource::Auto,
            direct_light: DirectLight::Analytic,
            analytic_rays: DEFAULT_ANALYTIC_RAYS,
            analytic_rays_max: None,
            analytic_ray_cost: None,
            light_samples: DEFAULT_LIGHT_SAMPLES,
            bsdf_samples: DEFAULT_LIGHT_SAMPLES,
            split_paths: false,
            light_shortcuts: true,
            specialize: None,
        }
    }
}

/// Which triangles of the object a finish covers (`[texture] cover` in scene and job
/// files; docs/scene-format.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Cover {
    /// Every planar region of the object (default): each region gets a map, repeated
    /// beyond its edges, so no face has an untextured border.
    #[default]
    Part,
    /// Only the regions of the inspected faces A, B and C, each map clipped to its own
    /// extent (slopes zero outside: the mirror band of the renderer before issue 11).
    Faces,
}

/// What the finish does on the surfaces of dents and scratches (`[texture] defects` in
/// scene files, `[mapping] defects` in jobs; docs/texture.md, "Defect surfaces").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DefectSurface {
    /// The finish's slope map continues over the defect's triangles, in its region's
    /// plane (default; the renderer before this option).
    #[default]
    Textured,
    /// No slope map on defect triangles: the smooth surface of the denting or scratching
    /// tool (a polished, hard tip) with the object's material and roughness.
    Burnished,
}

/// One inspected face's own height map (`[[texture.map]]`, docs/scene-format.md).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaceMapFile {
    /// "A", "B" or "C".
    pub face: String,
    /// EXR height map in µm (one channel; `Y` if several), relative to the scene file.
    pub path: PathBuf,
    /// Its texel spacing, µm, [1, 1000]; default `texture.spacing_um`.
    #[serde(default)]
    pub spacing_um: Option<f32>,
}

impl FaceMapFile {
    /// The face id (1, 2 or 3), or the error naming entry `index`'s `face`.
    pub fn face_id(&self, index: usize) -> Result<crate::scene::mesh::FaceId, ConfigError> {
        crate::scene::mesh::face_from_name(&self.face)
            .filter(|f| (1..=3).contains(f))
            .ok_or_else(|| {
                let allowed = format!("{:?}: allowed \"A\", \"B\" or \"C\"", self.face);
                self.error(index, "face", allowed)
            })
    }

    /// The error naming `field` of this entry, `texture.map[index]`.
    pub fn error(&self, index: usize, field: &'static str, message: String) -> ConfigError {
        ConfigError::TextureMap {
            index,
            field,
            message,
        }
    }
}

/// Slope maps on the inspected faces (docs/scene-format.md, `[texture]`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TextureConfig {
    /// "flat" (no map: shading normal = geometric normal), "test-grooves" (analytic
    /// sinusoidal grooves on faces A, B and C, a test pattern) or "file" (`path`).
    pub kind: String,
    /// EXR height map in µm (one channel; `Y` if several), relative to the scene file;
    /// its slopes go on faces A, B and C (those without a `map` entry of their own).
    /// Kind = "file" needs it, or a `map` entry for each of A, B and C.
    pub path: Option<PathBuf>,
    /// `[[texture.map]]`: faces with a height map of their own (kind = "file").
    pub map: Vec<FaceMapFile>,
    /// Texel spacing of generated maps and of the `path` map, µm, [1, 1000].
    pub spacing_um: f32,
    /// Groove period, mm, (0, 100].
    pub groove_period_mm: f32,
    /// Steepest groove slope, degrees, [0, 85].
    pub groove_max_slope_deg: f32,
    /// Rotation of the map on faces A, B, C about the face normal, degrees, from the face's
    /// u axis towards v, [-360, 360].
    pub rotation_deg: [f32; 3],
    /// Map centre relative to the face centre along (u, v) on faces A, B, C, mm,
    /// [-1000, 1000] each.
    pub offset_mm: [[f32; 2]; 3],
    /// "part" (default): the map covers every planar region of the object, repeated
    /// beyond its edges; "faces": only faces A, B, C, clipped to the map.
    pub cover: Cover,
    /// "textured" (default) or "burnished": whether dents and scratches carry the map.
    pub defects: DefectSurface,
}

impl Default for TextureConfig {
    fn default() -> Self {
        TextureConfig {
            kind: "flat".into(),
            path: None,
            map: Vec::new(),
            spacing_um: 20.0,
            groove_period_mm: 1.0,
            groove_max_slope_deg: 30.0,
            rotation_deg: [0.0; 3],
            offset_mm: [[0.0; 2]; 3],
            cover: Default::default(),
            defects: Default::default(),
        }
    }
}

/// A parsed viewpoint: face id (1..=3), angle from the normal and azimuth about it,
/// degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub face: crate::scene::mesh::FaceId,
    pub angle_deg: f32,
    /// Direction of the tilt about the face normal, from the face's `u` towards `v`,
    /// degrees, [-360, 360]; 0 (the default, "A20") tilts towards `u`.
    pub azimuth_deg: f32,
}

/// Parses "A20", "B0", "C10" (face letter, then degrees in [0, 89]), optionally with an
/// azimuth: "A20@45" (degrees in [-360, 360]).
pub fn parse_view(s: &str) -> Result<View, ConfigError> {
    let bad = || ConfigError::Invalid {
        field: "camera.view",
        message: format!(
            "{s:?} is not a view: expected a face letter A, B or C and an angle in degrees [0, 89], e.g. \"A20\", optionally an azimuth in degrees [-360, 360] after '@', e.g. \"A20@45\""
        ),
    };
    let (s, azimuth_deg) = match s.split_once('@') {
        Some((v, az)) => {
            let az: f32 = az.parse().map_err(|_| bad())?;
            if !(az.is_finite() && (-360.0..=360.0).contains(&az)) {
                return Err(bad());
            }
            (v, az)
        }
        None => (s, 0.0),
    };
    let mut chars = s.chars();
    let face = match chars.next() {
        Some('A') | Some('a') => crate::scene::mesh::FACE_A,
        Some('B') | Some('b') => crate::scene::mesh::FACE_B,
        Some('C') | Some('c') => crate::scene::mesh::FACE_C,
        _ => return Err(bad()),
    };
    let angle: f32 = chars.as_str().parse().map_err(|_| bad())?;
    if !(0.0..=89.0).contains(&angle) {
        return Err(bad());
    }
    Ok(View {
        face,
        angle_deg: angle,
        azimuth_deg,
    })
}

fn range_f(
    field: &'static str,
    v: f32,
    lo: f32,
    hi: f32,
    lo_open: bool,
    range: &'static str,
) -> Result<(), ConfigError> {
    let ok = v.is_finite() && (if lo_open { v > lo } else { v >= lo }) && v <= hi;
    if ok {
        Ok(())
    } else {
        Err(ConfigError::Range {
            field,
            value: v.to_string(),
            range,
        })
    }
}

fn range_u(
    field: &'static str,
    v: u32,
    lo: u32,
    hi: u32,
    range: &'static str,
) -> Result<(), ConfigError> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(ConfigError::Range {
            field,
            value: v.to_string(),
            range,
        })
    }
}

/// The `[render]` fields of the noise target and of the extra rays' choice, as a scene
/// file and a dataset job both give them (integers as i64 and numbers as f64, as a job
/// reads them), checked by one set of rules ([`NoiseFields::check`]). What the noise
/// target needs of the camera (the EMVA 1288 sensor) each file checks itself: the two
/// say it differently.
#[derive(Clone, Debug, Default)]
pub struct NoiseFields {
    pub spp: i64,
    pub noise_target: Option<f64>,
    pub min_spp: Option<i64>,
    pub adaptive_radius: Option<i64>,
    pub noise_target_growth: Option<f64>,
    pub noise_estimate: Option<NoiseEstimator>,
    /// `analytic_rays` where given (the rules read 1 without).
    pub analytic_rays: Option<i64>,
    pub analytic_rays_max: Option<i64>,
    pub analytic_ray_cost: Option<f64>,
    /// `direct_light = "sampled"`.
    pub direct_light_sampled: bool,
}

/// A field that breaks [`NoiseFields`]' rules: its name, its value and what is allowed.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldRule {
    pub field: &'static str,
    pub value: String,
    pub allowed: String,
}

impl From<FieldRule> for ConfigError {
    fn from(r: FieldRule) -> Self {
        ConfigError::Rule(r)
    }
}

impl NoiseFields {
    /// Each field in its range, and every one that only works with another given with it.
    pub fn check(&self) -> Result<(), FieldRule> {
        fn broken(
            field: &'static str,
            value: impl ToString,
            allowed: &str,
        ) -> Result<(), FieldRule> {
            Err(FieldRule {
                field,
                value: value.to_string(),
                allowed: allowed.to_string(),
            })
        }
        let int = |field, v: i64, lo: i64, hi: i64| {
            int_in(v, lo, hi).or_else(|allowed| broken(field, v, &allowed))
        };
        let real = |field, v: f64, lo: f64, hi: f64| {
            real_in(v, lo, hi).or_else(|allowed| broken(field, v, &allowed))
        };
        let with_target = self.noise_target.is_some();
        if let Some(t) = self.noise_target {
            real("render.noise_target", t, 0.01, 100.0)?;
        }
        if let Some(m) = self.min_spp {
            if !with_target {
                return broken(
                    "render.min_spp",
                    m,
                    "is the first noise check of `render.noise_target`: give that too, or remove it",
                );
            }
            int("render.min_spp", m, 2, self.spp.max(2))?;
        }
        if let Some(a) = self.adaptive_radius {
            if !with_target {
                return broken(
                    "render.adaptive_radius",
                    a,
                    "stops each pixel by its share of `render.noise_target`: give that too, or remove it",
                );
            }
            int("render.adaptive_radius", a, 0, 16)?;
        }
        if let Some(g) = self.noise_target_growth {
            if !with_target {
                return broken(
                    "render.noise_target_growth",
                    g,
                    "is how `render.noise_target` grows with an image's samples: give that too, or remove it",
                );
            }
            real("render.noise_target_growth", g, 0.0, 1.0)?;
        }
        if let Some(e) = self.noise_estimate
            && !with_target
        {
            return broken(
                "render.noise_estimate",
                format!("{e:?}").to_lowercase(),
                "is how `render.noise_target` estimates the noise: give that too, or remove it",
            );
        }
        if let Some(n) = self.analytic_rays {
            int("render.analytic_rays", n, 1, 64)?;
        }
        if let Some(m) = self.analytic_rays_max {
            if !with_target {
                return broken(
                    "render.analytic_rays_max",
                    m,
                    "is chosen at the first check of `render.noise_target`: give that too, or remove it",
                );
            }
            if self.direct_light_sampled {
                return broken(
                    "render.analytic_rays_max",
                    m,
                    "takes the analytic direct light, which `render.direct_light = \"sampled\"` turns off: remove one of the two",
                );
            }
            let first = self.analytic_rays.unwrap_or(1);
            if first < 2 {
                return broken(
                    "render.analytic_rays",
                    first,
                    "must be in [2, 64] with `render.analytic_rays_max` (the first samples' rays measure their spread)",
                );
            }
            int("render.analytic_rays_max", m, first, 64)?;
        }
        if let Some(k) = self.analytic_ray_cost {
            if self.analytic_rays_max.is_none() {
                return broken(
                    "render.analytic_ray_cost",
                    k,
                    "is what `render.analytic_rays_max`'s choice takes: give that too, or remove it",
                );
            }
            if !(k > 0.0 && k <= 10.0) {
                return broken("render.analytic_ray_cost", k, "must be a number in (0, 10]");
            }
        }
        Ok(())
    }
}

/// Whether integer `v` lies in [lo, hi]; else what is allowed, in the words of
/// [`NoiseFields`]' rules and of dataset jobs' ranges.
pub fn int_in(v: i64, lo: i64, hi: i64) -> Result<(), String> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(format!("must be an integer in [{lo}, {hi}]"))
    }
}

/// Whether `v` is a finite number in [lo, hi]; else what is allowed (as [`int_in`]).
pub fn real_in(v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(format!("must be a number in [{lo}, {hi}]"))
    }
}

/// A scene file's f32 as the f64 its text gave (0.01 stays 0.01, where `as f64` would
/// give 0.009999999776), so that [`NoiseFields`]' bounds and messages read it as written.
fn as_written(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(f64::NAN)
}

/// The image must fit one storage buffer on every Vulkan device
/// (`gpu_interface::MAX_IMAGE_PIXELS`, 33,554,432 pixels, e.g. 8192 x 4096).
pub fn pixel_count(field: &'static str, width: u32, height: u32) -> Result<(), ConfigError> {
    let max = crate::gpu_interface::MAX_IMAGE_PIXELS as u64;
    let n = width as u64 * height as u64;
    if n > max {
        return Err(ConfigError::Invalid {
            field,
            message: format!(
                "{width} x {height} = {n} pixels; allowed at most {max} (one f32 per pixel must fit the 128 MiB storage-buffer range every Vulkan device has)"
            ),
        });
    }
    Ok(())
}

impl SceneConfig {
    /// Reads and validates a scene file; a relative glTF path becomes relative to it.
    pub fn load(path: &Path) -> Result<SceneConfig, ConfigError> {
        let text = crate::limits::read_text(path).map_err(|source| ConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut cfg = Self::parse(&text).map_err(|e| match e {
            ConfigError::Parse { message, .. } => ConfigError::Parse {
                path: path.to_path_buf(),
                message,
            },
            other => other,
        })?;
        if let Some(g) = &cfg.object.gltf
            && g.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            cfg.object.gltf = Some(base.join(g));
        }
        if let Some(g) = &cfg.object.path
            && g.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            cfg.object.path = Some(base.join(g));
        }
        if let Some(t) = &cfg.texture.path
            && t.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            cfg.texture.path = Some(base.join(t));
        }
        for m in &mut cfg.texture.map {
            if m.path.is_relative() {
                let base = path.parent().unwrap_or(Path::new("."));
                m.path = base.join(&m.path);
            }
        }
        if let Some(c) = &cfg.camera.calibration
            && c.is_relative()
        {
            let base = path.parent().unwrap_or(Path::new("."));
            cfg.camera.calibration = Some(base.join(c));
        }
        cfg.camera.load_calibration(&text)?;
        Ok(cfg)
    }

    /// Parses and validates TOML text.
    pub fn parse(text: &str) -> Result<SceneConfig, ConfigError> {
        let cfg: SceneConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: PathBuf::from("<text>"),
            message: e.to_string(),
        })?;
        // `view` has a default, so whether it was written is read from the text.
        let view_written = toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|t| t.get("camera").and_then(|c| c.get("view")).map(|_| ()))
            .is_some();
        let free = cfg.camera.free_pose_fields();
        if view_written && !free.is_empty() {
            return Err(ConfigError::Invalid {
                field: "camera",
                message: format!(
                    "camera.view and {} given; give exactly one of camera.view, camera.look_at, camera.matrix, camera.opencv",
                    free.join(" and ")
                ),
            });
        }
        cfg.validate()?;
        Ok(cfg)
    }

    /// The camera's wavelength, nm: `sensor.wavelength_nm`, else 550.
    pub fn wavelength_nm(&self) -> f64 {
        self.sensor.as_ref().map_or(550.0, |s| s.wavelength_nm)
    }

    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let o = &self.object;
        if let (Some(g), Some(p)) = (&o.gltf, &o.path) {
            return Err(ConfigError::Invalid {
                field: "object.path / object.gltf",
                message: format!(
                    "both given ({} and {}); give one (`gltf` is the old name of `path`)",
                    p.display(),
                    g.display()
                ),
            });
        }
        if let Some(p) = o.path.as_ref().or(o.gltf.as_ref()) {
            let field = if o.path.is_some() {
                "object.path"
            } else {
                "object.gltf"
            };
            crate::scene::mesh_io::MeshFormat::of(p).map_err(|e| ConfigError::Invalid {
                field,
                message: e.to_string(),
            })?;
        }
        if let Some(list) = &o.inspect {
            crate::scene::inspect::parse(list)?;
        }
        match (o.path.as_ref().or(o.gltf.as_ref()), &o.builtin) {
            (Some(_), Some(_)) => {
                // `builtin` has a default, so only complain when both were written; the
                // loader clears the default when gltf is given (see `effective_builtin`).
            }
            (None, Some(b)) if b != "testbody-b" && b != "testbody-m" => {
                return Err(ConfigError::Invalid {
                    field: "object.builtin",
                    message: format!("{b:?}: allowed \"testbody-b\" or \"testbody-m\""),
                });
            }
            (None, None) => {
                return Err(ConfigError::Invalid {
                    field: "object",
                    message: "needs `path` (a mesh file) or `builtin`".into(),
                });
            }
            _ => {}
        }
        for (i, field) in [
            "object.position_mm[0]",
            "object.position_mm[1]",
            "object.position_mm[2]",
        ]
        .into_iter()
        .enumerate()
        {
            range_f(field, o.position_mm[i], -1e6, 1e6, false, "[-1e6, 1e6] mm")?;
        }
        let m = &self.material;
        if let Some(r) = m.roughness {
            range_f(
                "material.roughness",
                r,
                0.0,
                1.0,
                true,
                "(0, 1] (alpha = r^2)",
            )?;
        }
        range_f("material.alpha", m.alpha, 0.0, 1.0, true, "(0, 1]")?;
        range_f("material.ior_n", m.ior_n, 0.0, 10.0, true, "(0, 10]")?;
        range_f("material.ior_k", m.ior_k, 0.0, 20.0, false, "[0, 20]")?;
        crate::scene::materials::resolve(&m.region, m, self.wavelength_nm())?;
        let t = &self.table;
        range_f("table.albedo", t.albedo, 0.0, 1.0, false, "[0, 1]")?;
        range_f(
            "table.size_mm",
            t.size_mm,
            1.0,
            1e5,
            false,
            "[1, 100000] mm",
        )?;
        let l = &self.light;
        range_f(
            "light.major_radius_mm",
            l.major_radius_mm,
            0.0,
            1e4,
            true,
            "(0, 10000] mm",
        )?;
        range_f("light.radiance", l.radiance, 0.0, 1e6, false, "[0, 1e6]")?;
        if !(l.minor_radius_mm.is_finite()
            && l.minor_radius_mm > 0.0
            && l.minor_radius_mm < l.major_radius_mm)
        {
            return Err(ConfigError::Range {
                field: "light.minor_radius_mm",
                value: l.minor_radius_mm.to_string(),
                range: "(0, light.major_radius_mm) mm",
            });
        }
        range_u(
            "light.segments_major",
            l.segments_major,
            8,
            1024,
            "[8, 1024]",
        )?;
        range_u("light.segments_minor", l.segments_minor, 4, 256, "[4, 256]")?;
        l.specs()?;
        let c = &self.camera;
        range_u("camera.width", c.width, 1, 16384, "[1, 16384]")?;
        range_u("camera.height", c.height, 1, 16384, "[1, 16384]")?;
        pixel_count("camera.width x camera.height", c.width, c.height)?;
        range_f(
            "camera.pixel_um",
            c.pixel_um,
            0.0,
            1000.0,
            true,
            "(0, 1000] µm",
        )?;
        range_f(
            "camera.focal_mm",
            c.focal_mm,
            0.0,
            1e4,
            true,
            "(0, 10000] mm",
        )?;
        range_f(
            "camera.working_distance_mm",
            c.working_distance_mm,
            0.0,
            1e5,
            true,
            "(0, 100000] mm",
        )?;
        range_f("camera.exposure", c.exposure, 0.0, 1e9, true, "(0, 1e9]")?;
        range_f("camera.gain", c.gain, 0.0, 1e6, true, "(0, 1e6]")?;
        parse_view(&c.view)?;
        c.pose()?;
        if let Some(n) = c.f_number
            && !(n.is_finite() && (0.5..=1000.0).contains(&n))
        {
            return Err(ConfigError::Range {
                field: "camera.f_number",
                value: n.to_string(),
                range: "[0.5, 1000] or \"inf\" (pinhole)",
            });
        }
        if let Some(f) = c.focus_distance_mm {
            range_f(
                "camera.focus_distance_mm",
                f,
                0.0,
                1e5,
                true,
                "(0, 100000] mm",
            )?;
        }
        if let Some(s) = &self.sensor {
            s.validate()?;
            if c.f_number.is_none() {
                return Err(ConfigError::Invalid {
                    field: "camera.f_number",
                    message: "the [sensor] model needs the lens's working f-number for the image-plane irradiance (E = pi L cos^4 / (4 N^2)); give e.g. f_number = 8.0".into(),
                });
            }
        }
        let r = &self.render;
        range_u("render.spp", r.spp, 1, 1 << 20, "[1, 1048576]")?;
        range_u("render.max_bounces", r.max_bounces, 1, 64, "[1, 64]")?;
        range_u("render.batch_spp", r.batch_spp, 1, 1024, "[1, 1024]")?;
        range_f(
            "render.texture_filter_scale",
            r.texture_filter_scale,
            0.25,
            4.0,
            false,
            "[0.25, 4]",
        )?;
        NoiseFields {
            spp: r.spp as i64,
            noise_target: r.noise_target.map(as_written),
            min_spp: r.min_spp.map(i64::from),
            adaptive_radius: r.adaptive_radius.map(i64::from),
            noise_target_growth: r.noise_target_growth.map(as_written),
            noise_estimate: r.noise_estimate,
            analytic_rays: Some(r.analytic_rays as i64),
            analytic_rays_max: r.analytic_rays_max.map(i64::from),
            analytic_ray_cost: r.analytic_ray_cost.map(as_written),
            direct_light_sampled: r.direct_light == DirectLight::Sampled,
        }
        .check()
        .map_err(ConfigError::from)?;
        if r.noise_target.is_some() && self.sensor.is_none() {
            return Err(ConfigError::Invalid {
                field: "render.noise_target",
                message: "needs a [sensor] section (the EMVA 1288 camera): the target is the render noise over the camera's own noise, and the linear exposure model has none".into(),
            });
        }
        range_u("render.light_samples", r.light_samples, 1, 64, "[1, 64]")?;
        range_u("render.bsdf_samples", r.bsdf_samples, 1, 64, "[1, 64]")?;
        if r.split_paths && r.bsdf_samples < 2 {
            return Err(ConfigError::Range {
                field: "render.bsdf_samples",
                value: r.bsdf_samples.to_string(),
                range: "[2, 64] with render.split_paths (the branches are its directions)",
            });
        }
        let t = &self.texture;
        if !["flat", "test-grooves", "file"].contains(&t.kind.as_str()) {
            return Err(ConfigError::Invalid {
                field: "texture.kind",
                message: format!(
                    "{:?}: allowed \"flat\", \"test-grooves\" or \"file\"",
                    t.kind
                ),
            });
        }
        if t.kind == "file" && t.path.is_none() && t.map.is_empty() {
            return Err(ConfigError::Invalid {
                field: "texture.path",
                message: "kind = \"file\" needs `path` (an EXR height map in µm) or a `[[texture.map]]` entry for each of faces A, B and C".into(),
            });
        }
        if t.kind != "file" && !t.map.is_empty() {
            return Err(ConfigError::Invalid {
                field: "texture.map",
                message: format!("maps of their own need kind = \"file\", not {:?}", t.kind),
            });
        }
        let mut seen = Vec::new();
        for (index, m) in t.map.iter().enumerate() {
            let bad = |field, message| m.error(index, field, message);
            let face = m.face_id(index)?;
            if seen.contains(&face) {
                return Err(bad(
                    "face",
                    format!("face {} has two entries; one map a face", m.face),
                ));
            }
            seen.push(face);
            if let Some(s) = m.spacing_um
                && !(s.is_finite() && (1.0..=1000.0).contains(&s))
            {
                return Err(bad(
                    "spacing_um",
                    format!("{s} is out of range: allowed [1, 1000] µm"),
                ));
            }
        }
        if t.kind == "file" && t.path.is_none() {
            for name in ["A", "B", "C"] {
                if !t.map.iter().any(|m| m.face == name) {
                    return Err(ConfigError::Invalid {
                        field: "texture.map",
                        message: format!(
                            "face {name} has no map: give it a `[[texture.map]]` entry, or give `path`, the map of the faces without one"
                        ),
                    });
                }
            }
        }
        range_f(
            "texture.spacing_um",
            t.spacing_um,
            1.0,
            1000.0,
            false,
            "[1, 1000] µm",
        )?;
        range_f(
            "texture.groove_period_mm",
            t.groove_period_mm,
            0.0,
            100.0,
            true,
            "(0, 100] mm",
        )?;
        range_f(
            "texture.groove_max_slope_deg",
            t.groove_max_slope_deg,
            0.0,
            85.0,
            false,
            "[0, 85] degrees",
        )?;
        for r in t.rotation_deg {
            range_f(
                "texture.rotation_deg",
                r,
                -360.0,
                360.0,
                false,
                "[-360, 360] degrees",
            )?;
        }
        for o in t.offset_mm.iter().flatten() {
            range_f(
                "texture.offset_mm",
                *o,
                -1000.0,
                1000.0,
                false,
                "[-1000, 1000] mm",
            )?;
        }
        Ok(())
    }

    /// The built-in body to use, if any: `path` (or `gltf`) wins over the default
    /// `builtin`.
    pub fn effective_builtin(&self) -> Option<&str> {
        if self.object.gltf.is_some() || self.object.path.is_some() {
            None
        } else {
            self.object.builtin.as_deref()
        }
    }

    /// Changes the resolution keeping the sensor's physical size (the field of view):
    /// the pixel pitch scales with the width ratio.
    pub fn set_resolution(&mut self, width: u32, height: u32) -> Result<(), ConfigError> {
        range_u("--width", width, 1, 16384, "[1, 16384]")?;
        range_u("--height", height, 1, 16384, "[1, 16384]")?;
        pixel_count("--width x --height", width, height)?;
        // The sensor keeps its size, so the pixel pitch follows the width; the pitch's
        // own limit (1000 µm) is reported as a limit on the width the user gave.
        let sensor_um = self.camera.pixel_um * self.camera.width as f32;
        let min_width = (sensor_um / 1000.0).ceil().max(1.0) as u32;
        if width < min_width {
            return Err(ConfigError::Invalid {
                field: "--width",
                message: format!(
                    "{width}: the sensor ({:.1} mm wide) would need pixels over 1000 µm; allowed [{min_width}, 16384]",
                    sensor_um / 1000.0
                ),
            });
        }
        self.camera.pixel_um = sensor_um / width as f32;
        self.camera.width = width;
        self.camera.height = height;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_estimate_needs_a_noise_target() {
        // A noise target needs the EMVA sensor, and so the lens's f-number.
        let with_target = |estimate: &str| {
            SceneConfig::parse(&format!(
                "[render]\nnoise_target = 2.0\nnoise_estimate = \"{estimate}\"\n[camera]\nf_number = 8.0\n[sensor]\n"
            ))
        };
        let c = with_target("samples").expect("samples");
        assert_eq!(c.render.noise_estimate, Some(NoiseEstimator::Samples));
        assert_eq!(NoiseEstimator::default(), NoiseEstimator::Halves);
        let e = SceneConfig::parse("[render]\nnoise_estimate = \"halves\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("render.noise_estimate") && e.contains("noise_target"),
            "{e}"
        );
        let e = with_target("pairs").unwrap_err().to_string();
        assert!(e.contains("halves") && e.contains("samples"), "{e}");
        // `adaptive_radius` likewise, within [0, 16].
        let adaptive = |r: i32, target: &str| {
            SceneConfig::parse(&format!(
                "[render]\n{target}adaptive_radius = {r}\n[camera]\nf_number = 8.0\n[sensor]\n"
            ))
        };
        let target = "noise_target = 2.0\n";
        assert_eq!(adaptive(4, target).unwrap().render.adaptive_radius, Some(4));
        for (r, t) in [(17, target), (4, "")] {
            let e = adaptive(r, t).unwrap_err().to_string();
            assert!(e.contains("render.adaptive_radius"), "{e}");
        }
        // `noise_target_growth` likewise, within [0, 1].
        let growth = |g: f32, target: &str| {
            SceneConfig::parse(&format!(
                "[render]\n{target}noise_target_growth = {g}\n[camera]\nf_number = 8.0\n[sensor]\n"
            ))
        };
        assert_eq!(
            growth(0.5, target).unwrap().render.noise_target_growth,
            Some(0.5)
        );
        for (g, t) in [(1.5, target), (-0.1, target), (0.5, "")] {
            let e = growth(g, t).unwrap_err().to_string();
            assert!(e.contains("render.noise_target_growth"), "{e}");
        }
    }

    #[test]
    fn analytic_rays_max_needs_a_target_the_analytic_light_and_two_first_rays() {
        let parse = |render: &str| {
            SceneConfig::parse(&format!(
                "[render]\n{render}[camera]\nf_number = 8.0\n[sensor]\n"
            ))
        };
        let ok = "noise_target = 9.0\nanalytic_rays = 32\nanalytic_rays_max = 64\n";
        let c = parse(ok).expect("the recommended setting");
        assert_eq!(
            (c.render.analytic_rays_max, c.render.analytic_ray_cost),
            (Some(64), None)
        );
        let c = parse(&format!("{ok}analytic_ray_cost = 0.05\n")).expect("a cost");
        assert_eq!(c.render.analytic_ray_cost, Some(0.05));
        // Each bad setting names its field (and the allowed range where one is meant).
        for (render, field, says) in [
            (
                "analytic_rays = 32\nanalytic_rays_max = 64\n",
                "render.analytic_rays_max",
                "noise_target",
            ),
            (
                "noise_target = 9.0\nanalytic_rays = 32\nanalytic_rays_max = 64\ndirect_light = \"sampled\"\n",
                "render.analytic_rays_max",
                "analytic direct light",
            ),
            (
                "noise_target = 9.0\nanalytic_rays_max = 64\n",
                "render.analytic_rays",
                "[2, 64]",
            ),
            (
                "noise_target = 9.0\nanalytic_rays = 32\nanalytic_rays_max = 16\n",
                "render.analytic_rays_max",
                "[32, 64]",
            ),
            (
                "noise_target = 9.0\nanalytic_rays = 32\nanalytic_rays_max = 65\n",
                "render.analytic_rays_max",
                "[32, 64]",
            ),
            (
                "noise_target = 9.0\nanalytic_ray_cost = 0.05\n",
                "render.analytic_ray_cost",
                "analytic_rays_max",
            ),
            (
                &format!("{ok}analytic_ray_cost = 0.0\n"),
                "render.analytic_ray_cost",
                "(0, 10]",
            ),
            (
                &format!("{ok}analytic_ray_cost = 11.0\n"),
                "render.analytic_ray_cost",
                "(0, 10]",
            ),
        ] {
            let e = parse(render).unwrap_err().to_string();
            assert!(e.contains(field) && e.contains(says), "{render}: {e}");
        }
    }

    #[test]
    fn texture_filter_parses_and_checks_its_scale() {
        let c = SceneConfig::parse("").expect("defaults");
        assert_eq!(c.render.texture_filter, TextureFilter::None);
        let c =
            SceneConfig::parse("[render]\ntexture_filter = \"lean\"\ntexture_filter_scale = 0.5\n")
                .expect("lean");
        assert_eq!(
            (c.render.texture_filter, c.render.texture_filter_scale),
            (TextureFilter::Lean, 0.5)
        );
        let e = SceneConfig::parse("[render]\ntexture_filter_scale = 8.0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("render.texture_filter_scale") && e.contains("[0.25, 4]"),
            "{e}"
        );
        assert!(SceneConfig::parse("[render]\ntexture_filter = \"mip\"\n").is_err());
    }

    #[test]
    fn defaults_are_valid() {
        let c = SceneConfig::parse("").expect("defaults");
        assert_eq!(c.camera.width, 1224);
        assert_eq!(c.render.max_bounces, 8);
    }

    #[test]
    fn errors_name_field_and_range() {
        let e = SceneConfig::parse("[material]\nalpha = 0.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("material.alpha") && e.contains("(0, 1]"), "{e}");
        let e = SceneConfig::parse("[light]\nminor_radius_mm = 40.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("light.minor_radius_mm"), "{e}");
        let e = SceneConfig::parse("[camera]\nview = \"D10\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("camera.view"), "{e}");
        let e = SceneConfig::parse("[camera]\nfov = 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("fov"), "{e}");
    }

    #[test]
    fn roughness_or_alpha() {
        let c = SceneConfig::parse("[material]\nroughness = 0.3\n").expect("roughness");
        assert!((c.material.alpha - 0.09).abs() < 1e-7);
        assert_eq!(c.material.roughness, Some(0.3));
        let c = SceneConfig::parse("[material]\nalpha = 0.3\n").expect("alpha");
        assert_eq!(c.material.alpha, 0.3);
        assert_eq!(c.material.roughness, None);
        let c = SceneConfig::parse("[material]\nior_k = 5.0\n").expect("neither");
        assert_eq!(c.material.alpha, MaterialConfig::default().alpha);
        let e = SceneConfig::parse("[material]\nalpha = 0.1\nroughness = 0.3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`alpha`") && e.contains("`roughness`"), "{e}");
        let e = SceneConfig::parse("[material]\nroughness = 1.5\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("material.roughness") && e.contains("(0, 1]"),
            "{e}"
        );
        let e = SceneConfig::parse("[material]\nshine = 1.5\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("shine"), "{e}");
    }

    #[test]
    fn calibration_file_sets_the_intrinsics() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("cam.yaml"),
            "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 2000., 0., 330., 0., 2010., 235., 0., 0., 1. ]\n",
        )
        .unwrap();
        let scene = dir.path().join("s.toml");
        std::fs::write(
            &scene,
            "[camera]\ncalibration = \"cam.yaml\"\npixel_um = 5.0\n",
        )
        .unwrap();
        let c = SceneConfig::load(&scene).expect("load");
        assert_eq!((c.camera.width, c.camera.height), (640, 480));
        assert_eq!(c.camera.focal_mm, 10.0);
        assert_eq!(c.camera.intrinsics.unwrap().cx, 330.0);
        std::fs::write(
            &scene,
            "[camera]\ncalibration = \"cam.yaml\"\nwidth = 1000\n",
        )
        .unwrap();
        let e = SceneConfig::load(&scene).unwrap_err().to_string();
        assert!(
            e.contains("camera.width") && e.contains("calibration"),
            "{e}"
        );
        std::fs::write(&scene, "[camera]\ncalibration = \"missing.yaml\"\n").unwrap();
        let e = SceneConfig::load(&scene).unwrap_err().to_string();
        assert!(e.contains("missing.yaml"), "{e}");
    }

    #[test]
    fn lens_and_sensor_fields_parse_and_check() {
        let c = SceneConfig::parse("[camera]\nf_number = \"inf\"\n").unwrap();
        assert_eq!(c.camera.f_number, None);
        assert!(c.sensor.is_none());
        let c = SceneConfig::parse(
            "[camera]\nf_number = 8.0\nfocus_distance_mm = 80.0\n[sensor]\nexposure = { ms = 2.5 }\nbit_depth = 12\nblooming = \"vertical\"\n",
        )
        .unwrap();
        assert_eq!(c.camera.f_number, Some(8.0));
        let s = c.sensor.unwrap();
        assert_eq!(s.exposure, ExposureSetting::Fixed { ms: 2.5 });
        assert_eq!((s.bit_depth, s.blooming), (12, Blooming::Vertical));
        assert_eq!(
            SceneConfig::parse("[camera]\nf_number = 4\n[sensor]\n")
                .unwrap()
                .sensor,
            Some(SensorConfig::default())
        );
        for (text, field) in [
            ("[sensor]\n", "camera.f_number"),
            ("[camera]\nf_number = 0.1\n", "camera.f_number"),
            (
                "[camera]\nf_number = 8\n[sensor]\nbit_depth = 9\n",
                "sensor.bit_depth",
            ),
            (
                "[camera]\nf_number = 8\n[sensor]\nexposure = 3.0\n",
                "ms = 3",
            ),
            (
                "[camera]\nf_number = 8\n[sensor]\nexposure = \"manual\"\n",
                "auto",
            ),
            (
                "[camera]\nf_number = 8\n[sensor]\nquantum_efficiency = 1.5\n",
                "sensor.quantum_efficiency",
            ),
            (
                "[camera]\nf_number = 8\n[sensor]\nprnu_percent = 60\n",
                "sensor.prnu_percent",
            ),
            (
                "[camera]\nf_number = 8\n[sensor]\ndark_current_electrons_per_s = -1\n",
                "sensor.dark_current_electrons_per_s",
            ),
            ("[camera]\nf_number = \"wide\"\n", "camera.f_number"),
        ] {
            let e = SceneConfig::parse(text).unwrap_err().to_string();
            assert!(e.contains(field), "{text}: {e}");
        }
    }

    #[test]
    fn views_parse() {
        assert_eq!(parse_view("B10").unwrap().face, crate::scene::mesh::FACE_B);
        assert_eq!(parse_view("C0").unwrap().angle_deg, 0.0);
        assert!(parse_view("A90").is_err());
        assert!(parse_view("A").is_err());
        let v = parse_view("B12.5@-30").unwrap();
        assert_eq!((v.face, v.angle_deg, v.azimuth_deg), (2, 12.5, -30.0));
        assert!(parse_view("A10@400").is_err() && parse_view("A10@").is_err());
    }

    #[test]
    fn noise_fields_rules_name_the_field_for_scene_files_and_jobs() {
        let ok = NoiseFields {
            spp: 64,
            noise_target: Some(1.0),
            min_spp: Some(16),
            adaptive_radius: Some(4),
            noise_target_growth: Some(0.5),
            noise_estimate: Some(NoiseEstimator::Samples),
            analytic_rays: Some(16),
            analytic_rays_max: Some(64),
            analytic_ray_cost: Some(0.05),
            direct_light_sampled: false,
        };
        assert_eq!(ok.check(), Ok(()));
        let broken = |f: NoiseFields| f.check().unwrap_err().field;
        // Without the target, the first field that needs it is named.
        let untargeted = NoiseFields {
            noise_target: None,
            ..ok.clone()
        };
        assert_eq!(broken(untargeted.clone()), "render.min_spp");
        for (f, field) in [
            (
                NoiseFields {
                    min_spp: None,
                    ..untargeted.clone()
                },
                "render.adaptive_radius",
            ),
            (
                NoiseFields {
                    min_spp: None,
                    adaptive_radius: None,
                    noise_target_growth: None,
                    ..untargeted.clone()
                },
                "render.noise_estimate",
            ),
            (
                NoiseFields {
                    noise_target: Some(0.005),
                    ..ok.clone()
                },
                "render.noise_target",
            ),
            (
                NoiseFields {
                    min_spp: Some(65),
                    ..ok.clone()
                },
                "render.min_spp",
            ),
            (
                NoiseFields {
                    adaptive_radius: Some(17),
                    ..ok.clone()
                },
                "render.adaptive_radius",
            ),
            (
                NoiseFields {
                    noise_target_growth: Some(1.5),
                    ..ok.clone()
                },
                "render.noise_target_growth",
            ),
            (
                NoiseFields {
                    analytic_rays: Some(1),
                    ..ok.clone()
                },
                "render.analytic_rays",
            ),
            (
                NoiseFields {
                    analytic_rays: None,
                    ..ok.clone()
                },
                "render.analytic_rays",
            ),
            (
                NoiseFields {
                    analytic_rays_max: Some(8),
                    ..ok.clone()
                },
                "render.analytic_rays_max",
            ),
            (
                NoiseFields {
                    direct_light_sampled: true,
                    ..ok.clone()
                },
                "render.analytic_rays_max",
            ),
            (
                NoiseFields {
                    analytic_ray_cost: Some(0.0),
                    ..ok.clone()
                },
                "render.analytic_ray_cost",
            ),
            (
                NoiseFields {
                    analytic_rays_max: None,
                    ..ok.clone()
                },
                "render.analytic_ray_cost",
            ),
        ] {
            assert_eq!(broken(f), field);
        }
        // A scene file's f32 read as written: its lowest target and growth 1 are allowed.
        assert_eq!(as_written(0.01), 0.01);
        let text = "[camera]\nf_number = 8\n[sensor]\n[render]\nspp = 8\nnoise_target = 0.01\nnoise_target_growth = 1.0\n";
        SceneConfig::parse(text).expect("the lowest target");
        let e = SceneConfig::parse(&text.replace("0.01", "0.009"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("render.noise_target = 0.009: must be a number in [0.01, 100]"),
            "{e}"
        );
    }
}
