//! The scene's lights: `[[light]]` entries as written ([`LightEntry`]), checked and
//! resolved for their kind ([`LightSpec`]), and the emissive triangles of the area
//! lights. Kinds: `ring` (torus, on the camera or at a free pose), `bar` (box), `panel`
//! (one-sided rectangle), `dome` (hemisphere over the table, emitting inwards) and `spot`
//! (a point light with a cone: a delta light, sampled by next-event estimation only).
//! docs/scene-format.md (`[[light]]`) and docs/rendering.md ("Lights").

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use super::camera::{Camera, ring_light};
use super::config::{ConfigError, LightConfig, LightSampling, LookAt};

/// Most lights a scene or job may have.
pub const MAX_LIGHTS: usize = 64;

/// Square millimetres per square metre: an area light's power and a spot light's
/// irradiance need the scene's millimetres in metres (radiance is per m^2).
pub const MM2_PER_M2: f64 = 1e6;

/// A light's kind (`kind = "..."`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    Ring,
    Bar,
    Panel,
    Dome,
    Spot,
}

impl LightKind {
    pub fn name(self) -> &'static str {
        match self {
            LightKind::Ring => "ring",
            LightKind::Bar => "bar",
            LightKind::Panel => "panel",
            LightKind::Dome => "dome",
            LightKind::Spot => "spot",
        }
    }
}

/// One `[[light]]` entry as written. Which fields a kind takes, their units, defaults and
/// ranges: docs/scene-format.md; [`LightEntry::resolve`] refuses the others.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LightEntry {
    pub kind: LightKind,
    /// Mounted on the camera (ring: default when no pose is given; spot: optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on_camera: Option<bool>,
    /// Pose: eye (the light's position), target (where it points) and up, scene mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at: Option<LookAt>,
    /// Pose: position, mm (with `direction`, and optionally `up`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_mm: Option<[f64; 3]>,
    /// Pose: the direction the light points (any length > 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f64; 3]>,
    /// Pose: up (with `position_mm`); default +Z (+Y when `direction` is within 2.6
    /// degrees of the Z axis).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
    /// Emitted radiance of an area light, W sr^-1 m^-2, [0, 1e6]; default 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiance: Option<f32>,
    /// Ring: torus radii, mm, and tessellation, as `[light]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub major_radius_mm: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub minor_radius_mm: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segments_major: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segments_minor: Option<u32>,
    /// Ring: next-event estimation within the ring, "facing" (default) or "uniform".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<LightSampling>,
    /// Bar: [length (right), width (up), depth (forward)]; panel: [width (right), height
    /// (up)], mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_mm: Option<Vec<f32>>,
    /// Dome: radius, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_mm: Option<f32>,
    /// Dome: centre of the hemisphere's base circle, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centre_mm: Option<[f64; 3]>,
    /// Dome: tessellation [azimuth, elevation] segments.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segments: Option<[u32; 2]>,
    /// Spot: intensity on its axis, W sr^-1, [0, 1e6].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity_w_sr: Option<f32>,
    /// Spot: half angle of the cone, degrees, (0, 90]; zero intensity beyond.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub half_angle_deg: Option<f32>,
    /// Spot: width of the soft edge inside the cone, degrees, [0, half_angle_deg].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub falloff_deg: Option<f32>,
}

/// Where a light is: on the camera (position = eye, pointing along the view) or at a
/// free pose (unit forward, unit up orthogonal to it; scene mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightMount {
    OnCamera,
    Free {
        position: DVec3,
        forward: DVec3,
        up: DVec3,
    },
}

