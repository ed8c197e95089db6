//! Shared by the GPU integration tests: a lavapipe context with validation always on.

#![allow(dead_code)]

pub mod files;

use std::sync::{Arc, Mutex, OnceLock};

use glam::Vec3;
use synosis::render::PathTracer;
use synosis::render::energy::EnergyTables;
use synosis::render::path_trace::{
    Frame, FrameOptions, Radiance, RenderScene, load_object, render_scene_on,
};
use synosis::scene::config::SceneConfig;
use synosis::scene::mesh::{FACE_A, Mesh, TriLabel};
use synosis::trace::Backend;
use synosis::vk::{Context, ContextOptions};

/// A device with validation and ray query enabled (ray query is required on these
/// machines: tools/setup installs Mesa 25).
pub fn gpu() -> Arc<Context> {
    let ctx = Context::new(&ContextOptions {
        validation: true,
        ray_query: true,
    })
    .expect("Vulkan device (run tools/setup)");
    assert!(ctx.info.validation, "validation must be on in tests");
    assert!(
        ctx.info.ray_query_enabled,
        "tests need ray query (Mesa >= 25 lavapipe); run tools/setup"
    );
    ctx
}

/// One device for the whole test binary (validation and ray query on, as [`gpu`]), for
/// tests that render many small images: they share it and its path tracers
/// ([`tracer`]). Its GPU work is one submission at a time (a context's command pool is
/// held through each submission); a validation error made by any test fails the next
/// [`assert_clean`] of every test on it.
pub fn shared_gpu() -> Arc<Context> {
    static SHARED: OnceLock<Arc<Context>> = OnceLock::new();
    SHARED.get_or_init(gpu).clone()
}

/// The path tracer of `backend` on [`shared_gpu`] (default energy tables), made at its
/// first use and kept by the test binary: lavapipe takes 2.5 to 4 s (2-core machine)
/// to create a path-tracing pipeline, cache or not, which a test making one per image
/// paid per image.
pub fn tracer(backend: Backend) -> Arc<PathTracer> {
    static TRACERS: Mutex<Vec<(Backend, Arc<PathTracer>)>> = Mutex::new(Vec::new());
    let mut tracers = TRACERS.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((_, t)) = tracers.iter().find(|(b, _)| *b == backend) {
        return t.clone();
    }
    let t = Arc::new(
        PathTracer::new(&shared_gpu(), backend, &EnergyTables::compute()).expect("path tracer"),
    );
    tracers.push((backend, t.clone()));
    t
}

/// Renders `scene` with `backend`'s shared [`tracer`]; fails the test on any validation
/// error.
pub fn render_shared(
    scene: &RenderScene,
    cfg: &SceneConfig,
    backend: Backend,
    opts: FrameOptions<'_>,
) -> Frame {
    let tracer = tracer(backend);
    let f = render_scene_on(&tracer, scene, cfg, opts, |_| {}).expect("render");
    assert_clean(tracer.context());
    f
}

/// The radiance of [`render_shared`] without annotation.
pub fn path_trace_shared(scene: &RenderScene, cfg: &SceneConfig, backend: Backend) -> Radiance {
    render_shared(scene, cfg, backend, FrameOptions::default()).radiance
}

/// Every trace backend (both software layouts too): tests over it hold each to the same
/// bounds, so they are tested against each other.
pub const BACKENDS: [Backend; 3] = [Backend::RayQuery, Backend::Software, Backend::SoftwareWide];

/// Fails the test on any validation error collected so far.
pub fn assert_clean(ctx: &Context) {
    let errors = ctx.validation_errors();
    assert!(
        errors.is_empty(),
        "{} validation error(s):\n{}",
        errors.len(),
        errors.join("\n")
    );
}

/// Runs shard `shard` of the smoke job (scenes/smoke-dataset.toml) made smaller (32 x 24,
/// 1 spp) with `renderer` into `out`.
pub fn run_small_smoke(
    renderer: &mut dyn synosis::dataset::ImageRenderer,
    out: &std::path::Path,
    shard: synosis::dataset::Shard,
) -> synosis::dataset::RunReport {
    run_small_smoke_with(renderer, out, shard, synosis::dataset::DEFAULT_IN_FLIGHT)
}

/// scenes/smoke-dataset.toml at 32 x 24 pixels (its `spp = 4` line left for the caller
/// to replace).
pub fn small_smoke_text() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/smoke-dataset.toml"
    ))
    .unwrap()
    .replace("width = 64", "width = 32")
    .replace("height = 48", "height = 24")
}

/// As [`run_small_smoke`], with `in_flight` images in flight (1: one after the other).
pub fn run_small_smoke_with(
    renderer: &mut dyn synosis::dataset::ImageRenderer,
    out: &std::path::Path,
    shard: synosis::dataset::Shard,
    in_flight: usize,
) -> synosis::dataset::RunReport {
    run_small_smoke_lanes(renderer, Vec::new(), out, shard, in_flight)
}

