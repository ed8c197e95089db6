//! The interface between the dataset job and whatever makes the pixels: the job calls
//! [`ImageRenderer::render`] once per image. The production implementation is the GPU
//! path tracer plus annotation pass (`gpu.rs`); tests plug in a CPU test double.

use std::sync::Arc;

use crate::scene::Mesh;
use crate::scene::config::SceneConfig;

/// The scene configuration the GPU renderer renders one image with, validated: `base`
/// with the request's view, size, samples, bounces, seed and GGX alpha. `dataset check`
/// and `dataset run` (before the first image) run it for every instance and view, so a job
/// that passes the check does not fail on these settings later. Errors name the job's
/// field (`render.bounces`, not the scene file's `render.max_bounces`).
#[allow(clippy::too_many_arguments)]
pub fn render_config(
    base: &SceneConfig,
    view: &str,
    pose: Option<&super::job::JobPose>,
    width: u32,
    height: u32,
    spp: u32,
    bounces: u32,
    seed: u64,
    alpha: f32,
) -> Result<SceneConfig, String> {
    let job_names = |e: crate::scene::config::ConfigError| {
        e.to_string()
            .replace("render.max_bounces", "render.bounces")
            .replace("--width", "render.width")
            .replace("--height", "render.height")
            .replace("camera.view", "views")
            .replace("material.alpha", "material.alpha (GGX alpha, roughness^2)")
    };
    let mut cfg = base.clone();
    match pose {
        // A free pose: the view name is the pose's, not a face-relative view.
        Some(p) => p.apply(&mut cfg.camera),
        None => cfg.camera.view = view.to_string(),
    }
    cfg.set_resolution(width, height).map_err(job_names)?;
    cfg.render.spp = spp;
    cfg.render.max_bounces = bounces;
    // The shader takes a 32-bit seed: fold the 64-bit one.
    cfg.render.seed = (seed ^ (seed >> 32)) as u32;
    cfg.material.alpha = alpha;
    cfg.validate().map_err(job_names)?;
    Ok(cfg)
}

/// A slope map as the renderer takes it: the texture module's `SlopeMap` (row 0 at the
/// top, `[dh/dx, dh/dy]` unitless per texel of `spacing_um`), shared by `Arc` between the
/// cache and the renderer without copying.
pub type TextureMap = crate::texture::SlopeMap;

/// The texture on one inspected face: a planar projection in the face's frame
/// (`scene::face_frames`), rotated by `rotation_rad` and shifted by `offset_px` texture
/// pixels, centred on the face centre.
#[derive(Clone, Debug)]
pub struct FaceTexture {
    /// Face id (1 = A, 2 = B, 3 = C).
    pub face: u8,
    pub finish: String,
    /// Which of the finish's texture instances this is.
    pub texture_instance: u32,
    pub map: Arc<TextureMap>,
    pub rotation_rad: f32,
    pub offset_px: [f32; 2],
}

/// One image to make.
pub struct ImageRequest<'a> {
    /// The (defected) object with per-triangle face, class and instance labels.
    pub mesh: &'a Mesh,
    /// Identifies `mesh`: equal keys mean the same mesh, so a renderer may keep its
    /// acceleration structure between the views of one object instance.
    pub mesh_key: u64,
    /// Viewpoint name, e.g. "A20" (face A, 20 degrees from its normal, aimed at its centre;
    /// "A20@45" turns the tilt 45 degrees about the normal), or a `[[pose]]`'s name.
    pub view: &'a str,
    /// The free pose when the viewpoint is a `[[pose]]` (then `view` is only its name).
    pub pose: Option<&'a super::job::JobPose>,
    /// The camera's intrinsics and lens (the job's `[camera]`, `Job::camera_config`) at
    /// the camera's own resolution; the image is `width` x `height` of it (sensor size
    /// kept, as `render_config` does). Its pose fields are not used.
    pub camera: &'a crate::scene::config::CameraConfig,
    /// The job's `[[light]]` entries (checked); empty: the default ring on the camera.
    pub lights: &'a [crate::scene::lights::LightEntry],
    /// The object's materials per region (`[[object.material.region]]`, checked, with
    /// this instance's alpha where an entry gives none); empty: the whole object is the
    /// conductor of `alpha`.
    pub materials: &'a [crate::scene::materials::RegionMaterial],
    /// The glTF material of each triangle of `mesh` (for `gltf_material` selectors).
    pub gltf_materials: Option<&'a crate::scene::materials::GltfMaterials>,
    /// GGX alpha of the aluminium (appleseed / Disney roughness r = sqrt(alpha)).
    pub alpha: f32,
    pub face_textures: Vec<FaceTexture>,
    /// How the face textures spread over the object's other planar regions.
    pub placement: crate::scene::assemble::Placement,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel; with `noise` the most it may take.
    pub spp: u32,
    pub bounces: u32,
    pub seed: u64,
    /// Stop before `spp` once the render noise is below the camera's by this criterion
    /// (`[render] noise_target`; `camera::noise_stop`). None: exactly `spp`.
    pub noise: Option<&'a crate::render::noise::NoiseStop>,
    /// Where the labels come from (`[render] labels`; default "auto").
    pub labels: crate::scene::config::LabelSource,
    /// The direct light's estimator (`[render] direct_light`; default "analytic").
    pub direct_light: crate::scene::config::DirectLight,
    /// Camera rays per sample for the control variate's closed form
    /// (`[render] analytic_rays`; default 1).
    pub analytic_rays: u32,
    /// Light samples at the camera ray's first hit (`[render] light_samples`; default 1).
    pub light_samples: u32,
    /// BSDF samples for the direct light there (`[render] bsdf_samples`; default 1).
    pub bsdf_samples: u32,
    /// Whether those directions each continue as a path (`[render] split_paths`;
    /// default false).
    pub split_paths: bool,
    /// Samples per GPU submission (`[render] batch_spp`; default 16).
    pub batch_spp: u32,
    /// The object instance's scene (stage and acceleration structure) made by the run's
    /// preparing thread with the renderer's [`ImageRenderer::scene_prep`]; None: the
    /// renderer makes it (a GPU renderer uses it only for its own backend).
    pub scene: Option<&'a crate::render::PreparedScene>,
}

