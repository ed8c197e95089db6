//! The path-traced inspection image: scene assembly (object + table + ring light, one
//! material id per triangle) and the progressive GPU pass (glsl/path_trace.comp).

use std::sync::Arc;

use ash::vk;
use glam::Vec3;

use super::annotate::{AnnotatePass, Annotation, AnnotationTargets};
use super::energy::EnergyTables;
use super::raycast::PinholeCamera;
use super::slope::{FaceMap, SlopeMap};
use crate::graph::Graph;
use crate::scene::Mesh;
use crate::scene::camera::{Camera, ring_light};
use crate::scene::config::{SceneConfig, parse_view};
use crate::scene::mesh::{FACE_OTHER, TriLabel};
use crate::scene::testbody::{FaceFrame, face_frames};
use crate::trace::{Backend, TraceScene, scramble_multiplier, trace_pipeline};
use crate::vk::{Buffer, Context, MemoryKind, Profiler, VkError};

/// Material ids in the per-triangle material buffer (match path_trace.comp).
pub const MAT_CONDUCTOR: u32 = 0;
pub const MAT_TABLE: u32 = 1;
pub const MAT_LIGHT: u32 = 2;

/// Why a render could not be set up or run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Config(#[from] crate::scene::config::ConfigError),
    #[error("the mesh has no triangles labelled as face {0} (needed for the view)")]
    NoFace(&'static str),
    #[error("{width}x{height} needs {tiles} workgroups, more than one dispatch allows ({max})")]
    TooLarge {
        width: u32,
        height: u32,
        tiles: u32,
        max: u32,
    },
    #[error(transparent)]
    Mesh(#[from] crate::scene::MeshError),
    #[error(transparent)]
    Vk(#[from] VkError),
    #[error(transparent)]
    Slope(#[from] super::slope::SlopeError),
    #[error("texture.path: {0}")]
    Texture(#[from] crate::texture::TextureError),
}

/// The configured object (built-in test body or glTF), translated to its position.
pub fn load_object(cfg: &SceneConfig) -> Result<Mesh, RenderError> {
    use crate::scene::{Degenerates, Variant, import_mesh, testbody};
    let mut mesh = match (cfg.effective_builtin(), &cfg.object.gltf) {
        (Some("testbody-m"), _) => testbody(Variant::M),
        (Some(_), _) => testbody(Variant::B),
        (None, Some(path)) => import_mesh(path, Degenerates::Reject)?.mesh,
        (None, None) => {
            return Err(crate::scene::config::ConfigError::Invalid {
                field: "object",
                message: "needs `gltf` (a path) or `builtin`".into(),
            }
            .into());
        }
    };
    let t = Vec3::from(cfg.object.position_mm);
    for p in &mut mesh.positions {
        *p += t;
    }
    Ok(mesh)
}

/// Everything the GPU pass needs, built on the CPU.
pub struct RenderScene {
    /// Object, then the table's two triangles, then the ring light's triangles.
    pub mesh: Mesh,
    pub materials: Vec<u32>,
    /// (triangle, inclusive area CDF) of the emissive triangles.
    pub lights: Vec<(u32, f32)>,
    pub light_area: f32,
    /// Ring layout of the light triangles: [segments, triangles per segment], in order
    /// (used by `light.sampling = "facing"`).
    pub ring_segments: [u32; 2],
    pub camera: Camera,
    /// Frames of the object's inspected faces (where slope maps are projected).
    pub face_frames: Vec<FaceFrame>,
    /// Slope maps on inspected faces; none = shading normal is the geometric normal.
    /// Filled from `[texture]` by `assemble`; the dataset generator may replace them.
    pub face_maps: Vec<FaceMap>,
}

impl RenderScene {
    /// Places the camera for the configured view of `object` (already translated), adds
    /// the table under the object and the ring light around the camera.
    pub fn assemble(object: &Mesh, cfg: &SceneConfig) -> Result<RenderScene, RenderError> {
        let view = parse_view(&cfg.camera.view)?;
        let frames = face_frames(object);
        let frame = frames
            .iter()
            .find(|f| f.face == view.face)
            .ok_or(RenderError::NoFace(crate::scene::mesh::face_name(
                view.face,
            )))?;
        let camera = Camera::for_view(frame, view, &cfg.camera);
        let mut mesh = object.clone();
        let mut materials = vec![MAT_CONDUCTOR; mesh.triangles.len()];

        let [ox, oy, oz] = cfg.object.position_mm;
        let hs = cfg.table.size_mm * 0.5;
        let base = mesh.positions.len() as u32;
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            mesh.positions
                .push(Vec3::new(ox + sx * hs, oy + sy * hs, oz));
        }
        mesh.triangles.push([base, base + 1, base + 2]);
        mesh.triangles.push([base, base + 2, base + 3]);
        mesh.labels.extend(
            [TriLabel {
                face: FACE_OTHER,
                ..Default::default()
            }; 2],
        );
        materials.extend([MAT_TABLE; 2]);

        let (lp, lt) = ring_light(camera.eye, camera.forward, &cfg.light);
        let base = mesh.positions.len() as u32;
        let first_light = mesh.triangles.len() as u32;
        mesh.positions.extend(lp);
        let mut lights = Vec::with_capacity(lt.len());
        let mut area = 0.0f64;
        for (k, t) in lt.iter().enumerate() {
            let tri = t.map(|i| i + base);
            mesh.triangles.push(tri);
            mesh.labels.push(TriLabel::default());
            materials.push(MAT_LIGHT);
            let [a, b, c] = tri.map(|i| mesh.positions[i as usize].as_dvec3());
            area += 0.5 * (b - a).cross(c - a).length();
            lights.push((first_light + k as u32, area as f32));
        }
        for l in &mut lights {
            l.1 /= area as f32;
        }
        if let Some(last) = lights.last_mut() {
            last.1 = 1.0;
        }
        let face_maps = texture_maps(&cfg.texture, &frames)?;
        Ok(RenderScene {
            mesh,
            materials,
            lights,
            light_area: area as f32,
            ring_segments: [cfg.light.segments_major, 2 * cfg.light.segments_minor],
            camera,
            face_frames: frames,
            face_maps,
        })
    }
}

/// The maps `[texture]` asks for: none for "flat"; for "test-grooves" one groove map,
/// shared by faces A, B and C, large enough to cover each face at any rotation; for
/// "file" the slopes (central differences) of an EXR height map in µm, on all three faces.
fn texture_maps(
    t: &crate::scene::config::TextureConfig,
    frames: &[FaceFrame],
) -> Result<Vec<FaceMap>, RenderError> {
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
        let path = t
            .path
            .as_ref()
            .ok_or(crate::scene::config::ConfigError::Invalid {
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

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    eye: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    forward: [f32; 4],
    width: u32,
    height: u32,
    max_bounces: u32,
    seed: u32,
    alpha: f32,
    ior_n: f32,
    ior_k: f32,
    f_avg: f32,
    comp: u32,
    light_count: u32,
    sampler: u32,
    light_sampling: u32,
    table_albedo: f32,
    radiance: f32,
    light_area: f32,
    pad2: f32,
    light_first: u32,
    ring_segments: u32,
    segment_tris: u32,
    pad3: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push {
    sample_start: u32,
    sample_count: u32,
    tiles_x: u32,
    mult: u32,
}

/// A finished render: mean radiance per pixel (row 0 at the top) and GPU time.
pub struct Radiance {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
    pub gpu_ms: f64,
}

/// Renders `scene` with `cfg.render` settings; `progress(done_spp)` after each batch.
pub fn path_trace(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    cfg: &SceneConfig,
    backend: Backend,
    tables: &EnergyTables,
    profiler: Option<&Profiler>,
    progress: impl FnMut(u32),
) -> Result<Radiance, RenderError> {
    let opts = FrameOptions {
        annotate_grid: None,
        profiler,
    };
    render_frame(ctx, scene, cfg, backend, tables, opts, progress).map(|f| f.radiance)
}

/// What [`render_frame`] does besides path tracing.
#[derive(Clone, Copy, Default)]
pub struct FrameOptions<'a> {
    /// Run the annotation pass too, with this many coverage rays per pixel side.
    pub annotate_grid: Option<u32>,
    pub profiler: Option<&'a Profiler>,
}

/// A rendered image and, when asked for, its annotation from the same camera rays'
/// first hits (the annotation pass runs in the first batch's graph).
pub struct Frame {
    pub radiance: Radiance,
    pub annotation: Option<Annotation>,
}

/// The scene camera as the first-hit passes take it (square pixels).
pub fn pinhole(cam: &Camera) -> PinholeCamera {
    PinholeCamera {
        eye: cam.eye,
        forward: cam.forward,
        up: cam.up,
        vfov_deg: 2.0 * cam.tan_half_h.atan().to_degrees(),
    }
}

/// Path traces `scene` and, if `opts.annotate_grid` is set, annotates it in the same
/// render graph; `progress(done_spp)` after each batch.
pub fn render_frame(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    cfg: &SceneConfig,
    backend: Backend,
    tables: &EnergyTables,
    opts: FrameOptions<'_>,
    mut progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let profiler = opts.profiler;
    let (width, height) = (scene.camera.width, scene.camera.height);
    let tiles_x = width.div_ceil(8);
    let tiles = tiles_x * height.div_ceil(8);
    let max = ctx.info.max_workgroup_count[0];
    if tiles > max {
        return Err(RenderError::TooLarge {
            width,
            height,
            tiles,
            max,
        });
    }
    let light_first = scene.lights.first().map_or(scene.mesh.triangles.len(), |l| l.0 as usize);
    let object = Mesh {
        positions: scene.mesh.positions.clone(),
        triangles: scene.mesh.triangles[..light_first].to_vec(),
        labels: scene.mesh.labels[..light_first].to_vec(),
    };
    let light = crate::trace::TriangleSoup {
        positions: scene.mesh.positions.clone(),
        triangles: scene.mesh.triangles[light_first..].to_vec(),
    };
    let geo = Arc::new(crate::trace::TraceGeometry::build(ctx, &object, backend, 0, profiler)?);
    let trace = TraceScene::layered(ctx, geo, &light, profiler)?;
    let off = TraceScene::binding_kinds(backend).len() as u32;
    let annotation = match opts.annotate_grid {
        Some(grid) => Some((
            AnnotatePass::new(ctx, &trace, &object, grid)?,
            AnnotationTargets::new(ctx, width, height)?,
        )),
        None => None,
    };
    let pipeline = trace_pipeline(
        ctx,
        "path_trace",
        backend,
        11,
        std::mem::size_of::<Push>() as u32,
        [8, 8, 1],
    )?;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let cam = &scene.camera;
    let m = &cfg.material;
    let fresnel = super::bsdf::Fresnel::Conductor {
        n: m.ior_n,
        k: m.ior_k,
    };
    let params = Params {
        eye: cam.eye.extend(0.0).into(),
        right: (cam.right * cam.tan_half_w).extend(0.0).into(),
        up: (cam.up * cam.tan_half_h).extend(0.0).into(),
        forward: cam.forward.extend(0.0).into(),
        width,
        height,
        max_bounces: cfg.render.max_bounces,
        seed: cfg.render.seed,
        alpha: m.alpha,
        ior_n: m.ior_n,
        ior_k: m.ior_k,
        f_avg: fresnel.average(),
        comp: m.energy_compensation as u32,
        light_count: scene.lights.len() as u32,
        sampler: cfg.render.sampler as u32,
        light_sampling: match scene.ring_segments {
            [m, t] if m > 0 && t > 0 && m * t == scene.lights.len() as u32 => {
                cfg.light.sampling as u32
            }
            _ => 0, // not one ring of equal segments: uniform by area
        },
        table_albedo: cfg.table.albedo,
        radiance: cfg.light.radiance,
        light_area: scene.light_area,
        pad2: 0.0,
        light_first: light_first as u32,
        ring_segments: scene.ring_segments[0],
        segment_tris: scene.ring_segments[1],
        pad3: 0,
    };
    let light_words: Vec<[u32; 2]> = if scene.lights.is_empty() {
        vec![[0, 0]] // a binding may not be empty; light_count = 0 keeps it unread
    } else {
        scene
            .lights
            .iter()
            .map(|&(t, c)| [t, c.to_bits()])
            .collect()
    };
    // Material in the low byte, inspected face id in the next: the shader finds the
    // face's slope map without another buffer.
    let mat_words: Vec<u32> = scene
        .materials
        .iter()
        .zip(&scene.mesh.labels)
        .map(|(&m, l)| m | (l.face as u32) << 8)
        .collect();
    let (map_headers, map_texels) = super::slope::pack(
        &scene.face_maps,
        &scene.face_frames,
        ctx.info.max_storage_buffer_range as u64,
    )?;
    let mat_buf = Buffer::from_slice(ctx, "materials", &mat_words, storage)?;
    let map_head_buf = Buffer::from_slice(ctx, "slope map headers", &map_headers, storage)?;
    let mut map_bufs = Vec::with_capacity(3);
    for (texels, name) in map_texels.iter().zip(["slopes A", "slopes B", "slopes C"]) {
        // A binding may not be empty; a face without a map never reads it.
        let data: &[u32] = if texels.is_empty() { &[0] } else { texels };
        map_bufs.push(Buffer::from_slice(ctx, name, data, storage)?);
    }
    let light_buf = Buffer::from_slice(ctx, "lights", &light_words, storage)?;
    let energy_buf = Buffer::from_slice(ctx, "energy tables", &tables.packed(), storage)?;
    let param_buf = Buffer::from_slice(ctx, "path params", &[params], storage)?;
    let n = width as u64 * height as u64;
    let accum = Buffer::new(
        ctx,
        "radiance sum",
        n * 4,
        storage | vk::BufferUsageFlags::TRANSFER_DST,
        MemoryKind::Readback,
    )?;
    let mult = scramble_multiplier(tiles);
    let spp = cfg.render.spp;
    let batch = cfg.render.batch_spp.max(1);
    let mut done = 0u32;
    let mut gpu_ms = 0.0;
    while done < spp {
        let count = batch.min(spp - done);
        let push = Push {
            sample_start: done,
            sample_count: count,
            tiles_x,
            mult,
        };
        let mut g = Graph::new(ctx, "path trace");
        let refs = trace.import(&mut g);
        let geo = g.import(trace.shade_tris());
        let ltris = g.import(trace.second_shade_tris());
        let mats = g.import(&mat_buf);
        let lts = g.import(&light_buf);
        let en = g.import(&energy_buf);
        let pr = g.import(&param_buf);
        let mut acc = g.import(&accum);
        let mh = g.import(&map_head_buf);
        let ma = g.import(&map_bufs[0]);
        let mb = g.import(&map_bufs[1]);
        let mc = g.import(&map_bufs[2]);
        if done == 0 {
            g.fill("clear radiance", &mut acc, 0);
            if let Some((pass, targets)) = &annotation {
                let mut ids = g.import(&targets.ids);
                let mut cov = g.import(&targets.coverage);
                pass.record(
                    &mut g,
                    &refs,
                    off,
                    &pinhole(&scene.camera),
                    (&mut ids, &mut cov),
                    (width, height),
                );
            }
        }
        refs.bind(g.dispatch("path trace", &pipeline, [tiles, 1, 1]))
            .read(off, &geo)
            .read(off + 1, &mats)
            .read(off + 2, &lts)
            .read(off + 3, &en)
            .read(off + 4, &pr)
            .read_write(off + 5, &mut acc)
            .read(off + 6, &mh)
            .read(off + 7, &ma)
            .read(off + 8, &mb)
            .read(off + 9, &mc)
            .read(off + 10, &ltris)
            .push(&push)
            .submit();
        for t in g.execute(profiler)? {
            if t.gpu_ms.is_finite() {
                gpu_ms += t.gpu_ms;
            }
        }
        done += count;
        progress(done);
    }
    let sum: Vec<f32> = accum.read()?;
    let inv = 1.0 / spp as f32;
    let annotation = match &annotation {
        Some((_, targets)) => Some(targets.read()?),
        None => None,
    };
    Ok(Frame {
        radiance: Radiance {
            width,
            height,
            data: sum.iter().map(|v| v * inv).collect(),
            gpu_ms,
        },
        annotation,
    })
}
