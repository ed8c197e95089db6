//! Scene assembly on the CPU: the object on its table (one [`Stage`] per mesh), the
//! camera for a view and the ring light mounted on it (one [`ViewSetup`] per image), and
//! the slope maps a scene file asks for. Plain data: the renderer uploads a stage once
//! (`render::GpuScene`) and a view per image (`render::View`).

use std::sync::Arc;

use glam::{DVec3, Vec3};

use super::camera::Camera;
use super::config::{
    CameraConfig, ConfigError, LightConfig, LightSampling, ObjectConfig, Pose, SceneConfig,
    TableConfig, TextureConfig, View,
};
use super::curved::{
    CurvedPatch, CurvedTolerance, PatchKind, curved_patches, encode_normal, smooth_corner_normals,
};
use super::lights::{LightShape, LightSpec};
use super::materials::{GltfMaterials, RegionMaterial, SurfaceMaterial};
use super::mesh::{FACE_OTHER, FaceId, TriLabel, face_name};
use super::regions::{RegionTolerance, planar_regions, region_per_triangle};
use super::testbody::{FaceFrame, face_frames};
use super::{Mesh, MeshError};
use crate::gpu_interface::{MAT_CONDUCTOR, MAT_REGION_FIRST, MAT_TABLE};
use crate::texture::{SlopeMap, TextureError};
use crate::trace::TriangleSoup;

/// Why a scene could not be assembled.
#[derive(Debug, thiserror::Error)]
pub enum AssembleError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("the mesh has no triangles labelled as face {0} (needed for the view)")]
    NoFace(&'static str),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("texture.path: {0}")]
    Texture(#[from] TextureError),
    #[error("slope map for face {face}: {message}")]
    Placement { face: &'static str, message: String },
}

/// A slope map placed on one inspected face.
#[derive(Clone, Debug)]
pub struct FaceMap {
    pub face: FaceId,
    pub slopes: Arc<SlopeMap>,
    /// Rotation of the map about the face normal, degrees, from `u` towards `v`.
    pub rotation_deg: f32,
    /// Map centre relative to the face centre along (u, v), mm.
    pub offset_mm: [f32; 2],
}

pub use super::config::{Cover, DefectSurface};

/// How the face maps are spread over the object's planar regions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub cover: Cover,
    /// Seeds the choices for regions without a face map of their own.
    pub seed: u64,
    /// Those regions' map rotation is uniform in [-range, range], degrees, from their `u`.
    pub rotation_range_deg: f32,
    /// Whether dents and scratches carry the map (applied when the stage is built,
    /// [`Stage::burnish_defects`]).
    pub defects: DefectSurface,
}

impl Default for Placement {
    fn default() -> Self {
        Placement {
            cover: Cover::Part,
            seed: 0,
            rotation_range_deg: 0.0,
            defects: DefectSurface::Textured,
        }
    }
}

/// A planar region of the object (`scene::regions`), where a slope map is projected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionFrame {
    /// The region's stable id (`PlanarRegion::id`).
    pub id: u32,
    /// The inspected face (A, B, C) it holds, else `FACE_OTHER`.
    pub face: FaceId,
    pub centre: Vec3,
    pub normal: Vec3,
    pub u: Vec3,
    pub v: Vec3,
}

/// A slope map projected onto one region: map centre and axes in world space (mm).
#[derive(Clone, Debug)]
pub struct PlacedMap {
    pub region: u32,
    pub slopes: Arc<SlopeMap>,
    pub centre: Vec3,
    /// Map x axis (image right).
    pub axis_x: Vec3,
    /// Map up axis (image -y).
    pub axis_up: Vec3,
    /// Repeat the map beyond its edges (else zero slopes outside it).
    pub wrap: bool,
    /// Only the region's triangles labelled A, B or C get the map (`Cover::Faces`).
    pub labelled_only: bool,
}

