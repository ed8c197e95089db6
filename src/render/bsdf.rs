//! The object's BSDF on the CPU, mirroring glsl/common/ggx.glsl line by line (f32, same
//! formulas), so tests can check sampling and energy without a GPU and the tables in
//! `energy` use exactly the model the shader evaluates.
//!
//! Local frame: the shading normal is +z; `wo` points away from the surface (towards
//! the viewer), `wi` towards the light. GGX after Walter et al. 2007, separable
//! (uncorrelated) Smith masking-shadowing G1(wo) G1(wi) (not the height-correlated form;
//! see `ggx_g2` for why), visible-normal sampling (Heitz 2018).

use std::f32::consts::PI;

use glam::Vec3;

use super::energy::EnergyTables;

/// Alpha below this is clamped: D's peak 1/(pi alpha^2) must stay finite in f32.
pub const ALPHA_MIN: f32 = 1e-4;

pub fn clamp_alpha(alpha: f32) -> f32 {
    alpha.clamp(ALPHA_MIN, 1.0)
}

/// GGX normal distribution D(h).
pub fn ggx_d(alpha: f32, h: Vec3) -> f32 {
    if h.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let c2 = h.z * h.z;
    let t = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * t * t)
}

/// Smith Lambda for GGX.
pub fn ggx_lambda(alpha: f32, w: Vec3) -> f32 {
    let c2 = (w.z * w.z).max(1e-12);
    let t2 = ((1.0 - c2) / c2).max(0.0);
    0.5 * (-1.0 + (1.0 + alpha * alpha * t2).sqrt())
}

pub fn ggx_g1(alpha: f32, w: Vec3) -> f32 {
    1.0 / (1.0 + ggx_lambda(alpha, w))
}

/// Separable masking-shadowing G1(wo) G1(wi), as Mitsuba 3's rough conductor (our
/// reference renderer) and the white-furnace constants in QUALITY.md use. The
/// height-correlated form (Heitz 2014) would give E_avg 0.847 / 0.409 instead of
/// 0.843 / 0.377 at alpha 0.3 / 1; compensation removes most of the difference.
pub fn ggx_g2(alpha: f32, wo: Vec3, wi: Vec3) -> f32 {
    ggx_g1(alpha, wo) * ggx_g1(alpha, wi)
}

/// Samples a visible normal for `wo` (wo.z > 0), Heitz 2018 (isotropic).
pub fn sample_vndf(alpha: f32, wo: Vec3, u1: f32, u2: f32) -> Vec3 {
    let vh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    let p1 = r * phi.cos();
    let mut p2 = r * phi.sin();
    let s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

/// Density of `sample_vndf` in the direction `wi = reflect(wo, h)` (solid angle).
pub fn vndf_reflect_pdf(alpha: f32, wo: Vec3, wi: Vec3) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let h = (wo + wi).normalize();
    ggx_g1(alpha, wo) * ggx_d(alpha, h) / (4.0 * wo.z)
}

/// Unpolarised Fresnel reflectance of a conductor with complex IOR n + ik (pbrt's
/// FrConductor, exact for real angles).
pub fn fresnel_conductor(cos_i: f32, n: f32, k: f32) -> f32 {
    let c = cos_i.clamp(0.0, 1.0);
    let c2 = c * c;
    let s2 = 1.0 - c2;
    let t0 = n * n - k * k - s2;
    let a2b2 = (t0 * t0 + 4.0 * n * n * k * k).sqrt();
    let t1 = a2b2 + c2;
    let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
    let t2 = 2.0 * a * c;
    let rs = (t1 - t2) / (t1 + t2);
    let t3 = c2 * a2b2 + s2 * s2;
    let t4 = t2 * s2;
    let rp = rs * (t3 - t4) / (t3 + t4);
    (0.5 * (rp + rs)).clamp(0.0, 1.0)
}

/// Hemispherical average 2 * int F(mu) mu dmu (midpoint rule, 1024 nodes).
pub fn fresnel_average(n: f32, k: f32) -> f32 {
    let m = 1024;
    let s: f64 = (0..m)
        .map(|i| {
            let mu = (i as f64 + 0.5) / m as f64;
            fresnel_conductor(mu as f32, n, k) as f64 * mu
        })
        .sum();
    (2.0 * s / m as f64) as f32
}

