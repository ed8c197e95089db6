//! Scene assembly on the CPU: the object on its table (one [`Stage`] per mesh), the
//! camera for a view and the ring light mounted on it (one [`ViewSetup`] per image), and
//! the slope maps a scene file asks for. Plain data: the renderer uploads a stage once
//! (`render::GpuScene`) and a view per image (`render::View`).

use std::sync::Arc;

use glam::Vec3;

use super::camera::{Camera, ring_light};
use super::config::{
    CameraConfig, ConfigError, LightConfig, LightSampling, ObjectConfig, Pose, SceneConfig,
    TableConfig, TextureConfig, View,
};
use super::mesh::{FACE_OTHER, FaceId, TriLabel, face_name};
use super::regions::{RegionTolerance, planar_regions, region_per_triangle};
use super::testbody::{FaceFrame, face_frames};
use super::{Mesh, MeshError};
use crate::gpu_interface::{MAT_CONDUCTOR, MAT_TABLE};
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
    /// Frames of the object's inspected faces (where views aim and face maps are placed).
    pub face_frames: Vec<FaceFrame>,
    /// The object's planar regions (`scene::regions`, default tolerances), by id.
    pub regions: Vec<RegionFrame>,
    /// Region id of each object triangle (the table's two triangles have none).
    pub region_of: Vec<u32>,
}

impl Stage {
    /// Puts a square table of `table.size_mm` under `object`, centred below `centre`
    /// (the object's position) at its height.
    pub fn new(object: Mesh, centre: [f32; 3], table: &TableConfig) -> Stage {
        let face_frames = face_frames(&object);
        let found = planar_regions(&object, &RegionTolerance::default());
        let region_of = region_per_triangle(&object, &found);
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
            face_frames,
            regions,
            region_of,
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
}

/// The emissive triangles of a view (the ring light around the camera), numbered after
/// the stage's triangles.
#[derive(Clone, Debug)]
pub struct LightGeometry {
    pub tris: TriangleSoup,
    /// Index of the first light triangle in the scene (= the stage's triangle count).
    pub first: u32,
    /// (scene triangle index, inclusive area CDF) of each light triangle.
    pub lights: Vec<(u32, f32)>,
    /// Total emitting area, mm^2.
    pub area: f32,
    /// Ring layout: [segments, triangles per segment], in order (facing sampling).
    pub ring_segments: [u32; 2],
    /// Emitted radiance (the scene's unit).
    pub radiance: f32,
    pub sampling: LightSampling,
}

impl LightGeometry {
    /// The ring light of `light` mounted on `camera` (axis along its view direction).
    pub fn ring(camera: &Camera, light: &LightConfig, first: u32) -> LightGeometry {
        let (positions, triangles) = ring_light(camera.eye, camera.forward, light);
        let mut lights = Vec::with_capacity(triangles.len());
        let mut area = 0.0f64;
        for (k, t) in triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
            area += 0.5 * (b - a).cross(c - a).length();
            lights.push((first + k as u32, area as f32));
        }
        for l in &mut lights {
            l.1 /= area as f32;
        }
        if let Some(last) = lights.last_mut() {
            last.1 = 1.0;
        }
        LightGeometry {
            tris: TriangleSoup {
                positions,
                triangles,
            },
            first,
            lights,
            area: area as f32,
            ring_segments: [light.segments_major, 2 * light.segments_minor],
            radiance: light.radiance,
            sampling: light.sampling,
        }
    }

    /// Corners of scene triangle `t` (a light triangle).
    pub fn corners(&self, t: u32) -> [Vec3; 3] {
        self.tris.triangles[(t - self.first) as usize].map(|i| self.tris.positions[i as usize])
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
        let light = LightGeometry::ring(&camera, light, first_light);
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
        let light = LightGeometry::ring(&camera, light, first_light);
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

/// The maps `[texture]` asks for: none for "flat"; for "test-grooves" one groove map,
/// shared by faces A, B and C, large enough to cover each face at any rotation; for
/// "file" the slopes (central differences) of an EXR height map in µm, on all three faces.
pub fn texture_maps(
    t: &TextureConfig,
    frames: &[FaceFrame],
) -> Result<Vec<FaceMap>, AssembleError> {
    if t.kind == "flat" || frames.is_empty() {
        return Ok(Vec::new());
    }
    let place = |map: Arc<SlopeMap>| -> Vec<FaceMap> {
        frames
            .iter()
            .map(|f| {
                let i = (f.face as usize).clamp(1, 3) - 1;
                FaceMap {
                    face: f.face,
                    slopes: map.clone(),
                    rotation_deg: t.rotation_deg[i],
                    offset_mm: t.offset_mm[i],
                }
            })
            .collect()
    };
    if t.kind == "file" {
        let path = t.path.as_ref().ok_or(ConfigError::Invalid {
            field: "texture.path",
            message: "kind = \"file\" needs `path` (an EXR height map in µm)".into(),
        })?;
        let height = crate::texture::read_exr(path, t.spacing_um as f64)?;
        return Ok(place(Arc::new(height.slopes())));
    }
    let extent = frames
        .iter()
        .map(|f| {
            let i = (f.face as usize).clamp(1, 3) - 1;
            let o = t.offset_mm[i];
            2.0 * (f.half_size.length() + (o[0] * o[0] + o[1] * o[1]).sqrt())
        })
        .fold(0.0f32, f32::max);
    Ok(place(Arc::new(SlopeMap::test_grooves(
        extent,
        t.spacing_um as f64,
        t.groove_period_mm,
        t.groove_max_slope_deg,
    ))))
}
