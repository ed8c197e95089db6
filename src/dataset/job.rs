//! The job file (TOML): everything a dataset run needs, validated as a whole before any
//! rendering starts. Every error names the field and its allowed range.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::error::{DatasetError, Result};
use super::post::PostStep;

/// The paper's viewpoint plan: faces A, B, C at 0, 10 and 20 degrees from the normal.
pub const PAPER_VIEWS: [&str; 9] = ["A0", "A10", "A20", "B0", "B10", "B20", "C0", "C10", "C20"];

/// A parsed job. Counts are read as signed integers so a negative count gets a clear
/// message naming its field rather than a TOML type error; after [`Job::validate`] they
/// are known to be in range.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Job {
    /// The one seed every random choice is split from (see `seed.rs`).
    pub seed: u64,
    pub render: RenderSettings,
    /// Viewpoint names `"<face><degrees>"`, e.g. "A20". Default: [`PAPER_VIEWS`].
    #[serde(default = "default_views")]
    pub views: Vec<String>,
    /// Free camera poses (`[[pose]]`), after the views and the plan's views.
    #[serde(default, rename = "pose", skip_serializing_if = "Vec::is_empty")]
    pub poses: Vec<JobPose>,
    /// Generated face-relative views (`plan = { cone = {..}, ring = {..} }`), after `views`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plan: Option<ViewPlan>,
    #[serde(default)]
    pub material: MaterialSettings,
    #[serde(default)]
    pub mapping: MappingSettings,
    pub texture: TextureSettings,
    #[serde(default)]
    pub defects: DefectSettings,
    /// The camera's intrinsics and lens (`[camera]`, the keys of [`CAMERA_KEYS`] as in a
    /// scene's `[camera]`), as written; the pose comes from the viewpoints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<toml::Table>,
    /// `camera` read as a scene camera (the calibration file loaded when the job is read
    /// with its folder): default pose, the camera's own resolution (the images are
    /// rendered at `[render] width, height`, see [`Job::image_camera`]).
    #[serde(skip)]
    pub camera_config: crate::scene::config::CameraConfig,
    #[serde(default)]
    pub sensor: SensorSettings,
    #[serde(rename = "finish")]
    pub finishes: Vec<Finish>,
    #[serde(rename = "object")]
    pub objects: Vec<Object>,
    #[serde(default)]
    pub split: SplitRatios,
    /// The lights (`[[light]]`, as in a scene file); empty: the ring on the camera.
    #[serde(default, rename = "light", skip_serializing_if = "Vec::is_empty")]
    pub lights: Vec<crate::scene::lights::LightEntry>,
    /// Post-processing steps, applied in this order.
    #[serde(default, rename = "postprocess")]
    pub postprocess: Vec<PostStep>,
    /// Where relative paths (glTF, defect spec) are resolved; the job file's folder.
    #[serde(skip)]
    pub base_dir: PathBuf,
    /// The file the job came from, for error messages.
    #[serde(skip)]
    pub origin: String,
}

fn default_views() -> Vec<String> {
    PAPER_VIEWS.iter().map(|s| s.to_string()).collect()
}

/// A free camera pose of a job (`[[pose]]`): a name (the manifest's `viewpoint`) and
/// exactly one of `look_at`, `matrix`, `opencv` (as in a scene's `[camera]`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JobPose {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at: Option<crate::scene::config::LookAt>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub matrix: Option<[[f64; 4]; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub opencv: Option<crate::scene::config::OpenCvPose>,
}

impl JobPose {
    /// Puts this pose on a scene camera (replacing any free pose it had).
    pub fn apply(&self, cam: &mut crate::scene::config::CameraConfig) {
        cam.look_at = self.look_at.clone();
        cam.matrix = self.matrix;
        cam.opencv = self.opencv.clone();
    }
}

/// Generated views: a cone around a face normal and / or a ring of azimuths.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ViewPlan {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cone: Option<ConePlan>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ring: Option<RingPlan>,
}

/// `count` views of `face` filling the cone up to `max_tilt_deg` from its normal with
/// equal solid angle per view: view k has cos(tilt) = 1 - (1 - cos max) k / (count - 1)
/// (view 0 on the normal, the last at the maximum tilt) and azimuth k * 137.508 degrees
/// (the golden angle), so the views spread evenly over the cap.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ConePlan {
    pub face: String,
    pub max_tilt_deg: f64,
    pub count: i64,
}

/// `count` views of `face` at `tilt_deg` from its normal, azimuths
/// `azimuth_deg + 360 k / count`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RingPlan {
    pub face: String,
    pub tilt_deg: f64,
    pub count: i64,
    #[serde(default)]
    pub azimuth_deg: f64,
}

/// The golden angle, degrees: 360 (1 - 1 / phi).
pub const GOLDEN_ANGLE_DEG: f64 = 137.50776405003785;

/// Most views one plan may generate.
const MAX_PLAN_VIEWS: i64 = 10_000;

/// A generated view's name: "<face><tilt>@<azimuth>", both rounded to 0.001 degree
/// (the name is the view: the renderer parses it back).
fn plan_view_name(face: &str, tilt: f64, az: f64) -> String {
    let r = |x: f64| {
        let v = (x * 1000.0).round() / 1000.0;
        if v == 0.0 { 0.0 } else { v }
    };
    let (t, a) = (r(tilt), r(az.rem_euclid(360.0)));
    if a == 0.0 || a == 360.0 {
        format!("{face}{t}")
    } else {
        format!("{face}{t}@{a}")
    }
}

impl ViewPlan {
    /// The generated view names, cone first.
    pub fn views(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(c) = &self.cone {
            let n = c.count.max(0);
            let cmax = c.max_tilt_deg.to_radians().cos();
            for k in 0..n {
                let f = if n > 1 {
                    k as f64 / (n - 1) as f64
                } else {
                    0.0
                };
                let tilt = (1.0 - (1.0 - cmax) * f)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees();
                let az = if k == 0 {
                    0.0
                } else {
                    k as f64 * GOLDEN_ANGLE_DEG
                };
                out.push(plan_view_name(&c.face, tilt, az));
            }
        }
        if let Some(r) = &self.ring {
            for k in 0..r.count.max(0) {
                let az = r.azimuth_deg + 360.0 * k as f64 / r.count as f64;
                out.push(plan_view_name(&r.face, r.tilt_deg, az));
            }
        }
        out
    }
}