/// What the renderer returns, every buffer row-major with row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedImage {
    pub width: u32,
    pub height: u32,
    /// Linear radiance, >= 0.
    pub radiance: Vec<f32>,
    /// Defect class of the first hit: 0 none, 1 dent, 2 scratch.
    pub class: Vec<u8>,
    /// Defect instance id of the first hit, 0 = none.
    pub instance: Vec<u16>,
    /// Face id of the first hit: 0 other / background, 1 A, 2 B, 3 C.
    pub face: Vec<u8>,
    /// Defect coverage fraction of the pixel, in [0, 1].
    pub coverage: Vec<f32>,
    /// 1 where the first hit is the object, 0 for the table or nothing.
    pub object: Vec<u8>,
    /// With `[render] adaptive_radius`, each pixel's own samples when not all took the
    /// image's spp (written as spp.png); None: every pixel took them.
    pub pixel_spp: Option<Vec<u32>>,
}

impl RenderedImage {
    /// Checks sizes and values against the request, so a faulty renderer cannot write a
    /// broken image into the dataset.
    pub fn check(&self, req: &ImageRequest) -> Result<(), String> {
        if (self.width, self.height) != (req.width, req.height) {
            return Err(format!(
                "returned {}x{}, asked {}x{}",
                self.width, self.height, req.width, req.height
            ));
        }
        let n = self.width as usize * self.height as usize;
        let lens = [
            ("radiance", self.radiance.len()),
            ("class", self.class.len()),
            ("instance", self.instance.len()),
            ("face", self.face.len()),
            ("coverage", self.coverage.len()),
            ("object", self.object.len()),
        ];
        for (name, len) in lens {
            if len != n {
                return Err(format!("{name} has {len} values for {n} pixels"));
            }
        }
        // Finite; a pixel may be below zero: the analytic direct light's control variate
        // is unbiased, not positive (a shadowed highlight at low spp; the sensor and the
        // 8-bit image clamp it; docs/rendering.md, "Analytic direct light").
        if let Some(p) = self.radiance.iter().position(|v| !v.is_finite()) {
            return Err(format!("radiance at pixel {p} is {}", self.radiance[p]));
        }
        if let Some(p) = self.class.iter().position(|&c| c > 2) {
            return Err(format!("class at pixel {p} is {}", self.class[p]));
        }
        if let Some(p) = self.face.iter().position(|&f| f > 3) {
            return Err(format!("face at pixel {p} is {}", self.face[p]));
        }
        if let Some(p) = self.coverage.iter().position(|c| !(0.0..=1.0).contains(c)) {
            return Err(format!("coverage at pixel {p} is {}", self.coverage[p]));
        }
        if let Some(counts) = &self.pixel_spp {
            if counts.len() != n {
                return Err(format!(
                    "pixel_spp has {} values for {n} pixels",
                    counts.len()
                ));
            }
            if let Some(p) = counts.iter().position(|&c| c == 0 || c > req.spp) {
                return Err(format!(
                    "pixel {p} took {} samples, allowed [1, {}]",
                    counts[p], req.spp
                ));
            }
        }
        Ok(())
    }
}

/// Makes one image with its annotation.
pub trait ImageRenderer {
    /// A short description for the manifest (backend, device).
    fn describe(&self) -> String;
    fn render(&mut self, req: &ImageRequest) -> Result<RenderedImage, String>;
    /// Seconds spent in parts of the last `render` call, for the manifest's
    /// `stage_seconds` (names like "render.path_trace"); none by default.
    fn last_stages(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
    /// The timeline of the last `render` call (CPU phases, GPU passes) for a run's
    /// profile (`dataset run --profile`); none by default.
    fn last_profile(&self) -> Option<&crate::vk::Profiler> {
        None
    }
    /// Samples per pixel of the last `render` call and, when the request had a noise
    /// target, the criterion's estimates in order (the last at those samples); None: the
    /// request's `spp` (a renderer without the noise criterion ignores `noise`).
    fn last_samples(&self) -> Option<(u32, Vec<crate::render::noise::NoiseEstimate>)> {
        None
    }
    /// `[render] analytic_rays_max`: the camera rays per sample the last `render` call
    /// chose at its first check for the samples after it; None: no choice made.
    fn last_rays(&self) -> Option<u32> {
        None
    }
    /// How a run's preparing thread can make this renderer's scene of an object instance
    /// ahead of its views ([`ImageRequest::scene`]); None (the default): the renderer
    /// makes what it needs itself.
    fn scene_prep(&self) -> Option<super::gpu::ScenePrep> {
        None
    }
    /// The memory in live buffers and images on the renderer's device (with the
    /// renderers beside it and a run's preparing context: [`crate::vk::MemoryInUse`]);
    /// None (the default): it holds none. A run's profile records it after every image
    /// (the counter "device memory"), so that a leak shows as growth.
    fn device_memory(&self) -> Option<crate::vk::MemoryInUse> {
        None
    }
}