/// As [`run_small_smoke_with`], with `more` renderers beside `renderer`.
pub fn run_small_smoke_lanes(
    renderer: &mut dyn synosis::dataset::ImageRenderer,
    more: Vec<&mut (dyn synosis::dataset::ImageRenderer + Send)>,
    out: &std::path::Path,
    shard: synosis::dataset::Shard,
    in_flight: usize,
) -> synosis::dataset::RunReport {
    use synosis::dataset::{self, RunOptions};
    let text = small_smoke_text().replace("spp = 4", "spp = 1");
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let prep = dataset::prepare_text(&text, "smoke", scenes).unwrap();
    let mut textures = synosis::dataset::texture_bridge::ModuleTextures::default();
    let opts = RunOptions {
        shard,
        in_flight,
        more_renderers: more,
        ..Default::default()
    };
    dataset::run(&prep, out, renderer, &mut textures, opts).unwrap()
}

/// Integral over the area lights' triangles of radiance * g(wi) * cos_l / r^2 dA at `p`
/// (receiver normal +z: only directions above it count, wi pointing to the light, world
/// units): each triangle split into n^2 similar ones, one node at each centroid. With
/// g = wi.z it is the irradiance; with g = f * cos_i a BSDF's direct light.
pub fn light_integral(
    light: &synosis::scene::assemble::LightGeometry,
    p: glam::Vec3,
    n: usize,
    g: impl Fn(glam::DVec3) -> f64,
) -> f64 {
    let p = p.as_dvec3();
    let mut e = 0.0f64;
    for &(t, _) in &light.lights {
        let [a, b, c] = light.corners(t).map(|v| v.as_dvec3());
        let nl = (b - a).cross(c - a);
        let area = 0.5 * nl.length();
        let nl = nl.normalize();
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n - i {
                for up in [false, true] {
                    if up && i + j + 1 >= n {
                        continue;
                    }
                    let k = if up { 2.0 / 3.0 } else { 1.0 / 3.0 };
                    let (u, v) = ((i as f64 + k) / n as f64, (j as f64 + k) / n as f64);
                    let q = a + (b - a) * u + (c - a) * v;
                    let d = q - p;
                    let r2 = d.length_squared();
                    let w = d / r2.sqrt();
                    let cos_l = -nl.dot(w);
                    if w.z > 0.0 && cos_l > 0.0 {
                        sum += g(w) * cos_l / r2;
                    }
                }
            }
        }
        e += light.radiance_of(t) as f64 * sum * area / (n * n) as f64;
    }
    e
}

/// A 200 mm square plate at z = 10 mm, labelled face A (two triangles).
pub fn face_a_plate() -> Mesh {
    let mut plate = Mesh::default();
    for (x, y) in [
        (-100.0, -100.0),
        (100.0, -100.0),
        (100.0, 100.0),
        (-100.0, 100.0),
    ] {
        plate.positions.push(Vec3::new(x, y, 10.0));
    }
    plate.triangles = vec![[0, 1, 2], [0, 2, 3]];
    plate.labels = vec![
        TriLabel {
            face: FACE_A,
            ..Default::default()
        };
        2
    ];
    plate
}

/// Radiance and per-pixel face ids (centre ray: annotation grid 1) of one render.
pub fn render_faces(cfg: &SceneConfig, backend: Backend) -> (Radiance, Vec<u8>) {
    render_faces_with(cfg, backend, |_| {})
}

/// Radiance and per-pixel face ids of one render, after `tweak` on the assembled scene.
pub fn render_faces_with(
    cfg: &SceneConfig,
    backend: Backend,
    tweak: impl FnOnce(&mut RenderScene),
) -> (Radiance, Vec<u8>) {
    let object = load_object(cfg).expect("object");
    let mut scene = RenderScene::assemble(&object, cfg).expect("scene");
    tweak(&mut scene);
    let opts = FrameOptions {
        annotate_grid: Some(1),
        profiler: None,
        noise: None,
    };
    let f = render_shared(&scene, cfg, backend, opts);
    (f.radiance, f.annotation.expect("annotation").face)
}

/// Pixels of face A whose 8 neighbours are face A too (no silhouette pixels).
pub fn interior(face: &[u8], w: usize, h: usize) -> Vec<usize> {
    let mut out = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let all = (0..9).all(|k| face[(y + k / 3 - 1) * w + x + k % 3 - 1] == FACE_A);
            if all {
                out.push(y * w + x);
            }
        }
    }
    out
}