/// A light's shape and emission, checked.
#[derive(Clone, Debug, PartialEq)]
pub enum LightShape {
    /// Torus around the forward axis (as `[light]`): radii, tessellation and sampling.
    Ring(LightConfig),
    /// Box centred on the position: [length along right, width along up, depth along
    /// forward], mm; every face emits outwards.
    Bar { size_mm: [f32; 3] },
    /// Rectangle centred on the position in the (right, up) plane, [width, height] mm,
    /// emitting towards forward only.
    Panel { size_mm: [f32; 2] },
    /// Hemisphere of `radius_mm` over its base circle's centre (+Z up), emitting inwards;
    /// [azimuth, elevation] segments.
    Dome {
        radius_mm: f32,
        centre_mm: DVec3,
        segments: [u32; 2],
    },
    /// Point light: intensity on the axis (W sr^-1), cone half angle and soft edge (deg).
    Spot {
        intensity_w_sr: f32,
        half_angle_deg: f32,
        falloff_deg: f32,
    },
}

/// One light of a scene, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct LightSpec {
    pub shape: LightShape,
    pub mount: LightMount,
    /// Radiance of an area light, W sr^-1 m^-2 (unused by the spot).
    pub radiance: f32,
}

/// A light's frame in the scene: position, unit forward, unit up, unit right = forward x up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightFrame {
    pub position: DVec3,
    pub forward: DVec3,
    pub up: DVec3,
    pub right: DVec3,
}

const POSE_LIMIT: f64 = 1e6;

/// The frame of a look-at pose: unit forward towards `target - eye`, `up` made orthogonal
/// to it (as the camera's `look_at`). Errors say what is wrong and the allowed range.
pub fn look_frame(
    eye: [f64; 3],
    forward: DVec3,
    up: [f64; 3],
) -> Result<(DVec3, DVec3, DVec3), String> {
    let ok = |v: [f64; 3]| v.iter().all(|c| c.is_finite() && c.abs() <= POSE_LIMIT);
    for (name, v) in [("eye / position", eye), ("up", up)] {
        if !ok(v) {
            return Err(format!(
                "{name} = {v:?}: each coordinate finite, in [-1e6, 1e6] mm"
            ));
        }
    }
    if !(forward.is_finite() && forward.length() >= 1e-6) {
        return Err("the direction (target - eye) is shorter than 1e-6 mm or not finite".into());
    }
    let forward = forward.normalize();
    let upv = DVec3::from(up);
    let right = forward.cross(upv);
    if upv.length() < 1e-12 || right.length() < 1e-6 * upv.length() {
        return Err(format!(
            "up = {up:?} is zero or parallel to the direction; allowed: any direction not along it"
        ));
    }
    let right = right.normalize();
    Ok((DVec3::from(eye), forward, right.cross(forward).normalize()))
}

impl LightEntry {
    /// A ring on the camera with `[light]`'s defaults.
    pub fn ring_on_camera() -> LightEntry {
        LightEntry {
            kind: LightKind::Ring,
            on_camera: None,
            look_at: None,
            position_mm: None,
            direction: None,
            up: None,
            radiance: None,
            major_radius_mm: None,
            minor_radius_mm: None,
            segments_major: None,
            segments_minor: None,
            sampling: None,
            size_mm: None,
            radius_mm: None,
            centre_mm: None,
            segments: None,
            intensity_w_sr: None,
            half_angle_deg: None,
            falloff_deg: None,
        }
    }