/// Where an image's camera is: a named face-relative view, or a free pose.
#[derive(Clone, Debug, PartialEq)]
pub enum Viewpoint<'a> {
    View(String),
    Pose(&'a JobPose),
}

impl Viewpoint<'_> {
    /// The name: the view ("A20", "A14.142@137.508") or the pose's name.
    pub fn name(&self) -> &str {
        match self {
            Viewpoint::View(v) => v,
            Viewpoint::Pose(p) => &p.name,
        }
    }

    /// The pose of a `[[pose]]` viewpoint; None for a face-relative view.
    pub fn pose(&self) -> Option<&JobPose> {
        match self {
            Viewpoint::View(_) => None,
            Viewpoint::Pose(p) => Some(p),
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSettings {
    pub width: i64,
    pub height: i64,
    pub spp: i64,
    pub bounces: i64,
    /// Stop adding samples once the render noise is at most this fraction of the
    /// camera's own temporal noise (rms of each over the object's pixels; EMVA 1288
    /// sensor only), in [0.01, 100]; `spp` is then the maximum. None: exactly `spp`.
    /// docs/dataset.md, "Samples chosen from a noise target".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_target: Option<f64>,
    /// Samples before the first noise check (with `noise_target`), [2, spp]; default
    /// [`DEFAULT_MIN_SPP`] (or `spp` when smaller).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_spp: Option<i64>,
    /// How the noise check estimates the render noise (with `noise_target`): "halves"
    /// (default) or "samples" (docs/dataset.md, "Samples chosen from a noise target").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_estimate: Option<crate::scene::config::NoiseEstimator>,
    /// Samples per pixel by the pixel's own noise (with `noise_target`), [0, 16]: each
    /// pixel's variance averaged over the (2 r + 1)^2 pixels around it (docs/dataset.md,
    /// "Samples per pixel"); none: every pixel takes the image's samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive_radius: Option<i64>,
    /// How the target grows with an image's mean samples (with `noise_target`), [0, 1]:
    /// an image stops at `noise_target` (mean spp / min_spp)^growth. None or 0: every
    /// image to the same target; 0.5: the samples that minimise the dataset's pooled
    /// error for the samples spent (docs/dataset.md, "Samples chosen from a noise
    /// target").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_target_growth: Option<f64>,
    /// Where the labels come from: "auto" (default: the path tracer's own samples under
    /// a thin lens, the annotation pass under a pinhole), "pass" or "samples"
    /// (docs/dataset.md, "Labels from the path tracer's samples").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<crate::scene::config::LabelSource>,
    /// The direct light's estimator: "analytic" (default: the ring lights' control
    /// variate at the primary hit; docs/rendering.md, "Analytic direct light") or
    /// "sampled".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direct_light: Option<crate::scene::config::DirectLight>,
    /// Camera rays per sample for the control variate's closed form, [1, 64] (scene
    /// files' `[render] analytic_rays`); default 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub analytic_rays: Option<i64>,
    /// With `noise_target` and the analytic direct light: at the first noise check each
    /// image chooses its camera rays per sample for the closed form for the samples
    /// after it, between 1 and this, [analytic_rays, 64], from the variances its first
    /// samples measured (`render::noise::RayChoice`; docs/dataset.md, "The extra rays
    /// chosen per image"); `analytic_rays` (at least 2) is then the first samples'
    /// count. None: `analytic_rays` throughout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub analytic_rays_max: Option<i64>,
    /// With `analytic_rays_max`: one extra ray's cost over the rest of a sample's, the
    /// choice's k, (0, 10]; default [`DEFAULT_ANALYTIC_RAY_COST`] (measured on lavapipe).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub analytic_ray_cost: Option<f64>,
    /// Light samples at the camera ray's first hit, [1, 64] (scene files' `[render]
    /// light_samples`); default 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_samples: Option<i64>,
    /// BSDF samples for the direct light at the camera ray's first hit, [1, 64] (scene
    /// files' `[render] bsdf_samples`); default 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bsdf_samples: Option<i64>,
    /// Each of the `bsdf_samples` directions continues as a path of weight
    /// 1 / `bsdf_samples` (scene files' `[render] split_paths`); default false. Needs
    /// `bsdf_samples` >= 2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split_paths: Option<bool>,
    /// Samples per GPU submission, [1, 1024] (scene files' `[render] batch_spp`); default
    /// 16. With `noise_target` the checks after the first (`min_spp`) fall on batch ends,
    /// so a smaller batch lets an image stop earlier; the images do not depend on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_spp: Option<i64>,
}

/// `[render] min_spp` when not given (`render::noise::DEFAULT_MIN_SPP`).
pub const DEFAULT_MIN_SPP: i64 = crate::render::noise::DEFAULT_MIN_SPP as i64;
/// `[render] analytic_ray_cost` when not given (`render::noise::DEFAULT_ANALYTIC_RAY_COST`).
pub const DEFAULT_ANALYTIC_RAY_COST: f64 = crate::render::noise::DEFAULT_ANALYTIC_RAY_COST;

impl RenderSettings {
    /// Samples before the first noise check: `min_spp`, default [`DEFAULT_MIN_SPP`],
    /// never more than `spp`.
    pub fn first_check_spp(&self) -> u32 {
        self.min_spp.unwrap_or(DEFAULT_MIN_SPP).min(self.spp).max(1) as u32
    }
}

/// The object material's roughness, drawn uniformly per object instance from a range
/// given in one of two conventions: `roughness` (appleseed / Disney r, GGX alpha = r^2;
/// the paper's convention, since its renderer is appleseed) or `alpha` (GGX alpha
/// itself). Exactly one may be given; neither means the paper's `roughness = [0.05, 0.3]`.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSettings {
    /// Roughness r in [min, max], drawn uniformly; alpha = r^2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roughness: Option<[f64; 2]>,
    /// GGX alpha in [min, max], drawn uniformly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<[f64; 2]>,
}

/// The paper's roughness range (appleseed r): "we uniformly sample the material
/// roughness parameter from the range [0.05, 0.3]".
pub const PAPER_ROUGHNESS: [f64; 2] = [0.05, 0.3];

/// Which convention a drawn range is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoughnessConvention {
    /// appleseed / Disney r: alpha = r^2.
    Roughness,
    /// GGX alpha.
    Alpha,
}