/// Spreads the per-face maps over the object's regions (docs/texture.md, "Finishes on
/// the whole part"):
/// - a region of an inspected face gets that face's map, placed in the face's frame
///   (`FaceFrame`: centred on the labelled square) by its rotation and offset;
/// - with `Cover::Part`, every other region gets one of the maps (the region id, mixed
///   with the seed, picks it), a rotation uniform in `[-range, range]` from its own `u`
///   and a centre offset uniform over the map's extent along its own `(u, v)`, all drawn
///   from `placement.seed` and the region id; maps repeat beyond their edges.
///
/// A map on a face the mesh does not have is refused (a typo must not render flat).
pub fn place_maps(
    maps: &[FaceMap],
    face_frames: &[FaceFrame],
    regions: &[RegionFrame],
    placement: &Placement,
) -> Result<Vec<PlacedMap>, AssembleError> {
    use rand::{Rng, SeedableRng};
    let mut by_face: Vec<(&FaceMap, &FaceFrame)> = Vec::new();
    for m in maps {
        let bad = |message: &str| AssembleError::Placement {
            face: face_name(m.face),
            message: message.into(),
        };
        let frame = face_frames
            .iter()
            .find(|f| f.face == m.face)
            .ok_or_else(|| bad("the mesh has no such face"))?;
        if !(m.rotation_deg.is_finite() && m.offset_mm.iter().all(|v| v.is_finite())) {
            return Err(bad("rotation and offset must be finite"));
        }
        if by_face.iter().any(|(o, _)| o.face == m.face) {
            return Err(bad("two maps on one face"));
        }
        by_face.push((m, frame));
    }
    let wrap = placement.cover == Cover::Part;
    let mut out = Vec::new();
    for r in regions {
        if let Some((m, f)) = by_face.iter().find(|(m, _)| m.face == r.face) {
            let (sin, cos) = m.rotation_deg.to_radians().sin_cos();
            out.push(PlacedMap {
                region: r.id,
                slopes: m.slopes.clone(),
                centre: f.centre + f.u * m.offset_mm[0] + f.v * m.offset_mm[1],
                axis_x: f.u * cos + f.v * sin,
                axis_up: f.v * cos - f.u * sin,
                wrap,
                labelled_only: !wrap,
            });
        } else if wrap && !by_face.is_empty() {
            let mix = (r.id as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
            let mut rng = rand_pcg::Pcg64::seed_from_u64(placement.seed ^ mix);
            let (m, _) = by_face[rng.random_range(0..by_face.len())];
            let range = placement.rotation_range_deg.abs();
            let rot = if range > 0.0 {
                rng.random_range(-range..=range)
            } else {
                0.0
            };
            let s = &m.slopes;
            let half_mm = |n: usize| (0.5 * n as f64 * s.spacing_um * 1e-3) as f32;
            let (hx, hy) = (half_mm(s.width), half_mm(s.height));
            let off = [
                rng.random_range(-1.0f32..=1.0) * hx,
                rng.random_range(-1.0f32..=1.0) * hy,
            ];
            let (sin, cos) = rot.to_radians().sin_cos();
            out.push(PlacedMap {
                region: r.id,
                slopes: s.clone(),
                centre: r.centre + r.u * off[0] + r.v * off[1],
                axis_x: r.u * cos + r.v * sin,
                axis_up: r.v * cos - r.u * sin,
                wrap,
                labelled_only: false,
            });
        }
    }
    Ok(out)
}

/// A slope map on a curved patch (`scene::curved`): the map's centre at (u, v) =
/// `offset_mm` of the patch's frame, its x axis along u (about the axis), its up axis along
/// v (the generatrix); repeated beyond its edges.
#[derive(Clone, Debug)]
pub struct PlacedCurved {
    /// Slot `regions + 1 + patch`, as `PlacedMap::region + 1` (`map` holds the centre on
    /// the axis, `axis_x` = the patch's `e0`, `axis_up` = its axis).
    pub map: PlacedMap,
    /// u = `arc_radius` x theta: the patch radius, for a full turn rounded so that the
    /// circumference holds a whole number of map widths (no seam where theta wraps).
    pub arc_radius: f32,
    pub offset_mm: [f32; 2],
    pub sin_beta: f32,
    pub cos_beta: f32,
    /// Revolved (the fields above) or triplanar (`map` holds the patch's centroid,
    /// `axis_x` = +X, `axis_up` = +Z; only `offset_mm` of the fields above is used).
    pub kind: PatchKind,
}

/// With `Cover::Part`, each curved patch gets one of the face maps (chosen, with an
/// offset uniform over the map's extent, from `placement.seed` and the patch's first
/// region id, as `place_maps` does for planar regions), unrotated: map x runs about the
/// axis, map up along the generatrix. `first_region`: the number of planar regions (the
/// patches' slots follow theirs). None with `Cover::Faces` or without maps.
pub fn place_curved_maps(
    maps: &[FaceMap],
    patches: &[CurvedPatch],
    first_region: u32,
    placement: &Placement,
) -> Vec<PlacedCurved> {
    use rand::{Rng, SeedableRng};
    if placement.cover != Cover::Part || maps.is_empty() {
        return Vec::new();
    }
    patches
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let id = p.regions.first().copied().unwrap_or(0) as u64;
            let mix = (id + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x4355_5256_4544;
            let mut rng = rand_pcg::Pcg64::seed_from_u64(placement.seed ^ mix);
            let m = &maps[rng.random_range(0..maps.len())];
            let s = &m.slopes;
            let extent = |n: usize| (n as f64 * s.spacing_um * 1e-3) as f32;
            let (wx, wy) = (extent(s.width), extent(s.height));
            let off = [
                rng.random_range(-0.5f32..=0.5) * wx,
                rng.random_range(-0.5f32..=0.5) * wy,
            ];
            let arc_radius = if p.kind == PatchKind::Triplanar {
                0.0
            } else if p.full_turn {
                let turns = (std::f32::consts::TAU * p.radius / wx).round().max(1.0);
                turns * wx / std::f32::consts::TAU
            } else {
                p.radius
            };
            PlacedCurved {
                map: PlacedMap {
                    region: first_region + i as u32,
                    slopes: s.clone(),
                    centre: p.centre,
                    axis_x: p.e0,
                    axis_up: p.axis,
                    wrap: true,
                    labelled_only: false,
                },
                arc_radius,
                offset_mm: off,
                sin_beta: p.sin_beta,
                cos_beta: p.cos_beta,
                kind: p.kind,
            }
        })
        .collect()
}