    /// The fields written, by name (for "not allowed for this kind" errors).
    fn written(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        let mut add = |set: bool, name: &'static str| {
            if set {
                v.push(name)
            }
        };
        add(self.on_camera.is_some(), "on_camera");
        add(self.look_at.is_some(), "look_at");
        add(self.position_mm.is_some(), "position_mm");
        add(self.direction.is_some(), "direction");
        add(self.up.is_some(), "up");
        add(self.radiance.is_some(), "radiance");
        add(self.major_radius_mm.is_some(), "major_radius_mm");
        add(self.minor_radius_mm.is_some(), "minor_radius_mm");
        add(self.segments_major.is_some(), "segments_major");
        add(self.segments_minor.is_some(), "segments_minor");
        add(self.sampling.is_some(), "sampling");
        add(self.size_mm.is_some(), "size_mm");
        add(self.radius_mm.is_some(), "radius_mm");
        add(self.centre_mm.is_some(), "centre_mm");
        add(self.segments.is_some(), "segments");
        add(self.intensity_w_sr.is_some(), "intensity_w_sr");
        add(self.half_angle_deg.is_some(), "half_angle_deg");
        add(self.falloff_deg.is_some(), "falloff_deg");
        v
    }

    /// Checks the entry (number `index` of the list, from 0) for its kind: every field
    /// in range, only the kind's fields, one pose.
    pub fn resolve(&self, index: usize) -> Result<LightSpec, ConfigError> {
        let err = |field: &'static str, message: String| ConfigError::Light {
            index,
            field,
            message,
        };
        let range = |field: &'static str, v: f32, lo: f32, hi: f32, lo_open: bool, r: &str| {
            let ok = v.is_finite() && (if lo_open { v > lo } else { v >= lo }) && v <= hi;
            if ok {
                Ok(())
            } else {
                Err(err(field, format!("{v} is out of range: allowed {r}")))
            }
        };
        let kind = self.kind;
        let allowed: &[&str] = match kind {
            LightKind::Ring => &[
                "on_camera",
                "look_at",
                "position_mm",
                "direction",
                "up",
                "radiance",
                "major_radius_mm",
                "minor_radius_mm",
                "segments_major",
                "segments_minor",
                "sampling",
            ],
            LightKind::Bar | LightKind::Panel => &[
                "look_at",
                "position_mm",
                "direction",
                "up",
                "radiance",
                "size_mm",
            ],
            LightKind::Dome => &["radiance", "radius_mm", "centre_mm", "segments"],
            LightKind::Spot => &[
                "on_camera",
                "look_at",
                "position_mm",
                "direction",
                "up",
                "intensity_w_sr",
                "half_angle_deg",
                "falloff_deg",
            ],
        };
        if let Some(f) = self.written().into_iter().find(|f| !allowed.contains(f)) {
            return Err(ConfigError::Light {
                index,
                field: "kind",
                message: format!(
                    "`{f}` is not a field of a {} light; allowed: {}",
                    kind.name(),
                    allowed.join(", ")
                ),
            });
        }
        let radiance = self.radiance.unwrap_or(1.0);
        range(
            "radiance",
            radiance,
            0.0,
            1e6,
            false,
            "[0, 1e6] W sr^-1 m^-2",
        )?;
        let mount = self.mount(index)?;
        let shape = match kind {
            LightKind::Ring => {
                let d = LightConfig::default();
                let ring = LightConfig {
                    major_radius_mm: self.major_radius_mm.unwrap_or(d.major_radius_mm),
                    minor_radius_mm: self.minor_radius_mm.unwrap_or(d.minor_radius_mm),
                    radiance,
                    segments_major: self.segments_major.unwrap_or(d.segments_major),
                    segments_minor: self.segments_minor.unwrap_or(d.segments_minor),
                    sampling: self.sampling.unwrap_or(d.sampling),
                    list: None,
                };
                range(
                    "major_radius_mm",
                    ring.major_radius_mm,
                    0.0,
                    1e4,
                    true,
                    "(0, 10000] mm",
                )?;
                if !(ring.minor_radius_mm.is_finite()
                    && ring.minor_radius_mm > 0.0
                    && ring.minor_radius_mm < ring.major_radius_mm)
                {
                    return Err(err(
                        "minor_radius_mm",
                        format!(
                            "{} is out of range: allowed (0, major_radius_mm) mm",
                            ring.minor_radius_mm
                        ),
                    ));
                }
                for (f, v, lo, hi) in [
                    ("segments_major", ring.segments_major, 8, 1024),
                    ("segments_minor", ring.segments_minor, 4, 256),
                ] {
                    if !(lo..=hi).contains(&v) {
                        return Err(err(f, format!("{v} is out of range: allowed [{lo}, {hi}]")));
                    }
                }
                LightShape::Ring(ring)
            }
            LightKind::Bar | LightKind::Panel => {
                let n = if kind == LightKind::Bar { 3 } else { 2 };
                let size = match &self.size_mm {
                    Some(s) => s.clone(),
                    None if n == 3 => vec![100.0, 20.0, 10.0],
                    None => vec![100.0, 100.0],
                };
                if size.len() != n {
                    return Err(err(
                        "size_mm",
                        format!(
                            "{size:?}: allowed {n} sizes ({})",
                            if n == 3 {
                                "length along right, width along up, depth along the direction"
                            } else {
                                "width along right, height along up"
                            }
                        ),
                    ));
                }
                for &s in &size {
                    range("size_mm", s, 0.0, 1e5, true, "(0, 100000] mm each")?;
                }
                if n == 3 {
                    LightShape::Bar {
                        size_mm: [size[0], size[1], size[2]],
                    }
                } else {
                    LightShape::Panel {
                        size_mm: [size[0], size[1]],
                    }
                }
            }
            LightKind::Dome => {
                let radius_mm = self.radius_mm.unwrap_or(300.0);
                range("radius_mm", radius_mm, 0.0, 1e5, true, "(0, 100000] mm")?;
                let c = self.centre_mm.unwrap_or([0.0; 3]);
                if !c.iter().all(|v| v.is_finite() && v.abs() <= POSE_LIMIT) {
                    return Err(err(
                        "centre_mm",
                        format!("{c:?}: each coordinate finite, in [-1e6, 1e6] mm"),
                    ));
                }
                let segments = self.segments.unwrap_or([64, 16]);
                if !(8..=1024).contains(&segments[0]) || !(2..=256).contains(&segments[1]) {
                    return Err(err(
                        "segments",
                        format!(
                            "{segments:?} is out of range: allowed [azimuth in [8, 1024], elevation in [2, 256]]"
                        ),
                    ));
                }
                LightShape::Dome {
                    radius_mm,
                    centre_mm: DVec3::from(c),
                    segments,
                }
            }
            LightKind::Spot => {
                let intensity_w_sr = self.intensity_w_sr.unwrap_or(1.0);
                range(
                    "intensity_w_sr",
                    intensity_w_sr,
                    0.0,
                    1e6,
                    false,
                    "[0, 1e6] W sr^-1",
                )?;
                let half_angle_deg = self.half_angle_deg.unwrap_or(30.0);
                range(
                    "half_angle_deg",
                    half_angle_deg,
                    0.0,
                    90.0,
                    true,
                    "(0, 90] degrees",
                )?;
                let falloff_deg = self.falloff_deg.unwrap_or(0.0);
                if !(falloff_deg.is_finite() && (0.0..=half_angle_deg).contains(&falloff_deg)) {
                    return Err(err(
                        "falloff_deg",
                        format!(
                            "{falloff_deg} is out of range: allowed [0, half_angle_deg = {half_angle_deg}] degrees"
                        ),
                    ));
                }
                LightShape::Spot {
                    intensity_w_sr,
                    half_angle_deg,
                    falloff_deg,
                }
            }
        };
        Ok(LightSpec {
            shape,
            mount,
            radiance,
        })
    }

    /// The pose: `on_camera`, `look_at`, or `position_mm` + `direction` (+ `up`).
    fn mount(&self, index: usize) -> Result<LightMount, ConfigError> {
        let err = |field: &'static str, message: String| ConfigError::Light {
            index,
            field,
            message,
        };
        if self.kind == LightKind::Dome {
            return Ok(LightMount::OnCamera); // unused: the dome has centre_mm
        }
        let free = self.look_at.is_some() || self.position_mm.is_some();
        if self.look_at.is_some() && (self.position_mm.is_some() || self.direction.is_some()) {
            return Err(err(
                "look_at",
                "given with position_mm / direction; give one pose".into(),
            ));
        }
        if self.look_at.is_some() && self.up.is_some() {
            return Err(err(
                "up",
                "given with look_at, which has its own `up`".into(),
            ));
        }
        let on_camera = match (self.on_camera, free) {
            (Some(true), true) => {
                return Err(err(
                    "on_camera",
                    "true together with a pose (look_at / position_mm); give one".into(),
                ));
            }
            (Some(c), _) => c,
            (None, free) => self.kind == LightKind::Ring && !free,
        };
        if on_camera {
            if self.direction.is_some() || self.up.is_some() {
                return Err(err(
                    "direction",
                    "direction / up given for a light on the camera (it points along the view)"
                        .into(),
                ));
            }
            return Ok(LightMount::OnCamera);
        }
        if let Some(l) = &self.look_at {
            let f = DVec3::from(l.target) - DVec3::from(l.eye);
            if !l
                .target
                .iter()
                .all(|c| c.is_finite() && c.abs() <= POSE_LIMIT)
            {
                return Err(err(
                    "look_at",
                    format!(
                        "target = {:?}: each coordinate finite, in [-1e6, 1e6] mm",
                        l.target
                    ),
                ));
            }
            let (position, forward, up) =
                look_frame(l.eye, f, l.up).map_err(|m| err("look_at", m))?;
            return Ok(LightMount::Free {
                position,
                forward,
                up,
            });
        }
        let Some(p) = self.position_mm else {
            let how = if self.kind == LightKind::Ring || self.kind == LightKind::Spot {
                "on_camera = true, look_at or position_mm + direction"
            } else {
                "look_at or position_mm + direction"
            };
            return Err(err("position_mm", format!("no pose given; give {how}")));
        };
        let Some(d) = self.direction else {
            return Err(err(
                "direction",
                "position_mm needs `direction` (where the light points)".into(),
            ));
        };
        if !d.iter().all(|c| c.is_finite() && c.abs() <= POSE_LIMIT) {
            return Err(err(
                "direction",
                format!("{d:?}: each component finite, in [-1e6, 1e6]"),
            ));
        }
        // Default up: +Z, or +Y for a light pointing (nearly) straight up or down.
        let dv = DVec3::from(d);
        let default_up = if dv.length() > 0.0 && dv.normalize().z.abs() > 0.999 {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let (position, forward, up) =
            look_frame(p, dv, self.up.unwrap_or(default_up)).map_err(|m| err("position_mm", m))?;
        Ok(LightMount::Free {
            position,
            forward,
            up,
        })
    }
}

