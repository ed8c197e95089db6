//! Plain render settings: what the path tracer needs besides the scene, independent of
//! the scene file (`scene::config` converts into these).

pub use crate::scene::config::{
    DirectLight, LabelSource, LightSampling, SamplerKind, TextureFilter,
};
use crate::scene::config::{MaterialConfig, RenderConfig, SceneConfig};

/// The object's rough conductor (GGX, Kulla-Conty energy compensation optional).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// GGX alpha.
    pub alpha: f32,
    /// Complex index of refraction at the camera's wavelength.
    pub ior_n: f32,
    pub ior_k: f32,
    pub energy_compensation: bool,
}

impl From<&MaterialConfig> for Material {
    fn from(m: &MaterialConfig) -> Self {
        Material {
            alpha: m.alpha,
            ior_n: m.ior_n,
            ior_k: m.ior_k,
            energy_compensation: m.energy_compensation,
        }
    }
}

/// Sampling of one image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub spp: u32,
    /// Samples per pixel per dispatch (one graph each).
    pub batch_spp: u32,
    pub max_bounces: u32,
    pub seed: u32,
    pub sampler: SamplerKind,
    pub material: Material,
    /// Slope-map filtering (`[render] texture_filter`); "lean" needs the scene's maps
    /// uploaded with their moment pyramids (`GpuScene::set_face_maps_filtered`).
    pub texture_filter: TextureFilter,
    /// Footprint multiplier of "lean" (`[render] texture_filter_scale`).
    pub texture_filter_scale: f32,
    /// Where the labels come from when the render is annotated (`[render] labels`).
    pub labels: LabelSource,
    /// The direct light's estimator (`[render] direct_light`).
    pub direct_light: DirectLight,
    /// Camera rays per sample for the control variate's closed form
    /// (`[render] analytic_rays`).
    pub analytic_rays: u32,
    /// Light samples at the camera ray's first hit (`[render] light_samples`).
    pub light_samples: u32,
    /// BSDF samples for the direct light there (`[render] bsdf_samples`).
    pub bsdf_samples: u32,
    /// Whether those directions each continue as a path (`[render] split_paths`).
    pub split_paths: bool,
    /// Whether rays skip the lights' traversal where it cannot change their answer
    /// (`[render] light_shortcuts`).
    pub light_shortcuts: bool,
    /// Whether the path tracer's pipeline is compiled for these settings
    /// (`[render] specialize`).
    pub specialize: bool,
}

impl RenderSettings {
    pub fn new(r: &RenderConfig, material: &MaterialConfig) -> Self {
        RenderSettings {
            spp: r.spp,
            batch_spp: r.batch_spp,
            max_bounces: r.max_bounces,
            seed: r.seed,
            sampler: r.sampler,
            material: material.into(),
            texture_filter: r.texture_filter,
            texture_filter_scale: r.texture_filter_scale,
            labels: r.labels,
            direct_light: r.direct_light,
            analytic_rays: r.analytic_rays,
            light_samples: r.light_samples,
            bsdf_samples: r.bsdf_samples,
            split_paths: r.split_paths,
            light_shortcuts: r.light_shortcuts,
            specialize: r
                .specialize
                .unwrap_or_else(|| specialize_from_env().ok().flatten().unwrap_or(false)),
        }
    }
}

/// `SYNOSIS_SPECIALIZE`: "1" or "0" turns `[render] specialize` on or off for every
/// render of the process whose settings do not say (a dataset job's renders, which take
/// no such setting, included); unset or empty: None. Another value is an error (the CLI
/// checks it at its start; where it is not checked it is ignored).
pub fn specialize_from_env() -> Result<Option<bool>, String> {
    match std::env::var("SYNOSIS_SPECIALIZE") {
        Err(_) => Ok(None),
        Ok(v) => match v.trim() {
            "" => Ok(None),
            "1" => Ok(Some(true)),
            "0" => Ok(Some(false)),
            other => Err(format!(
                "SYNOSIS_SPECIALIZE={other:?}: allowed \"0\" (the path tracer reads its settings at run time) or \"1\" (compiled for them)"
            )),
        },
    }
}

impl From<&SceneConfig> for RenderSettings {
    fn from(cfg: &SceneConfig) -> Self {
        RenderSettings::new(&cfg.render, &cfg.material)
    }
}