/// The configured object (built-in test body or mesh file), its inspected faces chosen
/// by `inspect`, translated to its position.
pub fn load_object(scene: &SceneConfig) -> Result<Mesh, AssembleError> {
    Ok(load_object_inspected(scene)?.0)
}

/// As [`load_object`], with what each `inspect` entry selected (empty without `inspect`).
pub fn load_object_inspected(
    scene: &SceneConfig,
) -> Result<(Mesh, Vec<super::inspect::InspectedFace>), AssembleError> {
    use super::mesh_io::{GltfUnitDefault, load_mesh};
    use super::{Degenerates, Variant, testbody};
    let cfg: &ObjectConfig = &scene.object;
    let mut mesh = match (scene.effective_builtin(), &cfg.path, &cfg.gltf) {
        (Some("testbody-m"), _, _) => testbody(Variant::M),
        (Some(_), _, _) => testbody(Variant::B),
        (None, Some(path), _) => {
            load_mesh(path, cfg.unit, GltfUnitDefault::Spec, Degenerates::Reject)?
                .imported
                .mesh
        }
        (None, None, Some(path)) => {
            load_mesh(
                path,
                cfg.unit,
                GltfUnitDefault::Millimetres,
                Degenerates::Reject,
            )?
            .imported
            .mesh
        }
        (None, None, None) => {
            return Err(ConfigError::Invalid {
                field: "object",
                message: "needs `path` (a mesh file) or `builtin`".into(),
            }
            .into());
        }
    };
    let inspected = match &cfg.inspect {
        Some(list) => {
            let sel = super::inspect::parse(list)?;
            super::inspect::apply(&mut mesh, &sel, &super::RegionTolerance::default())?
        }
        None => Vec::new(),
    };
    let t = Vec3::from(cfg.position_mm);
    for p in &mut mesh.positions {
        *p += t;
    }
    Ok((mesh, inspected))
}

/// The object on its table: everything about a scene that stays the same from one view
/// of a mesh to the next.
#[derive(Clone, Debug)]
pub struct Stage {
    /// The object's triangles, then the table's two.
    pub mesh: Mesh,
    /// Material id per triangle of `mesh` (`gpu_interface::MAT_*`).
    pub materials: Vec<u32>,
    /// Lambertian albedo of the table.
    pub table_albedo: f32,
    /// The table's square: centre x, y, its height z (mm) and half its edge length.
    pub table: [f32; 4],
    /// Frames of the object's inspected faces (where views aim and face maps are placed).
    pub face_frames: Vec<FaceFrame>,
    /// The object's planar regions (`scene::regions`, default tolerances), by id.
    pub regions: Vec<RegionFrame>,
    /// Region id of each object triangle (the table's two triangles have none).
    pub region_of: Vec<u32>,
    /// The `[[material.region]]` entries: triangle material `MAT_REGION_FIRST + i` is
    /// entry i (`scene::materials`); empty: every object triangle is `[material]`'s.
    pub surfaces: Vec<SurfaceMaterial>,
    /// The object's curved patches (`scene::curved`, default tolerances): groups of
    /// facet regions with one map frame each.
    pub curved: Vec<CurvedPatch>,
    /// The curved patch of each planar region (`u32::MAX`: none).
    pub curved_of: Vec<u32>,
    /// Per triangle of `mesh`, the shader's corner values (`trace::Triangles::corner_w`):
    /// on triangles of triplanar patches the smooth normals, octahedral-coded
    /// (`curved::encode_normal`); zeros elsewhere. Empty (all zeros) when the object has
    /// no triplanar patch.
    pub corner_w: Vec<[f32; 3]>,
}

