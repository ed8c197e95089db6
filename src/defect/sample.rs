//! Sampling defect placements and parameters: positions uniform over the inspected faces
//! (area-weighted triangle, uniform barycentric point), rejected and redrawn while the
//! defect would cross its face's border.

use glam::DVec2;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};

use super::DefectError;
use super::region::Region;
use super::spec::{DefectSpec, DentSpec, Range, ScratchProfile, ScratchSpec};
use super::tool::DefectTool;
use crate::scene::Mesh;
use crate::scene::mesh::{CLASS_DENT, CLASS_SCRATCH, FaceId, face_from_name, face_name};

/// An ellipsoidal dent in face-local coordinates (mm). The imprint is the lower half of
/// an ellipsoid with semi-axes (diameter/2, minor/2, depth) centred on the face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dent {
    pub centre_uv_mm: [f64; 2],
    /// Major axis of the footprint ellipse.
    pub diameter_mm: f64,
    /// Minor axis (diameter / elongation).
    pub minor_mm: f64,
    /// Angle of the major axis from the face's u axis.
    pub rotation_deg: f64,
    pub depth_mm: f64,
    /// Rim height above the face (0: no rim).
    pub rim_height_mm: f64,
    /// Rim extent as a fraction of the semi-axes.
    pub rim_width: f64,
}

/// A scratch: a polyline in face-local coordinates swept with its profile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scratch {
    pub path_uv_mm: Vec<[f64; 2]>,
    /// Depth at each path point (linear in between).
    pub depth_mm: Vec<f64>,
    pub width_mm: f64,
    /// Length of the path polyline.
    pub length_mm: f64,
    pub step_mm: f64,
    pub curviness_deg: f64,
    /// The cross-section (sidecars written before it existed: parabolic).
    #[serde(default)]
    pub profile: ScratchProfile,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Shape {
    Dent(Dent),
    Scratch(Scratch),
}

/// One defect: where (face + face-local shape) and what (class, instance, spec name).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Defect {
    /// 1 ... n, unique within a set; the label of its triangles.
    pub instance: u16,
    /// 1 dent, 2 scratch.
    pub class: u8,
    /// The spec entry it was drawn from ("small dent", ...).
    pub name: String,
    /// "A", "B" or "C".
    pub face: String,
    pub shape: Shape,
}

impl Defect {
    pub fn face_id(&self) -> Option<FaceId> {
        face_from_name(&self.face).filter(|&f| f != 0)
    }
}

/// A sampled set of defects. Face-local, so it re-applies to any mesh with the same
/// labelled faces (e.g. both test body variants). This is the JSON sidecar.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DefectSet {
    pub seed: u64,
    /// Vertices across each defect's narrowest dimension when imprinted.
    pub resolution: f64,
    pub defects: Vec<Defect>,
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// The generator for defect `k` of job `seed`: independent of how many tries the other
/// defects needed, so each defect can be re-made alone.
fn defect_rng(seed: u64, k: usize) -> Pcg64 {
    Pcg64::seed_from_u64(splitmix(seed ^ splitmix(k as u64 ^ 0x5EED_DEFE_C700_0000)))
}

fn uniform(rng: &mut Pcg64, r: Range) -> f64 {
    r.min + (r.max - r.min) * rng.random::<f64>()
}

/// Area-weighted point picking over all inspected faces.
struct Picker<'a> {
    regions: &'a [Region],
    /// (region, triangle in region, cumulative area)
    cum: Vec<(usize, usize, f64)>,
}

impl<'a> Picker<'a> {
    fn new(regions: &'a [Region]) -> Self {
        let mut cum = Vec::new();
        let mut total = 0.0;
        for (ri, r) in regions.iter().enumerate() {
            for (ti, (_, [a, b, c])) in r.tris.iter().enumerate() {
                total += 0.5 * (*b - *a).perp_dot(*c - *a).abs();
                cum.push((ri, ti, total));
            }
        }
        Picker { regions, cum }
    }

    fn total(&self) -> f64 {
        self.cum.last().map_or(0.0, |c| c.2)
    }

    fn pick(&self, rng: &mut Pcg64) -> (usize, DVec2) {
        let x = rng.random::<f64>() * self.total();
        let i = self
            .cum
            .partition_point(|c| c.2 <= x)
            .min(self.cum.len() - 1);
        let (ri, ti, _) = self.cum[i];
        let [a, b, c] = self.regions[ri].tris[ti].1;
        let (mut s, mut t) = (rng.random::<f64>(), rng.random::<f64>());
        if s + t > 1.0 {
            (s, t) = (1.0 - s, 1.0 - t);
        }
        (ri, a + (b - a) * s + (c - a) * t)
    }
}