/// A labelled defect region of [`labelled_plane`]: triangles whose centroid lies strictly
/// inside [x0, x1] x [y0, y1] (mm) get `class` and `instance`.
pub struct Region {
    pub x: [f32; 2],
    pub y: [f32; 2],
    pub class: u8,
    pub instance: u16,
}

/// A [`Region`] on [x0, x1] x [y0, y1] (mm) labelled `class`, `instance`.
pub fn region(x: [f32; 2], y: [f32; 2], class: u8, instance: u16) -> Region {
    Region {
        x,
        y,
        class,
        instance,
    }
}

/// A square plane (face A) of side `side` mm centred on the z axis at height `z`, in
/// 0.5 mm cells, with labelled `regions`, and an unlabelled occluding quad `occluder`
/// (four corners, counter-clockwise) above it: the annotation tests' scene.
pub fn labelled_plane(side: f32, z: f32, regions: &[Region], occluder: [Vec3; 4]) -> Mesh {
    const CELL: f32 = 0.5;
    let mut m = Mesh::default();
    let n = (side / CELL) as u32;
    let h = side / 2.0;
    for j in 0..=n {
        for i in 0..=n {
            m.positions
                .push(Vec3::new(-h + i as f32 * CELL, -h + j as f32 * CELL, z));
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            for t in [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]] {
                let c = t.iter().map(|&k| m.positions[k as usize]).sum::<Vec3>() / 3.0;
                let (class, instance) = regions
                    .iter()
                    .find(|r| c.x > r.x[0] && c.x < r.x[1] && c.y > r.y[0] && c.y < r.y[1])
                    .map_or((0, 0), |r| (r.class, r.instance));
                m.triangles.push(t);
                m.labels.push(TriLabel {
                    face: FACE_A,
                    class,
                    instance,
                });
            }
        }
    }
    let b = m.positions.len() as u32;
    m.positions.extend(occluder);
    m.triangles.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
    m.labels.extend([TriLabel::default(); 2]);
    m
}

/// One GPU scene for every render of one mesh in a test, on the test binary's shared
/// device and path tracer ([`tracer`]: the pipelines take most of a small render's time
/// on lavapipe), or on a device and tracer of its own ([`SceneRenderer::own`]); each
/// render assembles the scene from its own config (view, lights, settings) over the
/// same stage.
pub struct SceneRenderer {
    pub ctx: Arc<Context>,
    tracer: Arc<synosis::render::PathTracer>,
    gpu: synosis::render::GpuScene,
    mesh: Mesh,
}

impl SceneRenderer {
    /// On the shared tracer of `backend`; `cfg`: any config of the test (the stage does
    /// not depend on the view).
    pub fn new(backend: Backend, mesh: Mesh, cfg: &SceneConfig) -> SceneRenderer {
        Self::on(tracer(backend), mesh, cfg)
    }

    /// On a device and path tracer of its own (a test that counts the tracer's
    /// pipelines); `begin_unspecialized` as [`synosis::render::PathTracer::beginning`].
    pub fn own(
        backend: Backend,
        mesh: Mesh,
        cfg: &SceneConfig,
        begin_unspecialized: bool,
    ) -> SceneRenderer {
        let tracer = synosis::render::PathTracer::beginning(
            &gpu(),
            backend,
            &EnergyTables::compute(),
            begin_unspecialized,
        )
        .expect("tracer");
        Self::on(Arc::new(tracer), mesh, cfg)
    }

    fn on(
        tracer: Arc<synosis::render::PathTracer>,
        mesh: Mesh,
        cfg: &SceneConfig,
    ) -> SceneRenderer {
        let scene = RenderScene::assemble(&mesh, cfg).expect("scene");
        let gpu = synosis::render::GpuScene::new(&tracer, &scene.stage, None).expect("gpu scene");
        SceneRenderer {
            ctx: tracer.context().clone(),
            tracer,
            gpu,
            mesh,
        }
    }

    /// How many path-tracing pipelines the renderer's tracer has made (one per distinct
    /// specialized setting, one reading the settings at run time).
    pub fn path_pipelines(&self) -> usize {
        self.tracer.path_pipeline_count()
    }

    /// Renders `cfg` (annotated with a 4 x 4 coverage grid when `annotate`); fails the
    /// test on any validation error.
    pub fn render(&self, cfg: &SceneConfig, annotate: bool) -> synosis::render::Frame {
        let scene = RenderScene::assemble(&self.mesh, cfg).expect("scene");
        let opts = FrameOptions {
            annotate_grid: annotate.then_some(4),
            profiler: None,
            noise: None,
        };
        let f = synosis::render::render_frame(
            &self.tracer,
            &self.gpu,
            &scene.view,
            &synosis::render::RenderSettings::from(cfg),
            opts,
            |_| {},
        )
        .expect("render");
        assert_clean(&self.ctx);
        f
    }
}