impl crate::trace::Triangles for Stage {
    fn positions(&self) -> &[Vec3] {
        &self.mesh.positions
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.mesh.triangles
    }
    fn corner_w(&self) -> Option<&[[f32; 3]]> {
        (!self.corner_w.is_empty()).then_some(self.corner_w.as_slice())
    }
}

impl Stage {
    /// Puts a square table of `table.size_mm` under `object`, centred below `centre`
    /// (the object's position) at its height.
    pub fn new(object: Mesh, centre: [f32; 3], table: &TableConfig) -> Stage {
        let face_frames = face_frames(&object);
        let found = planar_regions(&object, &RegionTolerance::default());
        let region_of = region_per_triangle(&object, &found);
        let curved = curved_patches(&object, &found, &region_of, &CurvedTolerance::default());
        let mut curved_of = vec![u32::MAX; found.len()];
        for (i, p) in curved.iter().enumerate() {
            for &r in &p.regions {
                curved_of[r as usize] = i as u32;
            }
        }
        let corner_w: Vec<[f32; 3]> = if curved.iter().any(|p| p.kind == PatchKind::Triplanar) {
            smooth_corner_normals(&object, &region_of, &curved, &curved_of)
                .into_iter()
                .map(|n| n.map_or([0.0; 3], |n| n.map(encode_normal)))
                .chain([[0.0; 3]; 2]) // the table
                .collect()
        } else {
            Vec::new()
        };
        let regions = found
            .iter()
            .map(|r| RegionFrame {
                id: r.id,
                face: r.face,
                centre: r.centre,
                normal: r.normal,
                u: r.u,
                v: r.v,
            })
            .collect();
        let mut mesh = object;
        let mut materials = vec![MAT_CONDUCTOR; mesh.triangles.len()];
        let [ox, oy, oz] = centre;
        let hs = table.size_mm * 0.5;
        let base = mesh.positions.len() as u32;
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            mesh.positions
                .push(Vec3::new(ox + sx * hs, oy + sy * hs, oz));
        }
        mesh.triangles.push([base, base + 1, base + 2]);
        mesh.triangles.push([base, base + 2, base + 3]);
        let other = TriLabel {
            face: FACE_OTHER,
            ..Default::default()
        };
        mesh.labels.extend([other; 2]);
        materials.extend([MAT_TABLE; 2]);
        Stage {
            mesh,
            materials,
            table_albedo: table.albedo,
            table: [ox, oy, oz, hs],
            face_frames,
            regions,
            region_of,
            surfaces: Vec::new(),
            curved,
            curved_of,
            corner_w,
        }
    }

    /// The slope-map slot of object triangle `t`: 0 for none (burnished defects, the
    /// table), `r + 1` for planar region r, `regions.len() + 1 + i` for curved patch i.
    pub fn map_slot(&self, t: usize) -> u32 {
        match self.region_of.get(t) {
            None | Some(&u32::MAX) => 0,
            Some(&r) => match self.curved_of.get(r as usize) {
                Some(&p) if p != u32::MAX => self.regions.len() as u32 + 1 + p,
                _ => r + 1,
            },
        }
    }

    /// Takes the defect triangles (class != 0) out of their regions, so no slope map
    /// reaches them (`DefectSurface::Burnished`): the region geometry is unchanged.
    pub fn burnish_defects(&mut self) {
        for (r, l) in self.region_of.iter_mut().zip(&self.mesh.labels) {
            if l.class != 0 {
                *r = u32::MAX;
            }
        }
    }

    /// Gives the object's triangles the materials `entries` select (the earlier entry
    /// wins; unselected triangles keep the `[material]` conductor). `gltf`: the glTF
    /// material of each object triangle, for `gltf_material` selectors. Replaces any
    /// entries set before.
    pub fn set_region_materials(
        &mut self,
        entries: &[RegionMaterial],
        gltf: Option<&GltfMaterials>,
    ) -> Result<(), AssembleError> {
        let normals: Vec<Vec3> = self.regions.iter().map(|r| r.normal).collect();
        let per =
            super::materials::assign(entries, &self.mesh.labels, &normals, &self.region_of, gltf)?;
        for (t, m) in per.iter().enumerate() {
            if self.materials[t] == MAT_CONDUCTOR || self.materials[t] >= MAT_REGION_FIRST {
                self.materials[t] = match m {
                    Some(i) => MAT_REGION_FIRST + *i as u32,
                    None => MAT_CONDUCTOR,
                };
            }
        }
        self.surfaces = entries.iter().map(|e| e.material.clone()).collect();
        Ok(())
    }
}