/// Draws the defects of `spec` on the inspected faces of `mesh`, deterministically from
/// `seed`. Parameters are drawn once per defect; position (and, for scratches, heading
/// and walk) are redrawn until the defect lies inside one face, at most `max_tries`.
pub fn sample_defects(mesh: &Mesh, spec: &DefectSpec, seed: u64) -> Result<DefectSet, DefectError> {
    spec.validate()?;
    let faces: Vec<FaceId> = spec
        .faces
        .iter()
        .filter_map(|f| face_from_name(f))
        .collect();
    let regions = Region::of_mesh(mesh, &faces);
    let picker = Picker::new(&regions);
    if regions.is_empty() || picker.total().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(DefectError::NoFace {
            faces: spec.faces.join(", "),
        });
    }
    let mut defects = Vec::with_capacity(spec.count());
    let mut k = 0usize;
    for d in &spec.dent {
        for _ in 0..d.quantity {
            let mut rng = defect_rng(seed, k);
            k += 1;
            defects.push(sample_dent(d, &picker, &mut rng, k as u16, spec)?);
        }
    }
    for s in &spec.scratch {
        for _ in 0..s.quantity {
            let mut rng = defect_rng(seed, k);
            k += 1;
            defects.push(sample_scratch(s, &picker, &mut rng, k as u16, spec)?);
        }
    }
    Ok(DefectSet {
        seed,
        resolution: spec.resolution,
        defects,
    })
}

fn sample_dent(
    d: &DentSpec,
    picker: &Picker,
    rng: &mut Pcg64,
    instance: u16,
    spec: &DefectSpec,
) -> Result<Defect, DefectError> {
    let diameter = uniform(rng, d.diameter_mm);
    let elongation = uniform(rng, d.elongation);
    let depth = uniform(rng, d.depth) * diameter;
    let rotation = uniform(rng, d.rotation_deg);
    let rim = uniform(rng, d.rim_height) * depth;
    for _ in 0..spec.max_tries {
        let (ri, p) = picker.pick(rng);
        let region = &picker.regions[ri];
        let defect = Defect {
            instance,
            class: CLASS_DENT,
            name: d.name.clone(),
            face: face_name(region.face).into(),
            shape: Shape::Dent(Dent {
                centre_uv_mm: p.to_array(),
                diameter_mm: diameter,
                minor_mm: diameter / elongation,
                rotation_deg: rotation,
                depth_mm: depth,
                rim_height_mm: rim,
                rim_width: d.rim_width,
            }),
        };
        if DefectTool::new(&defect, spec.resolution).fits(region) {
            return Ok(defect);
        }
    }
    Err(DefectError::NoFit {
        name: d.name.clone(),
        instance,
        size_mm: diameter,
        tries: spec.max_tries,
    })
}

fn sample_scratch(
    s: &ScratchSpec,
    picker: &Picker,
    rng: &mut Pcg64,
    instance: u16,
    spec: &DefectSpec,
) -> Result<Defect, DefectError> {
    let width = uniform(rng, s.width_mm);
    let depth = uniform(rng, s.depth) * width;
    let length = uniform(rng, s.path_length_mm);
    let curviness = uniform(rng, s.curviness_deg);
    let steps = (length / s.step_mm).ceil().max(1.0) as usize;
    // Depth varies smoothly: independent factors every ~1 mm of path, linear between.
    let controls = (length.ceil() as usize).max(1) + 1;
    let factors: Vec<f64> = (0..controls)
        .map(|_| 1.0 - s.depth_variation * rng.random::<f64>())
        .collect();
    let factor_at = |arc: f64| {
        let x = (arc / length * (controls - 1) as f64).clamp(0.0, (controls - 1) as f64);
        let i = (x.floor() as usize).min(controls - 2);
        let j = (i + 1).min(controls - 1);
        factors[i] + (factors[j] - factors[i]) * (x - i as f64)
    };
    let turn = Normal::new(0.0, curviness.to_radians()).map_err(|e| DefectError::Spec {
        field: format!("scratch ({}).curviness_deg", s.name),
        value: curviness.to_string(),
        allowed: e.to_string(),
    })?;
    for _ in 0..spec.max_tries {
        let (ri, start) = picker.pick(rng);
        let region = &picker.regions[ri];
        let mut heading = rng.random::<f64>() * std::f64::consts::TAU;
        let mut pts = vec![start];
        let mut p = start;
        for i in 0..steps {
            if i > 0 {
                heading += turn.sample(rng);
            }
            let len = s.step_mm.min(length - i as f64 * s.step_mm);
            if len <= 1e-9 {
                break;
            }
            p += DVec2::new(heading.cos(), heading.sin()) * len;
            pts.push(p);
        }
        let mut arc = 0.0;
        let mut depths = Vec::with_capacity(pts.len());
        for i in 0..pts.len() {
            if i > 0 {
                arc += (pts[i] - pts[i - 1]).length();
            }
            depths.push(depth * factor_at(arc));
        }
        let defect = Defect {
            instance,
            class: CLASS_SCRATCH,
            name: s.name.clone(),
            face: face_name(region.face).into(),
            shape: Shape::Scratch(Scratch {
                path_uv_mm: pts.iter().map(|q| q.to_array()).collect(),
                depth_mm: depths,
                width_mm: width,
                length_mm: arc,
                step_mm: s.step_mm,
                curviness_deg: curviness,
                profile: s.profile,
            }),
        };
        if DefectTool::new(&defect, spec.resolution).fits(region) {
            return Ok(defect);
        }
    }
    Err(DefectError::NoFit {
        name: s.name.clone(),
        instance,
        size_mm: length,
        tries: spec.max_tries,
    })
}
