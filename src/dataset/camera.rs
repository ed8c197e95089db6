//! The camera of a job's images and its sensor step: the intrinsics every image is
//! rendered with (recorded in the manifest, so `dataset postprocess` can re-do the
//! sensor without the calibration file), the per-image random exposure (the paper's
//! "random exposure" augmentation, `[sensor] exposure_jitter_ev`), and the step that
//! turns an image's linear radiance into the 8-bit units the post-processing steps take:
//! the linear model (`[sensor] exposure = <number>`) or the EMVA 1288 sensor
//! (`src/render/sensor.rs`). docs/dataset.md, "Camera and sensor".

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::job::{Job, SensorModel};
use super::seed::{derive, tag};
use crate::render::pixels::{Exposure, FULL_SCALE};
use crate::render::sensor::{Responsivity, capture, exposure_time_s, max_code};
use crate::scene::Camera;
use crate::scene::calibration::{Distortion, Intrinsics};
use crate::scene::config::CameraConfig;
use crate::scene::mesh::is_inspected;

/// The intrinsics and lens of an image, at the rendered resolution (the manifest's
/// `camera`): OpenCV's camera matrix (pixel centres at integer coordinates) and
/// distortion, the pixel pitch and focal length, the lens.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    pub width: u32,
    pub height: u32,
    /// Focal lengths in pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point, pixels (OpenCV: 0 = centre of the first pixel).
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2, k3 (OpenCV's order).
    pub distortion: [f32; 5],
    /// Pixel pitch at this resolution (the sensor's size over `width`), µm.
    pub pixel_um: f32,
    /// Focal length, mm.
    pub focal_mm: f32,
    /// Distance of the face-relative views' pinhole from the face centre, mm (free
    /// poses place the camera themselves). Default 0 for records without it.
    #[serde(default)]
    pub working_distance_mm: f32,
    /// Working f-number; None: pinhole.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_number: Option<f64>,
    /// Plane in focus, mm along the view axis (None: the working distance).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus_distance_mm: Option<f32>,
    /// The calibration file as the job names it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
}

impl CameraRecord {
    /// The record of a scene camera at its resolution (after `set_resolution`): the
    /// calibration scaled to the image (as the renderer's camera), or the centred
    /// pinhole of `focal_mm` and `pixel_um`.
    pub fn of(cam: &CameraConfig) -> CameraRecord {
        let k = match &cam.intrinsics {
            Some(k) => k.scaled(cam.width, cam.height),
            None => {
                let f = cam.focal_mm as f64 / (cam.pixel_um as f64 * 1e-3);
                Intrinsics {
                    fx: f,
                    fy: f,
                    cx: cam.width as f64 * 0.5 - 0.5,
                    cy: cam.height as f64 * 0.5 - 0.5,
                    width: cam.width,
                    height: cam.height,
                    distortion: Distortion::default(),
                }
            }
        };
        let d = k.distortion;
        CameraRecord {
            width: k.width,
            height: k.height,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            distortion: [d.k1, d.k2, d.p1, d.p2, d.k3],
            pixel_um: cam.pixel_um,
            focal_mm: cam.focal_mm,
            working_distance_mm: cam.working_distance_mm,
            f_number: cam.f_number,
            focus_distance_mm: cam.focus_distance_mm,
            calibration: cam.calibration.as_ref().map(|p| p.display().to_string()),
        }
    }

    pub fn intrinsics(&self) -> Intrinsics {
        let [k1, k2, p1, p2, k3] = self.distortion;
        Intrinsics {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            width: self.width,
            height: self.height,
            distortion: Distortion { k1, k2, p1, p2, k3 },
        }
    }

    /// A camera with these intrinsics in a fixed pose (looking down +Z): what the
    /// sensor's responsivity needs (it depends on the rays relative to the optical
    /// axis, not on the pose). Run and postprocess both build it from the record, so
    /// they compute the same numbers.
    pub fn sensor_camera(&self) -> Camera {
        Camera::look(
            glam::Vec3::ZERO,
            glam::Vec3::Z,
            -glam::Vec3::Y,
            40.0,
            self.width,
            self.height,
        )
        .with_intrinsics(&self.intrinsics())
    }
}

/// The exposure jitter of one image in EV stops (exposure factor 2^ev): drawn from
/// `[sensor] exposure_jitter_ev` with the image seed (`derive(seed, [EXPOSURE])`):
/// with probability `exposure_jitter_probability` ev ~ U(min, max), else 0. None when
/// the job has no jitter.
pub fn exposure_jitter_ev(job: &Job, image_seed: u64) -> Option<f64> {
    let [lo, hi] = job.sensor.exposure_jitter_ev?;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(derive(image_seed, &[tag::EXPOSURE]));
    let apply = rng.random::<f64>() < job.sensor.exposure_jitter_probability;
    let ev = rng.random_range(lo..=hi);
    Some(if apply { ev } else { 0.0 })
}

/// An image after the sensor, in 8-bit units, and the exposure it got.
#[derive(Clone, Debug, PartialEq)]
pub struct Exposed {
    /// 8-bit units (0..=255 as f32), the post-processing steps' scale.
    pub image: Vec<f32>,
    /// The EMVA sensor's exposure time (auto or fixed, times the finish's factor and the
    /// jitter), ms; None for the linear model.
    pub exposure_ms: Option<f64>,
    /// The jitter drawn for this image (EV stops); None without `exposure_jitter_ev`.
    pub exposure_ev: Option<f64>,
}