/// The lights of a view: the area lights' emissive triangles (all lights' in one soup,
/// light by light), numbered after the stage's triangles, and one [`Emitter`] per light.
#[derive(Clone, Debug)]
pub struct LightGeometry {
    pub tris: TriangleSoup,
    /// Index of the first light triangle in the scene (= the stage's triangle count).
    pub first: u32,
    /// (scene triangle index, inclusive area CDF within its emitter) of each light
    /// triangle.
    pub lights: Vec<(u32, f32)>,
    /// The emitter of each light triangle (index into `emitters`).
    pub owner: Vec<u32>,
    /// The lights, in scene order.
    pub emitters: Vec<Emitter>,
}

/// How next-event estimation samples one light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EmitterSampling {
    /// A triangle by area.
    Uniform,
    /// A ring: a segment uniformly, then a triangle of it by the "facing" weight;
    /// [segments, triangles per segment].
    Facing([u32; 2]),
    /// A point light (no triangles): position, unit axis, intensity (W sr^-1), cosines
    /// of the cone edge and of the inner edge of its soft falloff.
    Spot {
        position: Vec3,
        axis: Vec3,
        intensity_w_sr: f32,
        cos_edge: f32,
        cos_inner: f32,
    },
}

/// One light of a view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Emitter {
    /// Its triangles: `first_tri .. first_tri + tri_count`, counted in the light soup.
    pub first_tri: u32,
    pub tri_count: u32,
    /// Emitting area, mm^2 (0 for the spot).
    pub area: f32,
    /// Radiance, W sr^-1 m^-2 (area lights).
    pub radiance: f32,
    /// Power, W (choosing among lights: `LightSpec::power_w`).
    pub power_w: f64,
    pub sampling: EmitterSampling,
    /// A ring light's torus, for the analytic direct light; None for the other shapes.
    pub torus: Option<Torus>,
    /// Where its triangles lie (None: a spot, nothing to hit).
    pub reach: Option<Reach>,
}

impl Emitter {
    /// Its triangles' indices in the light soup (`first_tri .. first_tri + tri_count`).
    pub fn tri_range(&self) -> std::ops::Range<usize> {
        self.first_tri as usize..(self.first_tri + self.tri_count) as usize
    }
}

/// A shell holding a light's surface: every point of its triangles lies between `inner`
/// and `outer` mm from `centre` (the centre of a ring's torus or of a dome's sphere,
/// else the mean of the vertices). The analytic direct light uses it to tell whether a light can stand in
/// front of a ring seen from a shading point (docs/rendering.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    pub centre: Vec3,
    pub inner: f32,
    pub outer: f32,
}

impl Reach {
    /// The shell of triangles `tris` over `pos` about `centre` (or the mean vertex): the
    /// outer radius the farthest vertex, the inner one the nearest triangle plane (a
    /// lower bound of every point's distance), each widened by a part in 10^5 for the
    /// rounding to f32; None without triangles.
    fn of(pos: &[DVec3], tris: &[[u32; 3]], centre: Option<DVec3>) -> Option<Reach> {
        if tris.is_empty() {
            return None;
        }
        let c = centre.unwrap_or_else(|| pos.iter().sum::<DVec3>() / pos.len() as f64);
        let outer = pos.iter().map(|p| (*p - c).length()).fold(0.0, f64::max);
        let inner = tris
            .iter()
            .map(|t| {
                let [a, b, cc] = t.map(|i| pos[i as usize]);
                let n = (b - a).cross(cc - a);
                let l = n.length();
                if l > 0.0 {
                    (n.dot(a - c) / l).abs()
                } else {
                    (a - c).length()
                }
            })
            .fold(f64::INFINITY, f64::min);
        Some(Reach {
            centre: c.as_vec3(),
            inner: (inner * (1.0 - 1e-5)) as f32,
            outer: (outer * (1.0 + 1e-5)) as f32,
        })
    }
}

