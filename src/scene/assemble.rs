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
    /// Frames of the object's inspected faces (where slope maps are projected).
    pub face_frames: Vec<FaceFrame>,
}

impl Stage {
    /// Puts a square table of `table.size_mm` under `object`, centred below `centre`
    /// (the object's position) at its height.
    pub fn new(object: Mesh, centre: [f32; 3], table: &TableConfig) -> Stage {
        let face_frames = face_frames(&object);
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
}

impl RenderScene {
    /// The scene `cfg` describes around `object` (already translated): table, the
    /// configured view, the ring light and the `[texture]` maps.
    pub fn assemble(object: &Mesh, cfg: &SceneConfig) -> Result<RenderScene, AssembleError> {
        let stage = Stage::new(object.clone(), cfg.object.position_mm, &cfg.table);
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
        Ok(RenderScene {
            stage,
            view,
            face_maps,
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