/// Checks a list of entries (at most [`MAX_LIGHTS`]).
pub fn resolve_all(entries: &[LightEntry]) -> Result<Vec<LightSpec>, ConfigError> {
    if entries.len() > MAX_LIGHTS {
        return Err(ConfigError::Invalid {
            field: "light",
            message: format!("{} lights; allowed at most {MAX_LIGHTS}", entries.len()),
        });
    }
    entries
        .iter()
        .enumerate()
        .map(|(i, e)| e.resolve(i))
        .collect()
}

impl LightSpec {
    /// The old single `[light]` table: a ring on the camera.
    pub fn legacy_ring(l: &LightConfig) -> LightSpec {
        LightSpec {
            shape: LightShape::Ring(LightConfig {
                list: None,
                ..l.clone()
            }),
            mount: LightMount::OnCamera,
            radiance: l.radiance,
        }
    }

    /// The light's frame for a camera (on the camera: its eye, view direction and up).
    pub fn frame(&self, camera: &Camera) -> LightFrame {
        let (position, forward, up) = match self.mount {
            LightMount::OnCamera => (
                camera.eye.as_dvec3(),
                camera.forward.as_dvec3(),
                camera.up.as_dvec3(),
            ),
            LightMount::Free {
                position,
                forward,
                up,
            } => (position, forward, up),
        };
        LightFrame {
            position,
            forward,
            up,
            right: forward.cross(up),
        }
    }