/// A ring light's torus: centre, unit axis, major and tube radii (mm) and its segments
/// around the ring (those around the tube follow from its triangle count:
/// glsl/common/analytic_light.glsl).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Torus {
    pub centre: Vec3,
    pub axis: Vec3,
    pub major_mm: f32,
    pub minor_mm: f32,
    pub segments_major: u32,
}

impl LightGeometry {
    /// The ring light of `light` mounted on `camera` (axis along its view direction).
    pub fn ring(camera: &Camera, light: &LightConfig, first: u32) -> LightGeometry {
        LightGeometry::build(camera, &[LightSpec::legacy_ring(light)], first)
    }

    /// The lights `specs` for `camera` (lights on the camera follow it), their
    /// triangles numbered from `first`.
    pub fn build(camera: &Camera, specs: &[LightSpec], first: u32) -> LightGeometry {
        let mut positions: Vec<Vec3> = Vec::new();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut lights = Vec::new();
        let mut owner = Vec::new();
        let mut emitters = Vec::with_capacity(specs.len());
        for (e, spec) in specs.iter().enumerate() {
            let (pos, tris) = spec.triangles(camera);
            let base = positions.len() as u32;
            let first_tri = triangles.len() as u32;
            // Area CDF as the single ring light always had it: f64 sums, then f32
            // divided by the f32 total, the last exactly 1.
            let start = lights.len();
            let mut area = 0.0f64;
            for (k, t) in tris.iter().enumerate() {
                let [a, b, c] = t.map(|i| pos[i as usize].as_dvec3());
                area += 0.5 * (b - a).cross(c - a).length();
                lights.push((first + first_tri + k as u32, area as f32));
            }
            for l in &mut lights[start..] {
                l.1 /= area as f32;
            }
            if let Some(last) = lights[start..].last_mut() {
                last.1 = 1.0;
            }
            owner.extend(std::iter::repeat_n(e as u32, tris.len()));
            let sampling = match &spec.shape {
                LightShape::Ring(r) if r.sampling == LightSampling::Facing => {
                    EmitterSampling::Facing([r.segments_major, 2 * r.segments_minor])
                }
                LightShape::Spot {
                    intensity_w_sr,
                    half_angle_deg,
                    falloff_deg,
                } => {
                    let f = spec.frame(camera);
                    EmitterSampling::Spot {
                        position: f.position.as_vec3(),
                        axis: f.forward.as_vec3(),
                        intensity_w_sr: *intensity_w_sr,
                        cos_edge: half_angle_deg.to_radians().cos(),
                        cos_inner: (half_angle_deg - falloff_deg).to_radians().cos(),
                    }
                }
                _ => EmitterSampling::Uniform,
            };
            let torus = match &spec.shape {
                LightShape::Ring(r) => {
                    // Where its triangles are (LightSpec::triangles).
                    let (centre, axis) = spec.ring_centre_axis(camera);
                    Some(Torus {
                        centre,
                        axis: axis.normalize(),
                        major_mm: r.major_radius_mm,
                        minor_mm: r.minor_radius_mm,
                        segments_major: r.segments_major,
                    })
                }
                _ => None,
            };
            // About the torus's or the dome's own centre, else the mean vertex.
            let centre = match &spec.shape {
                LightShape::Dome { centre_mm, .. } => Some(*centre_mm),
                _ => torus.map(|t| t.centre.as_dvec3()),
            };
            let reach = Reach::of(
                &pos.iter().map(|p| p.as_dvec3()).collect::<Vec<_>>(),
                &tris,
                centre,
            );
            emitters.push(Emitter {
                first_tri,
                tri_count: tris.len() as u32,
                area: area as f32,
                radiance: spec.radiance,
                power_w: spec.power_w(area),
                sampling,
                torus,
                reach,
            });
            positions.extend(pos);
            triangles.extend(tris.iter().map(|t| t.map(|i| i + base)));
        }
        LightGeometry {
            tris: TriangleSoup {
                positions,
                triangles,
            },
            first,
            lights,
            owner,
            emitters,
        }
    }