/// The finish's exposure factor (1 when it has none) and the image's random exposure
/// in EV stops (None when the job has no jitter), shared by the sensor step and the
/// noise target so both expose alike.
fn exposure_scale(job: &Job, finish: &str, image_seed: u64) -> (f64, Option<f64>) {
    let finish_factor = job
        .finishes
        .iter()
        .find(|f| f.name == finish)
        .map_or(1.0, |f| f.exposure_factor());
    (finish_factor, exposure_jitter_ev(job, image_seed))
}

/// The lens's working f-number, which the EMVA sensor's radiometry needs.
fn lens_f_number(camera: &CameraRecord) -> Result<f64, String> {
    camera.f_number.ok_or_else(|| {
        "the [sensor] model needs camera.f_number (the lens's working f-number)".into()
    })
}

/// The sensor step of one image: linear radiance (row-major, `camera`'s size) to 8-bit
/// units. `finish`: the image's finish (its `exposure` factor); `faces`: the first hit's
/// face id per pixel (auto exposure looks at faces 1..=3); `image_seed`: the image's seed
/// (noise: `derive(seed, [SENSOR])`, jitter: `derive(seed, [EXPOSURE])`).
///
/// Linear model: `255 * exposure * finish exposure * 2^ev * L` (without jitter exactly
/// the factor of before). EMVA 1288: exposure time (fixed or auto) times the finish's
/// factor and 2^ev, then `render::sensor::capture` (with `diffraction`, on the radiance
/// convolved with the lens's Airy pattern, `render::optics`); codes scaled to 8-bit units by
/// `255 / (2^bit_depth - 1)` (8 bit: the codes themselves).
pub fn expose(
    job: &Job,
    finish: &str,
    image_seed: u64,
    camera: &CameraRecord,
    radiance: &[f32],
    faces: &[u8],
) -> Result<Exposed, String> {
    let (finish_factor, ev) = exposure_scale(job, finish, image_seed);
    match &job.sensor.model {
        SensorModel::Linear { exposure } => {
            let mut factor = exposure * finish_factor;
            if let Some(ev) = ev {
                factor *= ev.exp2();
            }
            Ok(Exposed {
                image: Exposure::new(factor as f32, 1.0).units8(radiance),
                exposure_ms: None,
                exposure_ev: ev,
            })
        }
        SensorModel::Emva(sensor) => {
            let n = lens_f_number(camera)?;
            let resp =
                Responsivity::new(&camera.sensor_camera(), camera.focal_mm as f64, n, sensor);
            let mask: Vec<bool> = faces.iter().map(|&f| is_inspected(f)).collect();
            // The lens's diffraction on the radiance the sensor sees.
            let seen = crate::render::optics::seen_by_sensor(
                radiance,
                camera.width as usize,
                camera.height as usize,
                camera.pixel_um as f64,
                n,
                sensor,
                None,
            );
            let radiance = &seen[..];
            let t = exposure_time_s(&resp, radiance, Some(&mask), sensor)
                .map_err(|e| e.to_string())?
                * finish_factor
                * ev.map_or(1.0, f64::exp2);
            let cap = capture(
                &resp,
                radiance,
                t,
                sensor,
                derive(image_seed, &[tag::SENSOR]),
            )
            .map_err(|e| e.to_string())?;
            let scale = (FULL_SCALE as f64 / max_code(sensor.bit_depth)) as f32;
            Ok(Exposed {
                image: cap.codes.iter().map(|&c| c as f32 * scale).collect(),
                exposure_ms: Some(t * 1e3),
                exposure_ev: ev,
            })
        }
    }
}

/// The noise criterion of `[render] noise_target` for one image: the camera's
/// responsivity (from the record, as the sensor step builds it), its EMVA sensor and the
/// factor the sensor step puts on the exposure time (the finish's `exposure`, the image's
/// jitter 2^ev). None without a target; an error for the linear model (the job's check
/// refuses that) or an EMVA sensor without `camera.f_number`.
pub fn noise_stop(
    job: &Job,
    finish: &str,
    image_seed: u64,
    camera: &CameraRecord,
) -> Result<Option<crate::render::noise::NoiseStop>, String> {
    let Some(target) = job.render.noise_target else {
        return Ok(None);
    };
    let SensorModel::Emva(sensor) = &job.sensor.model else {
        return Err("render.noise_target needs the EMVA 1288 sensor".into());
    };
    let n = lens_f_number(camera)?;
    let (finish_factor, ev) = exposure_scale(job, finish, image_seed);
    Ok(Some(crate::render::noise::NoiseStop {
        camera: crate::render::noise::CameraNoise {
            resp: Responsivity::new(&camera.sensor_camera(), camera.focal_mm as f64, n, sensor),
            sensor: sensor.clone(),
            exposure_factor: finish_factor * ev.map_or(1.0, f64::exp2),
        },
        target,
        min_spp: job.render.first_check_spp(),
        estimator: job.render.noise_estimate.unwrap_or_default(),
        adaptive_radius: job.render.adaptive_radius.map(|r| r as u32),
        growth: job.render.noise_target_growth.unwrap_or(0.0),
        rays: job.render.analytic_rays_max.map(|max| {
            crate::render::noise::RayChoice::up_to(max as u32, job.render.analytic_ray_cost)
        }),
    }))
}