impl MaterialSettings {
    /// The range and its convention (the paper's roughness when neither is given).
    pub fn range(&self) -> ([f64; 2], RoughnessConvention) {
        match (self.roughness, self.alpha) {
            (_, Some(a)) => (a, RoughnessConvention::Alpha),
            (Some(r), None) => (r, RoughnessConvention::Roughness),
            (None, None) => (PAPER_ROUGHNESS, RoughnessConvention::Roughness),
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct MappingSettings {
    /// Texture rotation per face drawn from [-rotation_deg, rotation_deg].
    pub rotation_deg: f64,
    /// Texture translation per face, texture pixels, each axis drawn from [-t, t].
    pub translation_px: FaceTranslation,
    /// "part" (default): every planar region of the object gets the finish (regions
    /// other than A, B, C: one of the instance's three maps, rotation drawn from
    /// [-rotation_deg, rotation_deg], offset over the whole map, maps repeated beyond
    /// their edges); "faces": only A, B and C, each map clipped (before issue 11).
    pub cover: crate::scene::assemble::Cover,
    /// "textured" (default): dents and scratches carry the finish; "burnished": the
    /// smooth surface of the tool (docs/texture.md, "Defect surfaces").
    pub defects: crate::scene::assemble::DefectSurface,
}

impl Default for MappingSettings {
    fn default() -> Self {
        MappingSettings {
            rotation_deg: 15.0,
            translation_px: FaceTranslation::default(),
            cover: Default::default(),
            defects: Default::default(),
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaceTranslation {
    #[serde(rename = "A")]
    pub a: f64,
    #[serde(rename = "B")]
    pub b: f64,
    #[serde(rename = "C")]
    pub c: f64,
}

impl Default for FaceTranslation {
    fn default() -> Self {
        // The paper's 5 / 3 / 1 px for faces A / B / C.
        FaceTranslation {
            a: 5.0,
            b: 3.0,
            c: 1.0,
        }
    }
}

impl FaceTranslation {
    pub fn for_face(&self, face: u8) -> f64 {
        match face {
            1 => self.a,
            2 => self.b,
            _ => self.c,
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TextureSettings {
    /// Side of each (square) texture map, pixels.
    pub size_px: i64,
    /// Texture pixel spacing, micrometres.
    pub spacing_um: f64,
    /// Textures kept in memory at once (bounded cache keyed by (finish, instance)).
    #[serde(default = "default_cache")]
    pub cache: i64,
}

fn default_cache() -> i64 {
    8
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DefectSettings {
    /// "paper" for the paper's table, or a defect spec TOML path (relative to the job).
    pub spec: String,
    /// Distinct defect geometries, sampled once and re-used across objects and finishes.
    /// Default: the largest `defective` count of any object.
    pub sets: Option<i64>,
}

impl Default for DefectSettings {
    fn default() -> Self {
        DefectSettings {
            spec: "paper".into(),
            sets: None,
        }
    }
}

/// The keys a job's `[camera]` accepts: a scene camera's intrinsics and lens (the pose
/// comes from `views`, `plan` and `[[pose]]`).
pub const CAMERA_KEYS: [&str; 8] = [
    "width",
    "height",
    "pixel_um",
    "focal_mm",
    "working_distance_mm",
    "calibration",
    "f_number",
    "focus_distance_mm",
];

/// `[sensor]`: the linear model (`exposure = <number>`, or no `[sensor]`: exposure 1) or
/// an EMVA 1288 camera (`exposure = "auto"` or `{ ms = .. }` and / or any field of a
/// scene's `[sensor]`), plus the per-image random exposure. Kept as written for
/// serialising.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(try_from = "toml::Table", into = "toml::Table")]
pub struct SensorSettings {
    pub model: SensorModel,
    /// Random exposure per image: EV stops drawn uniformly from [min, max] (factor
    /// 2^ev on the exposure), each in [-10, 10]. None: off.
    pub exposure_jitter_ev: Option<[f64; 2]>,
    /// Probability that an image gets a jitter (else ev = 0), [0, 1]; default 1.
    pub exposure_jitter_probability: f64,
    written: toml::Table,
}

/// How radiance becomes an image.
#[derive(Clone, Debug, PartialEq)]
pub enum SensorModel {
    /// Image value (8-bit units, 0..=255) = 255 * exposure * radiance, before the
    /// post-processing steps.
    Linear { exposure: f64 },
    /// The EMVA 1288 sensor of a scene's `[sensor]` (same fields, same checks).
    Emva(crate::scene::config::SensorConfig),
}

impl SensorModel {
    /// The bit depth of image.png's codes when deeper than 8: an EMVA sensor of 10, 12
    /// or 16 bit writes a 16-bit PNG with the codes unscaled (recorded in the manifest as
    /// `bit_depth`); None for 8-bit images (the linear model, an 8-bit sensor).
    pub fn deep_bit_depth(&self) -> Option<u32> {
        match self {
            SensorModel::Emva(s) if s.bit_depth > 8 => Some(s.bit_depth),
            _ => None,
        }
    }
}

impl Default for SensorSettings {
    fn default() -> Self {
        SensorSettings {
            model: SensorModel::Linear { exposure: 1.0 },
            exposure_jitter_ev: None,
            exposure_jitter_probability: 1.0,
            written: toml::Table::new(),
        }
    }
}

impl From<SensorSettings> for toml::Table {
    fn from(s: SensorSettings) -> toml::Table {
        s.written
    }
}

impl TryFrom<toml::Table> for SensorSettings {
    type Error = String;
    fn try_from(t: toml::Table) -> std::result::Result<Self, String> {
        let number = |key: &str, v: &toml::Value| match v {
            toml::Value::Float(f) => Ok(*f),
            toml::Value::Integer(i) => Ok(*i as f64),
            other => Err(format!("sensor.{key} = {other}: must be a number")),
        };
        let mut rest = t.clone();
        let jitter = match rest.remove("exposure_jitter_ev") {
            None => None,
            Some(toml::Value::Array(a)) if a.len() == 2 => Some([
                number("exposure_jitter_ev[0]", &a[0])?,
                number("exposure_jitter_ev[1]", &a[1])?,
            ]),
            Some(other) => {
                return Err(format!(
                    "sensor.exposure_jitter_ev = {other}: must be [min, max] in EV stops"
                ));
            }
        };
        let probability = match rest.remove("exposure_jitter_probability") {
            None => 1.0,
            Some(v) => number("exposure_jitter_probability", &v)?,
        };
        let model = match rest.get("exposure") {
            Some(v @ (toml::Value::Float(_) | toml::Value::Integer(_))) => {
                let exposure = number("exposure", v)?;
                let others: Vec<&str> = rest
                    .keys()
                    .map(String::as_str)
                    .filter(|k| *k != "exposure")
                    .collect();
                if !others.is_empty() {
                    return Err(format!(
                        "sensor.exposure = {exposure} is the linear model's factor, but {} are fields of the EMVA 1288 sensor: for that sensor write exposure = \"auto\" or {{ ms = <time> }}, for the linear model remove them",
                        others.join(", ")
                    ));
                }
                SensorModel::Linear { exposure }
            }
            None if rest.is_empty() => SensorModel::Linear { exposure: 1.0 },
            _ => SensorModel::Emva(
                toml::Value::Table(rest)
                    .try_into()
                    .map_err(|e: toml::de::Error| format!("sensor: {}", e.message()))?,
            ),
        };
        Ok(SensorSettings {
            model,
            exposure_jitter_ev: jitter,
            exposure_jitter_probability: probability,
            written: t,
        })
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum FinishKind {
    Milled,
    Sandblasted,
}

/// A surface finish: how its textures are made. `params`, `variation` and `exemplar` are
/// handed to the texture module (`docs/texture.md` lists their fields).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Finish {
    /// Name, e.g. "parallel-d4-ae0.5"; the texture type (the part before the first '-')
    /// selects the linear post-processing row and is what `synosis compare` groups by.
    pub name: String,
    pub kind: FinishKind,
    /// Texture instances of this finish; each face draws one of them.
    pub textures: i64,
    /// Milled: `MilledParams` fields; sandblasted: `SandblastParams` fields.
    #[serde(default)]
    pub params: toml::Table,
    /// Milled only: "paper" (the paper's variation sets), "none", or a table of sets.
    #[serde(default)]
    pub variation: Option<toml::Value>,
    /// Sandblasted only: the stand-in exemplar's fields (e.g. pressure_bar).
    #[serde(default)]
    pub exemplar: Option<toml::Table>,
    /// A measured height map of this finish (Alicona xyz or EXR): a sandblasted finish
    /// synthesises from it (instead of the stand-in exemplar), a milled one is moment
    /// matched to its mean and Sq (instead of the default). docs/dataset.md.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measurement: Option<MeasurementRef>,
    /// Multiplies `[sensor] exposure` for this finish's images (a bright sandblasted
    /// finish and a dark milled one both well exposed; docs/dataset.md). Default 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<f64>,
}

/// A measured height map named in a job.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeasurementRef {
    /// `.xyz` / `.txt` / `.asc` (Alicona ASCII x y z) or `.exr` (one channel, um),
    /// relative to the job file.
    pub path: String,
    /// Unit of the xyz coordinates: "m" (Alicona's default), "mm" or "um".
    #[serde(default = "default_xyz_unit")]
    pub unit: crate::texture::XyzUnit,
    /// Pixel spacing of an EXR measurement, um (xyz files carry their own).
    #[serde(default = "default_exr_spacing")]
    pub exr_spacing_um: f64,
    /// Form removal before use: "none" (mean), "plane" (default) or "quadratic".
    #[serde(default)]
    pub form: crate::texture::FormRemoval,
    /// `path` resolved against the job file's folder.
    #[serde(skip)]
    pub resolved: PathBuf,
}

fn default_xyz_unit() -> crate::texture::XyzUnit {
    crate::texture::XyzUnit::M
}

fn default_exr_spacing() -> f64 {
    1.75
}

impl Finish {
    /// The exposure factor of this finish's images (`exposure`, default 1).
    pub fn exposure_factor(&self) -> f64 {
        self.exposure.unwrap_or(1.0)
    }

    /// Texture type: the name up to its first '-', lower case (as `synosis compare`).
    pub fn texture_type(&self) -> String {
        crate::metrics::dataset::texture_of(&self.name)
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Object {
    pub name: String,
    /// "testbody-b", "testbody-m", or a mesh file (glTF/GLB, OBJ, STL, PLY; relative to
    /// the job file).
    pub mesh: String,
    /// Unit of the mesh file ("mm", "m", "in"); default millimetres for every format
    /// (glTF included, as job meshes were always read).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<crate::scene::MeshUnit>,
    /// Inspected faces as in a scene's `[object] inspect` (labels, region ids, normals);
    /// default the mesh's own labels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inspect: Option<Vec<crate::scene::inspect::InspectEntry>>,
    /// Finishes this object is made in; default all, in job order.
    #[serde(default)]
    pub finishes: Option<Vec<String>>,
    /// Materials per region of this object (`[[object.material.region]]`, the entries of
    /// a scene file's `[[material.region]]`); none: the whole object is the job's
    /// `[material]` conductor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<ObjectMaterial>,
    /// Instances per finish carrying defect set 0, 1, ... (cycled if fewer sets).
    pub defective: i64,
    /// Instances per finish without defects.
    pub defect_free: i64,
}

/// An object's `material` table: only its region entries (the object's own conductor
/// is the job's `[material]` roughness draw).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ObjectMaterial {
    /// As a scene file's `[[material.region]]` (docs/scene-format.md): selectors, kind,
    /// preset / IOR, alpha / roughness, albedo, finish.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub region: Vec<crate::scene::materials::RegionMaterialConfig>,
}

impl Object {
    /// The object's region materials, checked, for an instance whose conductor has GGX
    /// alpha `alpha`: entries without `alpha` / `roughness` take it (as a scene file's
    /// entries take `[material]`'s), entries without a preset or IOR take aluminium.
    /// `wavelength_nm`: the camera's (presets are tabulated at 550 nm). Errors name
    /// `object[<index>].material.region` and the entry.
    pub fn region_materials(
        &self,
        index: usize,
        alpha: f32,
        wavelength_nm: f64,
    ) -> std::result::Result<Vec<crate::scene::materials::RegionMaterial>, String> {
        let Some(m) = &self.material else {
            return Ok(Vec::new());
        };
        let base = crate::scene::config::MaterialConfig {
            alpha,
            ..Default::default()
        };
        crate::scene::materials::resolve(&m.region, &base, wavelength_nm).map_err(|e| {
            e.to_string().replace(
                "material.region",
                &format!("object[{index}].material.region"),
            )
        })
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SplitRatios {
    pub train: f64,
    pub val: f64,
    pub test: f64,
}

impl Default for SplitRatios {
    fn default() -> Self {
        SplitRatios {
            train: 0.7,
            val: 0.1,
            test: 0.2,
        }
    }
}

/// Largest accepted counts: far beyond any real job, they catch typos (an extra zero
/// times nine views is hours of rendering).
const MAX_INSTANCES: i64 = 100_000;
const MAX_SIZE: i64 = 16_384;

impl Job {
    /// Every viewpoint of an object instance, in order: `views`, the plan's views, then
    /// the `[[pose]]` entries.
    pub fn viewpoints(&self) -> Vec<Viewpoint<'_>> {
        let mut out: Vec<Viewpoint> = self.views.iter().cloned().map(Viewpoint::View).collect();
        if let Some(p) = &self.plan {
            out.extend(p.views().into_iter().map(Viewpoint::View));
        }
        out.extend(self.poses.iter().map(Viewpoint::Pose));
        out
    }

    /// `views` defaults to the paper's nine only when the job has no plan and no poses:
    /// whether it was written is read from the text.
    fn default_views_only_alone(&mut self, text: &str) {
        let written = toml::from_str::<toml::Table>(text)
            .ok()
            .is_some_and(|t| t.contains_key("views"));
        if !written && (self.plan.is_some() || !self.poses.is_empty()) {
            self.views.clear();
        }
    }

    /// Reads and validates a job file; relative paths become relative to its folder.
    pub fn load(path: &Path) -> Result<Job> {
        let text = crate::limits::read_text(path).map_err(|e| DatasetError::io(path, e))?;
        let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        Job::parse(&text, &path.display().to_string(), &base)
    }

    /// Parses and validates job TOML; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str, base_dir: &Path) -> Result<Job> {
        let mut job: Job = toml::from_str(text).map_err(|e| DatasetError::Parse {
            file: origin.to_string(),
            message: e.to_string(),
        })?;
        job.base_dir = base_dir.to_path_buf();
        job.origin = origin.to_string();
        job.default_views_only_alone(text);
        job.resolve_measurements();
        job.read_camera(text, true)?;
        job.validate()?;
        Ok(job)
    }

    /// Parses the copy of a job stored in a dataset folder: validated, except that mesh
    /// files are not looked for (relative paths point beside the original job file).
    pub fn parse_stored(text: &str, origin: &str) -> Result<Job> {
        let mut job: Job = toml::from_str(text).map_err(|e| DatasetError::Parse {
            file: origin.to_string(),
            message: e.to_string(),
        })?;
        job.origin = origin.to_string();
        job.default_views_only_alone(text);
        job.resolve_measurements();
        job.read_camera(text, false)?;
        job.check(false)?;
        Ok(job)
    }

    /// True if the two jobs make the same renders (only post-processing may differ).
    pub fn same_except_postprocess(&self, other: &Job) -> bool {
        let strip = |j: &Job| {
            let mut j = j.clone();
            j.postprocess.clear();
            // Exposure and the sensor act on the stored linear radiance: post-processing
            // re-does them.
            j.sensor = SensorSettings::default();
            for f in &mut j.finishes {
                f.exposure = None;
            }
            j.base_dir = PathBuf::new();
            j.origin.clear();
            toml::to_string(&j).ok()
        };
        strip(self).is_some() && strip(self) == strip(other)
    }

    /// Reads `[camera]` into `camera_config` with the scene file's own parser and
    /// checks (`CameraConfig`); with `load_files`, the calibration file (relative to the
    /// job) is read too. A stored job (a dataset folder's copy) keeps the calibration's
    /// path unread: its images' intrinsics are in the manifest.
    fn read_camera(&mut self, text: &str, load_files: bool) -> Result<()> {
        let Some(table) = &self.camera else {
            return Ok(());
        };
        for key in table.keys() {
            if !CAMERA_KEYS.contains(&key.as_str()) {
                let hint = match key.as_str() {
                    "view" | "look_at" | "matrix" | "opencv" => {
                        "; poses come from `views`, `plan` and [[pose]]"
                    }
                    "exposure" | "gain" => "; the exposure is `[sensor] exposure`",
                    _ => "",
                };
                return Err(self.field(
                    format!("camera.{key}"),
                    table[key].to_string(),
                    &format!(
                        "not a job camera key: allowed {}{hint}",
                        CAMERA_KEYS.join(", ")
                    ),
                ));
            }
        }
        let parse_err = |message: String| DatasetError::Parse {
            file: self.origin.clone(),
            message,
        };
        let mut cam: crate::scene::config::CameraConfig = toml::Value::Table(table.clone())
            .try_into()
            .map_err(|e: toml::de::Error| parse_err(format!("camera: {}", e.message())))?;
        if let Some(c) = &cam.calibration
            && c.is_relative()
        {
            cam.calibration = Some(self.base_dir.join(c));
        }
        if load_files {
            cam.load_calibration(text)
                .map_err(|e| parse_err(e.to_string()))?;
        }
        self.camera_config = cam;
        Ok(())
    }

    /// A scene configuration with the job's camera and sensor (the scene defaults
    /// otherwise): what the renderer starts from, and what the scene file's checks run
    /// on.
    pub fn scene_base(&self) -> crate::scene::config::SceneConfig {
        crate::scene::config::SceneConfig {
            camera: self.camera_config.clone(),
            sensor: match &self.sensor.model {
                SensorModel::Emva(s) => Some(s.clone()),
                SensorModel::Linear { .. } => None,
            },
            ..Default::default()
        }
    }

    /// The camera at the images' resolution (`[render] width, height`; the sensor keeps
    /// its physical size, so the pixel pitch and a calibration scale with the image).
    pub fn image_camera(&self) -> std::result::Result<crate::scene::config::CameraConfig, String> {
        let mut cfg = self.scene_base();
        cfg.set_resolution(self.render.width as u32, self.render.height as u32)
            .map_err(|e| {
                e.to_string()
                    .replace("--width", "render.width")
                    .replace("--height", "render.height")
            })?;
        Ok(cfg.camera)
    }

    fn resolve_measurements(&mut self) {
        let base = self.base_dir.clone();
        for f in &mut self.finishes {
            if let Some(m) = &mut f.measurement {
                let p = Path::new(&m.path);
                m.resolved = if p.is_absolute() {
                    p.to_path_buf()
                } else {
                    base.join(p)
                };
            }
        }
    }

    fn field(&self, field: impl Into<String>, value: impl ToString, allowed: &str) -> DatasetError {
        DatasetError::Field {
            file: self.origin.clone(),
            field: field.into(),
            value: value.to_string(),
            allowed: allowed.to_string(),
        }
    }

    fn int(&self, field: &str, v: i64, lo: i64, hi: i64) -> Result<()> {
        crate::scene::config::int_in(v, lo, hi).map_err(|allowed| self.field(field, v, &allowed))
    }

    fn real(&self, field: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
        crate::scene::config::real_in(v, lo, hi).map_err(|allowed| self.field(field, v, &allowed))
    }

    /// Every check that needs no file other than the job itself (meshes and the defect
    /// spec are checked by `prepare`, still before rendering).
    pub fn validate(&self) -> Result<()> {
        self.check(true)
    }

    fn check(&self, check_files: bool) -> Result<()> {
        let r = &self.render;
        self.int("render.width", r.width, 1, MAX_SIZE)?;
        self.int("render.height", r.height, 1, MAX_SIZE)?;
        let max_pixels = crate::gpu_interface::MAX_IMAGE_PIXELS as i64;
        if r.width * r.height > max_pixels {
            return Err(self.field(
                "render.width x render.height",
                r.width * r.height,
                &format!(
                    "must be at most {max_pixels} pixels (e.g. 8192 x 4096): one f32 per pixel must fit the 128 MiB storage-buffer range every Vulkan device has"
                ),
            ));
        }
        self.int("render.spp", r.spp, 1, 1 << 16)?;
        self.int("render.bounces", r.bounces, 1, 64)?;
        crate::scene::config::NoiseFields {
            spp: r.spp,
            noise_target: r.noise_target,
            min_spp: r.min_spp,
            adaptive_radius: r.adaptive_radius,
            noise_target_growth: r.noise_target_growth,
            noise_estimate: r.noise_estimate,
            analytic_rays: r.analytic_rays,
            analytic_rays_max: r.analytic_rays_max,
            analytic_ray_cost: r.analytic_ray_cost,
            direct_light_sampled: r.direct_light
                == Some(crate::scene::config::DirectLight::Sampled),
        }
        .check()
        .map_err(|e| self.field(e.field, e.value, &e.allowed))?;
        if let Some(t) = r.noise_target
            && let SensorModel::Linear { .. } = self.sensor.model
        {
            return Err(self.field(
                "render.noise_target",
                t,
                "needs the EMVA 1288 sensor (`[sensor] exposure = \"auto\"` or `{ ms = .. }`): the target is the render noise over the camera's own noise, and the linear model has none; remove it to render exactly `spp`",
            ));
        }
        if let Some(n) = r.light_samples {
            self.int("render.light_samples", n, 1, 64)?;
        }
        if let Some(n) = r.bsdf_samples {
            self.int("render.bsdf_samples", n, 1, 64)?;
        }
        let bsdf = r
            .bsdf_samples
            .unwrap_or(crate::scene::config::DEFAULT_LIGHT_SAMPLES as i64);
        if r.split_paths == Some(true) && bsdf < 2 {
            return Err(self.field(
                "render.bsdf_samples",
                bsdf,
                "must be in [2, 64] with `render.split_paths` (the branches are its directions)",
            ));
        }
        if let Some(n) = r.batch_spp {
            self.int("render.batch_spp", n, 1, 1024)?;
        }
        self.check_viewpoints()?;
        crate::scene::lights::resolve_all(&self.lights).map_err(|e| DatasetError::Parse {
            file: self.origin.clone(),
            message: e.to_string(),
        })?;
        if let (Some(r), Some(a)) = (self.material.roughness, self.material.alpha) {
            return Err(self.field(
                "material.roughness / material.alpha",
                format!("{r:?} / {a:?}"),
                "give one of them: `roughness` (appleseed/Disney r, alpha = r^2) or `alpha` (GGX alpha)",
            ));
        }
        let ([lo, hi], conv) = self.material.range();
        let key = match conv {
            RoughnessConvention::Roughness => "material.roughness",
            RoughnessConvention::Alpha => "material.alpha",
        };
        self.real(&format!("{key}[0]"), lo, 0.001, 1.0)?;
        self.real(&format!("{key}[1]"), hi, lo, 1.0)?;
        self.real(
            "mapping.rotation_deg",
            self.mapping.rotation_deg,
            0.0,
            180.0,
        )?;
        let t = &self.mapping.translation_px;
        for (f, v) in [("A", t.a), ("B", t.b), ("C", t.c)] {
            self.real(&format!("mapping.translation_px.{f}"), v, 0.0, 1.0e4)?;
        }
        self.int("texture.size_px", self.texture.size_px, 16, 65_536)?;
        self.real("texture.spacing_um", self.texture.spacing_um, 0.01, 1.0e4)?;
        self.int("texture.cache", self.texture.cache, 1, 1024)?;
        if let SensorModel::Linear { exposure } = self.sensor.model {
            self.real("sensor.exposure", exposure, 0.0, 1.0e9)?;
        }
        if let Some([lo, hi]) = self.sensor.exposure_jitter_ev {
            self.real("sensor.exposure_jitter_ev[0]", lo, -10.0, 10.0)?;
            self.real("sensor.exposure_jitter_ev[1]", hi, lo, 10.0)?;
        }
        self.real(
            "sensor.exposure_jitter_probability",
            self.sensor.exposure_jitter_probability,
            0.0,
            1.0,
        )?;
        if self.sensor.exposure_jitter_ev.is_none()
            && self.sensor.exposure_jitter_probability != 1.0
        {
            return Err(self.field(
                "sensor.exposure_jitter_probability",
                self.sensor.exposure_jitter_probability,
                "only with sensor.exposure_jitter_ev = [min, max]",
            ));
        }
        // The camera and the EMVA sensor: the scene file's own checks (ranges, the
        // sensor's need for `camera.f_number`).
        self.scene_base()
            .validate()
            .map_err(|e| DatasetError::Parse {
                file: self.origin.clone(),
                message: e.to_string(),
            })?;
        if let Some(s) = self.defects.sets {
            self.int("defects.sets", s, 1, MAX_INSTANCES)?;
        }
        if self.defects.spec.trim().is_empty() {
            return Err(self.field(
                "defects.spec",
                "\"\"",
                "\"paper\" or a defect spec TOML path",
            ));
        }

        if self.finishes.is_empty() {
            return Err(self.field("finish", "[]", "at least one [[finish]]"));
        }
        let mut names = BTreeSet::new();
        for (i, f) in self.finishes.iter().enumerate() {
            let p = format!("finish[{i}]");
            if f.name.trim().is_empty() || f.name.contains(['/', '\\']) {
                return Err(self.field(
                    format!("{p}.name"),
                    format!("{:?}", f.name),
                    "a non-empty name without '/' or '\\'",
                ));
            }
            if !names.insert(f.name.as_str()) {
                return Err(self.field(
                    format!("{p}.name"),
                    format!("{:?}", f.name),
                    "finish names must be unique",
                ));
            }
            self.int(&format!("{p}.textures"), f.textures, 1, 10_000)?;
            if let Some(e) = f.exposure {
                self.real(&format!("{p}.exposure"), e, 1e-6, 1e6)?;
            }
            match f.kind {
                FinishKind::Milled => {
                    if f.exemplar.is_some() {
                        return Err(self.field(
                            format!("{p}.exemplar"),
                            "set",
                            "only for kind = \"sandblasted\"",
                        ));
                    }
                }
                FinishKind::Sandblasted => {
                    if f.variation.is_some() {
                        return Err(self.field(
                            format!("{p}.variation"),
                            "set",
                            "only for kind = \"milled\"",
                        ));
                    }
                }
            }
            if let Some(toml::Value::String(s)) = &f.variation
                && s != "paper"
                && s != "none"
            {
                return Err(self.field(
                    format!("{p}.variation"),
                    format!("{s:?}"),
                    "\"paper\", \"none\" or a table of value sets",
                ));
            }
            if let Some(m) = &f.measurement {
                self.real(
                    &format!("{p}.measurement.exr_spacing_um"),
                    m.exr_spacing_um,
                    0.001,
                    1.0e4,
                )?;
                if f.kind == FinishKind::Sandblasted && f.exemplar.is_some() {
                    return Err(self.field(
                        format!("{p}.exemplar / {p}.measurement"),
                        "both set",
                        "give one: the stand-in `exemplar` or a `measurement`",
                    ));
                }
                if f.kind == FinishKind::Milled && f.params.contains_key("moments") {
                    return Err(self.field(
                        format!("{p}.params.moments / {p}.measurement"),
                        "both set",
                        "give one: the measurement's moments are the target",
                    ));
                }
                if check_files && !m.resolved.is_file() {
                    return Err(self.field(
                        format!("{p}.measurement.path"),
                        format!("{:?}", m.path),
                        &format!(
                            "an existing .xyz/.txt/.asc or .exr file ({} not found)",
                            m.resolved.display()
                        ),
                    ));
                }
            }
            super::textures::validate_finish(f)
                .map_err(|msg| self.field(p.clone(), &f.name, &msg))?;
        }

        if self.objects.is_empty() {
            return Err(self.field("object", "[]", "at least one [[object]]"));
        }
        let mut onames = BTreeSet::new();
        for (i, o) in self.objects.iter().enumerate() {
            let p = format!("object[{i}]");
            if o.name.trim().is_empty() || o.name.contains(['/', '\\']) {
                return Err(self.field(
                    format!("{p}.name"),
                    format!("{:?}", o.name),
                    "a non-empty name without '/' or '\\'",
                ));
            }
            if !onames.insert(o.name.as_str()) {
                return Err(self.field(
                    format!("{p}.name"),
                    format!("{:?}", o.name),
                    "object names must be unique",
                ));
            }
            self.int(&format!("{p}.defective"), o.defective, 0, MAX_INSTANCES)?;
            self.int(&format!("{p}.defect_free"), o.defect_free, 0, MAX_INSTANCES)?;
            if o.defective + o.defect_free == 0 {
                return Err(self.field(
                    format!("{p}.defective + defect_free"),
                    0,
                    "at least one instance",
                ));
            }
            if let Some(fs) = &o.finishes {
                if fs.is_empty() {
                    return Err(self.field(
                        format!("{p}.finishes"),
                        "[]",
                        "omit it for all finishes, or name at least one",
                    ));
                }
                for (j, f) in fs.iter().enumerate() {
                    if !names.contains(f.as_str()) {
                        let known: Vec<&str> = names.iter().copied().collect();
                        return Err(self.field(
                            format!("{p}.finishes[{j}]"),
                            format!("{f:?}"),
                            &format!("unknown finish; defined: {}", known.join(", ")),
                        ));
                    }
                }
            }
            // Region materials: the scene file's checks (an entry that gives no alpha
            // takes the instance's, drawn from the checked range: any value does here).
            let placeholder = crate::scene::config::MaterialConfig::default().alpha;
            o.region_materials(i, placeholder, self.scene_base().wavelength_nm())
                .map_err(|message| DatasetError::Parse {
                    file: self.origin.clone(),
                    message,
                })?;
            if let Some(list) = &o.inspect {
                crate::scene::inspect::parse(list).map_err(|e| {
                    self.field(
                        format!("{p}.inspect"),
                        "",
                        &e.to_string().replace("object.inspect: ", ""),
                    )
                })?;
            }
            if builtin_variant(&o.mesh).is_none() {
                crate::scene::MeshFormat::of(Path::new(&o.mesh)).map_err(|_| {
                    self.field(
                        format!("{p}.mesh"),
                        format!("{:?}", o.mesh),
                        "\"testbody-b\", \"testbody-m\" or a .gltf, .glb, .obj, .stl or .ply file",
                    )
                })?;
            }
            if check_files && builtin_variant(&o.mesh).is_none() {
                let path = self.resolve(&o.mesh);
                if !path.is_file() {
                    return Err(self.field(format!("{p}.mesh"), format!("{:?}", o.mesh), &format!("\"testbody-b\", \"testbody-m\" or an existing mesh file ({} not found)", path.display())));
                }
            }
        }

        let s = &self.split;
        for (n, v) in [
            ("split.train", s.train),
            ("split.val", s.val),
            ("split.test", s.test),
        ] {
            self.real(n, v, 0.0, 1.0)?;
        }
        let sum = s.train + s.val + s.test;
        if (sum - 1.0).abs() > 1e-6 {
            return Err(self.field(
                "split",
                format!("{} + {} + {} = {sum}", s.train, s.val, s.test),
                "train + val + test must sum to 1",
            ));
        }

        let types: BTreeSet<String> = self.finishes.iter().map(Finish::texture_type).collect();
        for (i, step) in self.postprocess.iter().enumerate() {
            step.validate(&types).map_err(|(f, v, allowed)| {
                self.field(format!("postprocess[{i}].{f}"), v, &allowed)
            })?;
        }
        Ok(())
    }

    fn check_viewpoints(&self) -> Result<()> {
        for (i, v) in self.views.iter().enumerate() {
            parse_view(v).ok_or_else(|| {
                self.field(
                    format!("views[{i}]"),
                    format!("{v:?}"),
                    "a face letter A, B or C then degrees from the normal in [0, 89], e.g. \"A20\", optionally '@' and an azimuth in [-360, 360] degrees",
                )
            })?;
        }
        if let Some(p) = &self.plan {
            if p.cone.is_none() && p.ring.is_none() {
                return Err(self.field("plan", "{}", "give `cone` and / or `ring`"));
            }
            let face = |field: &str, f: &str| {
                if ["A", "B", "C"].contains(&f) {
                    Ok(())
                } else {
                    Err(self.field(field, format!("{f:?}"), "\"A\", \"B\" or \"C\""))
                }
            };
            if let Some(c) = &p.cone {
                face("plan.cone.face", &c.face)?;
                self.real("plan.cone.max_tilt_deg", c.max_tilt_deg, 0.0, 89.0)?;
                self.int("plan.cone.count", c.count, 1, MAX_PLAN_VIEWS)?;
            }
            if let Some(r) = &p.ring {
                face("plan.ring.face", &r.face)?;
                self.real("plan.ring.tilt_deg", r.tilt_deg, 0.0, 89.0)?;
                self.int("plan.ring.count", r.count, 1, MAX_PLAN_VIEWS)?;
                self.real("plan.ring.azimuth_deg", r.azimuth_deg, -360.0, 360.0)?;
            }
        }
        for (i, p) in self.poses.iter().enumerate() {
            let f = format!("pose[{i}]");
            if p.name.trim().is_empty() || parse_view(&p.name).is_some() {
                return Err(self.field(
                    format!("{f}.name"),
                    format!("{:?}", p.name),
                    "a non-empty name that is not a view name like \"A20\"",
                ));
            }
            let mut cam = crate::scene::config::CameraConfig::default();
            p.apply(&mut cam);
            if cam.free_pose_fields().is_empty() {
                return Err(self.field(
                    f,
                    &p.name,
                    "one of look_at, matrix, opencv (as in a scene's [camera])",
                ));
            }
            cam.pose().map_err(|e| {
                self.field(
                    format!("{f} ({})", p.name),
                    "",
                    &e.to_string().replace("camera.", ""),
                )
            })?;
        }
        let all = self.viewpoints();
        if all.is_empty() {
            return Err(self.field(
                "views",
                "[]",
                "at least one viewpoint: a view (e.g. \"A20\"), a plan or a [[pose]]",
            ));
        }
        let mut seen = BTreeSet::new();
        for v in &all {
            if !seen.insert(v.name()) {
                return Err(self.field(
                    "views / plan / pose",
                    format!("{:?}", v.name()),
                    "every viewpoint name once (a plan's view equal to a listed view, or two poses of one name)",
                ));
            }
        }
        Ok(())
    }

    /// A path from the job file, relative to its folder.
    pub fn resolve(&self, p: &str) -> PathBuf {
        let path = Path::new(p);
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.base_dir.join(path)
        }
    }

    /// Finish indices an object is made in.
    pub fn object_finishes(&self, object: usize) -> Vec<usize> {
        match &self.objects[object].finishes {
            None => (0..self.finishes.len()).collect(),
            Some(names) => names
                .iter()
                .filter_map(|n| self.finishes.iter().position(|f| &f.name == n))
                .collect(),
        }
    }

    /// Distinct defect geometries to sample.
    pub fn defect_sets(&self) -> usize {
        match self.defects.sets {
            Some(s) => s as usize,
            None => self
                .objects
                .iter()
                .map(|o| o.defective.max(0) as usize)
                .max()
                .unwrap_or(0),
        }
    }

    /// Linear post-processing rows per texture type, for the docs and the manifest.
    pub fn texture_types(&self) -> BTreeMap<String, Vec<String>> {
        let mut m: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for f in &self.finishes {
            m.entry(f.texture_type()).or_default().push(f.name.clone());
        }
        m
    }
}

/// The built-in test body a mesh string names, if any.
pub fn builtin_variant(mesh: &str) -> Option<crate::scene::Variant> {
    match mesh {
        "testbody-b" => Some(crate::scene::Variant::B),
        "testbody-m" => Some(crate::scene::Variant::M),
        _ => None,
    }
}

/// A viewpoint name "A20" (or "A20@45", with an azimuth in [-360, 360] degrees): face id
/// (1..=3) and degrees from the face normal in [0, 89].
pub fn parse_view(s: &str) -> Option<(u8, f64)> {
    let s = match s.split_once('@') {
        Some((v, az)) => {
            let az: f64 = az.parse().ok()?;
            if !(az.is_finite() && (-360.0..=360.0).contains(&az)) {
                return None;
            }
            v
        }
        None => s,
    };
    let mut chars = s.chars();
    let face = match chars.next()? {
        'A' => 1,
        'B' => 2,
        'C' => 3,
        _ => return None,
    };
    let deg: f64 = chars.as_str().parse().ok()?;
    (deg.is_finite() && (0.0..=89.0).contains(&deg)).then_some((face, deg))
}