    /// Probability with which next-event estimation chooses each emitter: proportional
    /// to its power (docs/rendering.md, "Lights"); all zero when no light emits.
    pub fn selection(&self) -> Vec<f64> {
        let total: f64 = self.emitters.iter().map(|e| e.power_w).sum();
        self.emitters
            .iter()
            .map(|e| if total > 0.0 { e.power_w / total } else { 0.0 })
            .collect()
    }

    /// Corners of scene triangle `t` (a light triangle).
    pub fn corners(&self, t: u32) -> [Vec3; 3] {
        self.tris.triangles[(t - self.first) as usize].map(|i| self.tris.positions[i as usize])
    }

    /// Radiance of scene triangle `t` (a light triangle).
    pub fn radiance_of(&self, t: u32) -> f32 {
        self.emitters[self.owner[(t - self.first) as usize] as usize].radiance
    }
}

/// What changes from one image to the next: the camera and the light on it.
#[derive(Clone, Debug)]
pub struct ViewSetup {
    pub camera: Camera,
    pub light: LightGeometry,
}

impl ViewSetup {
    /// The view `view` of a face of a stage (given by its face frames), with the ring
    /// light on the camera, its triangles numbered from `first_light` (the stage's
    /// triangle count).
    pub fn for_view(
        face_frames: &[FaceFrame],
        first_light: u32,
        view: View,
        camera: &CameraConfig,
        light: &LightConfig,
    ) -> Result<ViewSetup, AssembleError> {
        let frame = face_frames
            .iter()
            .find(|f| f.face == view.face)
            .ok_or(AssembleError::NoFace(face_name(view.face)))?;
        let camera = Camera::for_view(frame, view, camera);
        let light = LightGeometry::build(&camera, &light.specs()?, first_light);
        Ok(ViewSetup { camera, light })
    }
}

impl ViewSetup {
    /// The camera at `pose` (a face-relative view or a free pose) with the ring light on
    /// it; the view's face must have a frame.
    pub fn for_pose(
        face_frames: &[FaceFrame],
        first_light: u32,
        pose: &Pose,
        camera: &CameraConfig,
        light: &LightConfig,
    ) -> Result<ViewSetup, AssembleError> {
        if let Pose::View(view) = pose {
            return ViewSetup::for_view(face_frames, first_light, *view, camera, light);
        }
        let camera =
            Camera::for_pose(face_frames, pose, camera).expect("a free pose needs no face frame");
        let light = LightGeometry::build(&camera, &light.specs()?, first_light);
        Ok(ViewSetup { camera, light })
    }
}

/// A whole scene file's scene: stage, view and slope maps.
#[derive(Clone, Debug)]
pub struct RenderScene {
    pub stage: Stage,
    pub view: ViewSetup,
    /// Slope maps on inspected faces; none = shading normal is the geometric normal.
    pub face_maps: Vec<FaceMap>,
    /// How the face maps spread over the rest of the object (`[texture] cover`; other
    /// regions unrotated, their offsets drawn from the render seed).
    pub placement: Placement,
}

impl RenderScene {
    /// The scene `cfg` describes around `object` (already translated): table, the
    /// configured view, the ring light and the `[texture]` maps.
    pub fn assemble(object: &Mesh, cfg: &SceneConfig) -> Result<RenderScene, AssembleError> {
        let mut stage = Stage::new(object.clone(), cfg.object.position_mm, &cfg.table);
        let entries =
            super::materials::resolve(&cfg.material.region, &cfg.material, cfg.wavelength_nm())?;
        if !entries.is_empty() {
            let gltf = if entries.iter().any(|e| {
                e.selectors
                    .iter()
                    .any(|s| matches!(s, super::materials::RegionSelector::Gltf(_)))
            }) {
                object_gltf_materials(&cfg.object)?
            } else {
                None
            };
            stage.set_region_materials(&entries, gltf.as_ref())?;
        }
        if cfg.texture.defects == DefectSurface::Burnished {
            stage.burnish_defects();
        }
        let pose = cfg.camera.pose()?;
        let first_light = stage.mesh.triangles.len() as u32;
        let view = ViewSetup::for_pose(
            &stage.face_frames,
            first_light,
            &pose,
            &cfg.camera,
            &cfg.light,
        )?;
        let face_maps = texture_maps(&cfg.texture, &stage.face_frames)?;
        let placement = Placement {
            cover: cfg.texture.cover,
            seed: cfg.render.seed as u64,
            rotation_range_deg: 0.0,
            defects: cfg.texture.defects,
        };
        Ok(RenderScene {
            stage,
            view,
            face_maps,
            placement,
        })
    }
}