/// Fresnel model: F = 1 (furnace tests) or a conductor.
#[derive(Clone, Copy, Debug)]
pub enum Fresnel {
    One,
    Conductor { n: f32, k: f32 },
}

impl Fresnel {
    pub fn eval(self, cos: f32) -> f32 {
        match self {
            Fresnel::One => 1.0,
            Fresnel::Conductor { n, k } => fresnel_conductor(cos, n, k),
        }
    }
    pub fn average(self) -> f32 {
        match self {
            Fresnel::One => 1.0,
            Fresnel::Conductor { n, k } => fresnel_average(n, k),
        }
    }
}

/// A sampled direction: `weight` = f * cos / pdf.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    pub weight: f32,
    pub pdf: f32,
}

/// The rough conductor, optionally with Kulla-Conty multiple-scattering compensation.
pub struct Conductor<'a> {
    pub alpha: f32,
    pub fresnel: Fresnel,
    /// (tables, F_avg) when compensation is on.
    pub compensation: Option<(&'a EnergyTables, f32)>,
}

impl Conductor<'_> {
    pub fn new(alpha: f32, fresnel: Fresnel, tables: Option<&EnergyTables>) -> Conductor<'_> {
        Conductor {
            alpha: clamp_alpha(alpha),
            fresnel,
            compensation: tables.map(|t| (t, fresnel.average())),
        }
    }

    /// Probability of picking the multiple-scattering (cosine) lobe when sampling.
    fn ms_prob(&self, wo: Vec3) -> f32 {
        match self.compensation {
            Some((t, _)) => (1.0 - t.e(wo.z, self.alpha)).clamp(0.0, 1.0),
            None => 0.0,
        }
    }

    /// Kulla-Conty lobe times cos(wi): (1-E(mu_o))(1-E(mu_i)) / (pi (1-E_avg)) * F_ms.
    fn ms_eval_cos(&self, wo: Vec3, wi: Vec3) -> f32 {
        let Some((t, f_avg)) = self.compensation else {
            return 0.0;
        };
        let e_avg = t.e_avg(self.alpha);
        if e_avg >= 1.0 - 1e-6 {
            return 0.0;
        }
        let f_ms = f_avg * f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg));
        (1.0 - t.e(wo.z, self.alpha)) * (1.0 - t.e(wi.z, self.alpha)) / (PI * (1.0 - e_avg))
            * f_ms
            * wi.z
    }

    /// f(wo, wi) * cos(wi).
    pub fn eval_cos(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let h = (wo + wi).normalize();
        let ss = self.fresnel.eval(wo.dot(h)) * ggx_d(self.alpha, h) * ggx_g2(self.alpha, wo, wi)
            / (4.0 * wo.z);
        ss + self.ms_eval_cos(wo, wi)
    }

    /// Solid-angle density of `sample`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let p = self.ms_prob(wo);
        (1.0 - p) * vndf_reflect_pdf(self.alpha, wo, wi) + p * wi.z / PI
    }

    /// Samples wi from three uniform numbers: `u[0]` picks the lobe.
    pub fn sample(&self, wo: Vec3, u: [f32; 3]) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let p = self.ms_prob(wo);
        let wi = if u[0] < p {
            cosine_hemisphere(u[1], u[2])
        } else {
            let h = sample_vndf(self.alpha, wo, u[1], u[2]);
            2.0 * wo.dot(h) * h - wo
        };
        if wi.z <= 0.0 {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        if pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight: self.eval_cos(wo, wi) / pdf,
            pdf,
        })
    }
}

/// Cosine-weighted hemisphere direction (Malley's method, concentric-free polar form).
pub fn cosine_hemisphere(u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

/// Low-discrepancy 2D point i of n (Hammersley with the radical inverse in base 2).
pub fn hammersley(i: u32, n: u32) -> (f32, f32) {
    (
        (i as f32 + 0.5) / n as f32,
        i.reverse_bits() as f32 * (1.0 / 4_294_967_296.0),
    )
}