    /// Where a ring is placed for `camera`: its centre and axis (on the camera, exactly
    /// the old ring's: the eye and view direction in f32).
    pub fn ring_centre_axis(&self, camera: &Camera) -> (Vec3, Vec3) {
        match self.mount {
            LightMount::OnCamera => (camera.eye, camera.forward),
            LightMount::Free { .. } => {
                let f = self.frame(camera);
                (f.position.as_vec3(), f.forward.as_vec3())
            }
        }
    }

    /// Emissive triangles of an area light (positions, then triangles wound so that
    /// the geometric normal cross(b - a, c - a) points to the emitting side); none for
    /// the spot.
    pub fn triangles(&self, camera: &Camera) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let f = self.frame(camera);
        match &self.shape {
            LightShape::Ring(ring) => {
                let (centre, axis) = self.ring_centre_axis(camera);
                ring_light(centre, axis, ring)
            }
            LightShape::Bar { size_mm } => {
                let h = [size_mm[0], size_mm[1], size_mm[2]].map(|s| 0.5 * s as f64);
                let axes = [f.right * h[0], f.up * h[1], f.forward * h[2]];
                let mut pos = Vec::with_capacity(8);
                for k in 0..8 {
                    let s = |b: usize| if k >> b & 1 == 1 { 1.0 } else { -1.0 };
                    pos.push(f.position + axes[0] * s(0) + axes[1] * s(1) + axes[2] * s(2));
                }
                // Faces as corner bit masks: the axis fixed and its side, two free axes.
                let mut quads = Vec::with_capacity(6);
                for axis in 0..3 {
                    let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
                    for side in 0..2usize {
                        let c = |i: usize, j: usize| side << axis | i << a1 | j << a2;
                        quads.push([c(0, 0), c(1, 0), c(1, 1), c(0, 1)]);
                    }
                }
                let outward = |n: DVec3, q: DVec3| n.dot(q - f.position) > 0.0;
                wind(&pos, &quads, outward)
            }
            LightShape::Panel { size_mm } => {
                let (hx, hy) = (0.5 * size_mm[0] as f64, 0.5 * size_mm[1] as f64);
                let pos = vec![
                    f.position - f.right * hx - f.up * hy,
                    f.position + f.right * hx - f.up * hy,
                    f.position + f.right * hx + f.up * hy,
                    f.position - f.right * hx + f.up * hy,
                ];
                let fwd = f.forward;
                wind(&pos, &[[0, 1, 2, 3]], |n, _| n.dot(fwd) > 0.0)
            }
            LightShape::Dome {
                radius_mm,
                centre_mm,
                segments,
            } => {
                let (na, ne) = (segments[0] as usize, segments[1] as usize);
                let r = *radius_mm as f64;
                let mut pos = Vec::with_capacity(na * ne + 1);
                for j in 0..ne {
                    let el = std::f64::consts::FRAC_PI_2 * j as f64 / ne as f64;
                    for i in 0..na {
                        let az = std::f64::consts::TAU * i as f64 / na as f64;
                        pos.push(
                            *centre_mm
                                + r * DVec3::new(
                                    el.cos() * az.cos(),
                                    el.cos() * az.sin(),
                                    el.sin(),
                                ),
                        );
                    }
                }
                let pole = pos.len();
                pos.push(*centre_mm + DVec3::new(0.0, 0.0, r));
                let id = |i: usize, j: usize| j * na + i % na;
                let mut quads = Vec::new();
                let mut tris = Vec::new();
                for j in 0..ne {
                    for i in 0..na {
                        if j + 1 < ne {
                            quads.push([id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
                        } else {
                            tris.push([id(i, j), id(i + 1, j), pole]);
                        }
                    }
                }
                let c = *centre_mm;
                let inward = |n: DVec3, q: DVec3| n.dot(q - c) < 0.0;
                let (p, mut t) = wind(&pos, &quads, inward);
                for tri in tris {
                    t.push(orient(&pos, tri, inward));
                }
                (p, t)
            }
            LightShape::Spot { .. } => (Vec::new(), Vec::new()),
        }
    }

    /// Power (W) for choosing among lights: pi radiance area for an area light (area in
    /// m^2), intensity times the cone's solid angle 2 pi (1 - cos half angle) for the spot
    /// (its soft edge ignored).
    pub fn power_w(&self, area_mm2: f64) -> f64 {
        match &self.shape {
            LightShape::Spot {
                intensity_w_sr,
                half_angle_deg,
                ..
            } => {
                *intensity_w_sr as f64
                    * std::f64::consts::TAU
                    * (1.0 - (*half_angle_deg as f64).to_radians().cos())
            }
            _ => std::f64::consts::PI * self.radiance as f64 * area_mm2 / MM2_PER_M2,
        }
    }
}

/// Orients triangle `t` so that `wanted(normal, centroid)` holds.
fn orient(pos: &[DVec3], t: [usize; 3], wanted: impl Fn(DVec3, DVec3) -> bool) -> [u32; 3] {
    let [a, b, c] = t.map(|i| pos[i]);
    let n = (b - a).cross(c - a);
    let t = t.map(|i| i as u32);
    if wanted(n, (a + b + c) / 3.0) {
        t
    } else {
        [t[0], t[2], t[1]]
    }
}

/// Splits quads (corner order around the quad) into two triangles each, oriented by
/// `wanted`; positions to f32.
fn wind(
    pos: &[DVec3],
    quads: &[[usize; 4]],
    wanted: impl Fn(DVec3, DVec3) -> bool + Copy,
) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut tris = Vec::with_capacity(quads.len() * 2);
    for q in quads {
        tris.push(orient(pos, [q[0], q[1], q[2]], wanted));
        tris.push(orient(pos, [q[0], q[2], q[3]], wanted));
    }
    (pos.iter().map(|p| p.as_vec3()).collect(), tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(text: &str) -> LightEntry {
        toml::from_str(text).expect("entry")
    }

    fn cam() -> Camera {
        Camera::look(Vec3::new(0.0, 0.0, 200.0), -Vec3::Z, Vec3::Y, 10.0, 8, 8)
    }

    /// Signed area vectors of the triangles: sum 0 for a closed surface.
    fn area_vector(p: &[Vec3], t: &[[u32; 3]]) -> (DVec3, f64) {
        let mut s = DVec3::ZERO;
        let mut a = 0.0;
        for tri in t {
            let [x, y, z] = tri.map(|i| p[i as usize].as_dvec3());
            let n = (y - x).cross(z - x) * 0.5;
            s += n;
            a += n.length();
        }
        (s, a)
    }

    #[test]
    fn bar_is_a_closed_box_wound_outwards() {
        let s = entry("kind = \"bar\"\nposition_mm = [10, 0, 50]\ndirection = [0, 0, -1]\nup = [0, 1, 0]\nsize_mm = [80, 20, 10]")
            .resolve(0)
            .unwrap();
        let (p, t) = s.triangles(&cam());
        assert_eq!(t.len(), 12);
        let (sum, area) = area_vector(&p, &t);
        assert!(sum.length() < 1e-3, "{sum}");
        assert!((area - 2.0 * (80.0 * 20.0 + 80.0 * 10.0 + 20.0 * 10.0)).abs() < 1e-2);
        let c = DVec3::new(10.0, 0.0, 50.0);
        for tri in &t {
            let [x, y, z] = tri.map(|i| p[i as usize].as_dvec3());
            assert!((y - x).cross(z - x).dot((x + y + z) / 3.0 - c) > 0.0);
        }
    }

    #[test]
    fn panel_emits_along_its_direction_and_dome_inwards() {
        let s = entry("kind = \"panel\"\nlook_at = { eye = [0, 0, 100], target = [0, 0, 0], up = [0, 1, 0] }\nsize_mm = [40, 30]")
            .resolve(0)
            .unwrap();
        let (p, t) = s.triangles(&cam());
        let (sum, area) = area_vector(&p, &t);
        assert!((area - 1200.0).abs() < 1e-3);
        assert!((sum.normalize() - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-9);
        let d =
            entry("kind = \"dome\"\nradius_mm = 100\ncentre_mm = [0, 0, 5]\nsegments = [32, 8]")
                .resolve(0)
                .unwrap();
        let (p, t) = d.triangles(&cam());
        assert_eq!(t.len(), 32 * 7 * 2 + 32);
        let (sum, area) = area_vector(&p, &t);
        // Inward: the area vector of a hemisphere over +Z points down (-pi r^2 projected).
        assert!(sum.z < 0.0 && (sum.z + std::f64::consts::PI * 1e4).abs() < 0.02 * 3.2e4);
        assert!(area < std::f64::consts::TAU * 1e4 && area > 0.95 * std::f64::consts::TAU * 1e4);
    }

    #[test]
    fn poses_and_defaults() {
        let r = entry("kind = \"ring\"").resolve(0).unwrap();
        assert_eq!(r.mount, LightMount::OnCamera);
        assert_eq!(r.shape, LightShape::Ring(LightConfig::default()));
        let r = entry("kind = \"ring\"\nposition_mm = [0, 0, 100]\ndirection = [0, 0, -2]")
            .resolve(0)
            .unwrap();
        match r.mount {
            LightMount::Free { forward, .. } => assert_eq!(forward, DVec3::new(0.0, 0.0, -1.0)),
            m => panic!("{m:?}"),
        }
        let s = entry("kind = \"spot\"\non_camera = true")
            .resolve(0)
            .unwrap();
        assert_eq!(s.mount, LightMount::OnCamera);
        assert!(s.triangles(&cam()).1.is_empty());
    }

    #[test]
    fn bad_values_name_the_field_and_range() {
        let cases = [
            (
                "kind = \"spot\"\non_camera = true\nhalf_angle_deg = 95",
                "light[3].half_angle_deg",
                "(0, 90]",
            ),
            (
                "kind = \"spot\"\non_camera = true\nhalf_angle_deg = 20\nfalloff_deg = 30",
                "light[3].falloff_deg",
                "[0, half_angle_deg",
            ),
            (
                "kind = \"bar\"\nposition_mm = [0, 0, 1]\ndirection = [1, 0, 0]\nsize_mm = [1, 2]",
                "light[3].size_mm",
                "3 sizes",
            ),
            (
                "kind = \"panel\"\nposition_mm = [0, 0, 1]\ndirection = [0, 0, -1]\nsize_mm = [0, 2]",
                "light[3].size_mm",
                "(0, 100000]",
            ),
            (
                "kind = \"panel\"\nradiance = -1\nposition_mm = [0, 0, 1]\ndirection = [0, 0, -1]",
                "light[3].radiance",
                "[0, 1e6]",
            ),
            ("kind = \"panel\"", "light[3].position_mm", "no pose"),
            (
                "kind = \"bar\"\non_camera = true",
                "light[3].kind",
                "not a field of a bar",
            ),
            (
                "kind = \"dome\"\nradius_mm = 0",
                "light[3].radius_mm",
                "(0, 100000]",
            ),
            (
                "kind = \"dome\"\nsegments = [4, 8]",
                "light[3].segments",
                "[8, 1024]",
            ),
            (
                "kind = \"ring\"\nminor_radius_mm = 40",
                "light[3].minor_radius_mm",
                "(0, major_radius_mm)",
            ),
            (
                "kind = \"ring\"\non_camera = true\nposition_mm = [0, 0, 1]",
                "light[3].on_camera",
                "give one",
            ),
            (
                "kind = \"spot\"\nposition_mm = [0, 0, 1]\ndirection = [1, 0, 0]\nup = [2, 0, 0]",
                "light[3].position_mm",
                "parallel",
            ),
            (
                "kind = \"spot\"\non_camera = true\nintensity_w_sr = 1e7",
                "light[3].intensity_w_sr",
                "[0, 1e6]",
            ),
        ];
        for (text, field, range) in cases {
            let e = entry(text).resolve(3).unwrap_err().to_string();
            assert!(e.contains(field) && e.contains(range), "{text}: {e}");
        }
        let many = vec![entry("kind = \"ring\""); MAX_LIGHTS + 1];
        let e = resolve_all(&many).unwrap_err().to_string();
        assert!(e.contains("at most 64"), "{e}");
    }
}