/// The glTF material of each triangle of the configured object when it is a glTF file
/// (read again from the file: the object's triangles are the file's, in order, since
/// scene objects refuse degenerate triangles); None for other formats and built-ins.
fn object_gltf_materials(cfg: &ObjectConfig) -> Result<Option<GltfMaterials>, AssembleError> {
    use super::mesh_io::{MeshFormat, load_mesh};
    let path = match cfg.path.as_ref().or(cfg.gltf.as_ref()) {
        Some(p) if MeshFormat::of(p)? == MeshFormat::Gltf => p,
        _ => return Ok(None),
    };
    let loaded = load_mesh(
        path,
        cfg.unit,
        super::mesh_io::GltfUnitDefault::Spec,
        super::Degenerates::Reject,
    )?;
    Ok(loaded.imported.materials)
}

/// The maps `[texture]` asks for: none for "flat"; for "test-grooves" one groove map,
/// shared by faces A, B and C, large enough to cover each face at any rotation; for
/// "file" the slopes (central differences) of EXR height maps in µm: each face's
/// `[[texture.map]]` entry's, the others `path`'s.
pub fn texture_maps(
    t: &TextureConfig,
    frames: &[FaceFrame],
) -> Result<Vec<FaceMap>, AssembleError> {
    if t.kind == "flat" {
        return Ok(Vec::new());
    }
    if frames.is_empty() {
        // Every map is placed from a face's frame (other regions and curved patches take
        // one of the faces' maps): without faces the object would render bare, silently.
        return Err(ConfigError::Invalid {
            field: "texture.kind",
            message: format!(
                "{:?}: the mesh has no faces A, B or C to place the map on; label them in the mesh (docs/mesh-format.md) or choose them with `[object] inspect`, or use kind = \"flat\"",
                t.kind
            ),
        }
        .into());
    }
    // Each face's map: its `[[texture.map]]` entry's, else the shared one.
    let place = |own: &[(FaceId, Arc<SlopeMap>)], shared: Option<Arc<SlopeMap>>| -> Vec<FaceMap> {
        frames
            .iter()
            .filter_map(|f| {
                let i = (f.face as usize).clamp(1, 3) - 1;
                let slopes = own
                    .iter()
                    .find(|(face, _)| *face == f.face)
                    .map(|(_, m)| m.clone())
                    .or_else(|| shared.clone())?;
                Some(FaceMap {
                    face: f.face,
                    slopes,
                    rotation_deg: t.rotation_deg[i],
                    offset_mm: t.offset_mm[i],
                })
            })
            .collect()
    };
    if t.kind == "file" {
        if t.path.is_none() && t.map.is_empty() {
            return Err(ConfigError::Invalid {
                field: "texture.path",
                message: "kind = \"file\" needs `path` (an EXR height map in µm) or `[[texture.map]]` entries".into(),
            }
            .into());
        }
        let shared = match &t.path {
            Some(path) => Some(Arc::new(
                crate::texture::read_exr(path, t.spacing_um as f64)?.slopes(),
            )),
            None => None,
        };
        let mut own = Vec::new();
        for (index, m) in t.map.iter().enumerate() {
            let bad = |field, message| m.error(index, field, message);
            let face = m.face_id(index)?;
            if !frames.iter().any(|f| f.face == face) {
                return Err(bad("face", format!("the mesh has no face {}", m.face)).into());
            }
            let spacing = m.spacing_um.unwrap_or(t.spacing_um);
            let height = crate::texture::read_exr(&m.path, spacing as f64)
                .map_err(|e| bad("path", e.to_string()))?;
            own.push((face, Arc::new(height.slopes())));
        }
        return Ok(place(&own, shared));
    }
    let extent = frames
        .iter()
        .map(|f| {
            let i = (f.face as usize).clamp(1, 3) - 1;
            let o = t.offset_mm[i];
            2.0 * (f.half_size.length() + (o[0] * o[0] + o[1] * o[1]).sqrt())
        })
        .fold(0.0f32, f32::max);
    Ok(place(
        &[],
        Some(Arc::new(SlopeMap::test_grooves(
            extent,
            t.spacing_um as f64,
            t.groove_period_mm,
            t.groove_max_slope_deg,
        ))),
    ))
}
