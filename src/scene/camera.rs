//! Inspection camera poses from the viewpoint plan, and the ring light mounted on it.

use glam::{DVec3, Vec2, Vec3};

use super::calibration::{Distortion, Intrinsics};
use super::config::{CameraConfig, LightConfig, Pose, View};
use super::testbody::FaceFrame;

/// The camera (one type for every pass): a pinhole with eye, orthonormal
/// forward/right/up, the half extents of the image plane at distance 1 (sensor half
/// size / focal length: `width / (2 fx)`, `height / (2 fy)`) and the image size in
/// pixels; the principal point's offset from the image centre and the lens distortion
/// (OpenCV's model, src/scene/calibration.rs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub tan_half_w: f32,
    pub tan_half_h: f32,
    pub width: u32,
    pub height: u32,
    /// Principal point in normalised device coordinates (-1 .. 1 across the image, +y
    /// down): `(cx + 0.5) / width * 2 - 1`, and the same for y; 0 = the image centre.
    pub principal: Vec2,
    /// Lens distortion; zero = the ideal pinhole.
    pub distortion: Distortion,
    /// Thin-lens aperture radius, mm (`focal_mm / (2 f_number)`); 0 = pinhole.
    pub lens_radius_mm: f32,
    /// Distance from the lens along `forward` to the plane in focus, mm.
    pub focus_distance_mm: f32,
}

/// Vertical field of view of the raycast framing camera.
pub const FRAMING_VFOV_DEG: f32 = 40.0;
/// Margin around the bounding box in the framing camera (10 %).
pub const FRAMING_MARGIN: f32 = 1.1;

impl Camera {
    /// The view `view` of `face`: the camera sits at the working distance from the face
    /// centre, tilted by `angle` from the face normal towards the face's `u` axis (the
    /// up-slope direction, so tilted views look down rather than up from the table), and
    /// aims at the centre. Image up is the tilted `u`.
    /// A non-zero azimuth turns the tilt direction (and the image up) about the normal,
    /// from `u` towards `v`.
    pub fn for_view(face: &FaceFrame, view: View, cam: &CameraConfig) -> Camera {
        let th = (view.angle_deg as f64).to_radians();
        let n = face.normal.as_dvec3();
        let u = if view.azimuth_deg == 0.0 {
            face.u.as_dvec3()
        } else {
            let az = (view.azimuth_deg as f64).to_radians();
            face.u.as_dvec3() * az.cos() + face.v.as_dvec3() * az.sin()
        };
        let dir = n * th.cos() + u * th.sin();
        let up = (u * th.cos() - n * th.sin()).normalize();
        let forward = -dir.normalize();
        let right = forward.cross(up).normalize();
        let eye = face.centre.as_dvec3() + dir * cam.working_distance_mm as f64;
        let pitch_mm = cam.pixel_um as f64 * 1e-3;
        let mut c = Camera {
            eye: eye.as_vec3(),
            forward: forward.as_vec3(),
            right: right.as_vec3(),
            up: up.as_vec3(),
            tan_half_w: (cam.width as f64 * pitch_mm * 0.5 / cam.focal_mm as f64) as f32,
            tan_half_h: (cam.height as f64 * pitch_mm * 0.5 / cam.focal_mm as f64) as f32,
            width: cam.width,
            height: cam.height,
            principal: Vec2::ZERO,
            distortion: Distortion::default(),
            lens_radius_mm: 0.0,
            focus_distance_mm: cam.working_distance_mm,
        };
        if let Some(n) = cam.f_number {
            c.lens_radius_mm = (cam.focal_mm as f64 / (2.0 * n)) as f32;
            c.focus_distance_mm = cam.focus_distance_mm.unwrap_or(cam.working_distance_mm);
        }
        if let Some(k) = &cam.intrinsics {
            c = c.with_intrinsics(&k.scaled(cam.width, cam.height));
        }
        c
    }

    /// This camera's pose with calibrated intrinsics `k` (image size, focal lengths,
    /// principal point, distortion).
    pub fn with_intrinsics(mut self, k: &Intrinsics) -> Camera {
        self.width = k.width;
        self.height = k.height;
        self.tan_half_w = (k.width as f64 / (2.0 * k.fx)) as f32;
        self.tan_half_h = (k.height as f64 / (2.0 * k.fy)) as f32;
        self.principal = Vec2::new(
            ((k.cx + 0.5) / k.width as f64 * 2.0 - 1.0) as f32,
            ((k.cy + 0.5) / k.height as f64 * 2.0 - 1.0) as f32,
        );
        self.distortion = k.distortion;
        self
    }

    /// The camera at a pose: a face-relative view of `frames` (as [`Camera::for_view`]), or
    /// a free pose (eye, unit forward, unit up orthogonal to it), with the intrinsics of
    /// `cam`. `None` when the view's face has no frame.
    pub fn for_pose(frames: &[FaceFrame], pose: &Pose, cam: &CameraConfig) -> Option<Camera> {
        match *pose {
            Pose::View(view) => frames
                .iter()
                .find(|f| f.face == view.face)
                .map(|f| Camera::for_view(f, view, cam)),
            Pose::Free { eye, forward, up } => {
                // The intrinsics (and whatever else `for_view` derives from `cam`) from
                // the view code path, so both kinds of pose share them; then the pose.
                let frame = FaceFrame {
                    face: 1,
                    centre: Vec3::ZERO,
                    normal: Vec3::Z,
                    u: Vec3::X,
                    v: Vec3::Y,
                    half_size: glam::Vec2::ONE,
                    area: 1.0,
                };
                let view = View {
                    face: 1,
                    angle_deg: 0.0,
                    azimuth_deg: 0.0,
                };
                let mut c = Camera::for_view(&frame, view, cam);
                c.eye = eye.as_vec3();
                c.forward = forward.as_vec3();
                c.right = forward.cross(up).normalize().as_vec3();
                c.up = up.as_vec3();
                Some(c)
            }
        }
    }

    /// Looks along `forward` with `up` as the image's up (made orthogonal), square
    /// pixels and a vertical field of view of `vfov_deg`.
    pub fn look(
        eye: Vec3,
        forward: Vec3,
        up: Vec3,
        vfov_deg: f32,
        width: u32,
        height: u32,
    ) -> Camera {
        let forward = forward.normalize();
        let right = forward.cross(up).normalize();
        let up = right.cross(forward).normalize();
        let tan_half_h = (vfov_deg.to_radians() * 0.5).tan();
        Camera {
            eye,
            forward,
            right,
            up,
            tan_half_w: tan_half_h * width as f32 / height as f32,
            tan_half_h,
            width,
            height,
            principal: Vec2::ZERO,
            distortion: Distortion::default(),
            lens_radius_mm: 0.0,
            focus_distance_mm: 1.0,
        }
    }

    /// An ideal pinhole with the principal point at the image centre: camera rays take
    /// the original (pre-calibration) arithmetic, so such images stay bit for bit.
    pub fn is_centred_pinhole(&self) -> bool {
        self.principal == Vec2::ZERO && self.distortion.is_zero()
    }

    /// Looks straight down -Z from above the centre of `mesh`'s bounding box, image up
    /// = +Y, right = +X, far enough that the box's XY extent (plus 10 %) fills the view
    /// (vertical field of view 40 degrees).
    pub fn framing(mesh: &super::Mesh, width: u32, height: u32) -> Camera {
        let (lo, hi) = mesh.bounds();
        let c = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        let aspect = width as f32 / height as f32;
        let tan = (FRAMING_VFOV_DEG.to_radians() * 0.5).tan();
        let half_h = (half.y.max(half.x / aspect) * FRAMING_MARGIN).max(1e-6);
        let dist = half_h / tan;
        let eye = Vec3::new(c.x, c.y, hi.z + dist);
        Camera::look(eye, -Vec3::Z, Vec3::Y, FRAMING_VFOV_DEG, width, height)
    }

    /// Unit direction through the centre of pixel (px, py), row 0 at the top.
    pub fn pixel_dir(&self, px: u32, py: u32) -> Vec3 {
        self.dir(px as f32 + 0.5, py as f32 + 0.5)
    }

    /// Unit direction through image position (x, y) in pixels (row 0 at the top, (0, 0)
    /// the top-left corner of the image, so OpenCV's pixel u is x - 0.5). The same model
    /// as `camera_dir` in glsl/common/camera.glsl: the pixel's distorted normalised
    /// coordinates, undistorted by Newton's method, give the ray.
    pub fn dir(&self, x: f32, y: f32) -> Vec3 {
        let nx = x / self.width as f32 * 2.0 - 1.0;
        let ny = y / self.height as f32 * 2.0 - 1.0;
        if self.is_centred_pinhole() {
            return (self.forward + nx * self.tan_half_w * self.right
                - ny * self.tan_half_h * self.up)
                .normalize();
        }
        let xd = (nx - self.principal.x) * self.tan_half_w;
        let yd = (ny - self.principal.y) * self.tan_half_h;
        let (xu, yu) = self.distortion.undistort(xd, yd);
        (self.forward + xu * self.right - yu * self.up).normalize()
    }

    /// The thin lens's ray through image position (x, y) from aperture sample `u`
    /// ([0, 1)^2, Shirley-Chiu concentric map onto the disc): origin and unit direction.
    /// The pinhole ray meets the plane of focus; the ray leaves the lens point towards
    /// that point. Same model as `camera_ray` in glsl/common/camera.glsl.
    pub fn lens_ray(&self, x: f32, y: f32, u: Vec2) -> (Vec3, Vec3) {
        let d = self.dir(x, y);
        if self.lens_radius_mm <= 0.0 {
            return (self.eye, d);
        }
        let focus = self.eye + d * (self.focus_distance_mm / d.dot(self.forward));
        let o2 = 2.0 * u - Vec2::ONE;
        let a = if o2 == Vec2::ZERO {
            Vec2::ZERO
        } else {
            let (r, phi) = if o2.x.abs() > o2.y.abs() {
                (o2.x, std::f32::consts::FRAC_PI_4 * (o2.y / o2.x))
            } else {
                (
                    o2.y,
                    std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (o2.x / o2.y),
                )
            };
            r * Vec2::new(phi.cos(), phi.sin())
        } * self.lens_radius_mm;
        let o = self.eye + a.x * self.right + a.y * self.up;
        (o, (focus - o).normalize())
    }

    /// Image position (pixels, as [`Camera::dir`] takes them) of world point `p`, or
    /// None behind the camera: OpenCV's projection (normalise, distort, scale, shift).
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let v = p - self.eye;
        let z = v.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        let (x, y) = (v.dot(self.right) / z, -v.dot(self.up) / z);
        let (xd, yd) = self.distortion.distort(x, y);
        let nx = xd / self.tan_half_w + self.principal.x;
        let ny = yd / self.tan_half_h + self.principal.y;
        Some(Vec2::new(
            (nx + 1.0) * 0.5 * self.width as f32,
            (ny + 1.0) * 0.5 * self.height as f32,
        ))
    }
}

/// Triangles of the ring light: a torus centred at `centre` with axis `axis`,
/// tessellated on a regular (phi, theta) grid, wound so the geometric normal points
/// outward (the emitting side). Positions, then triangles (indices into them).
pub fn ring_light(centre: Vec3, axis: Vec3, light: &LightConfig) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let axis = axis.as_dvec3().normalize();
    let (e1, e2) = {
        let a = if axis.x.abs() < 0.9 {
            DVec3::X
        } else {
            DVec3::Y
        };
        let e1 = axis.cross(a).normalize();
        (e1, axis.cross(e1))
    };
    let (nm, nn) = (light.segments_major, light.segments_minor);
    let (rr, r) = (light.major_radius_mm as f64, light.minor_radius_mm as f64);
    let c = centre.as_dvec3();
    let mut pos = Vec::with_capacity((nm * nn) as usize);
    for i in 0..nm {
        let phi = std::f64::consts::TAU * i as f64 / nm as f64;
        let radial = e1 * phi.cos() + e2 * phi.sin();
        for j in 0..nn {
            let th = std::f64::consts::TAU * j as f64 / nn as f64;
            let p = c + radial * (rr + r * th.cos()) + axis * (r * th.sin());
            pos.push(p.as_vec3());
        }
    }
    let id = |i: u32, j: u32| (i % nm) * nn + (j % nn);
    let mut tris = Vec::with_capacity((2 * nm * nn) as usize);
    for i in 0..nm {
        for j in 0..nn {
            let (a, b, cc, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            // d(phi) x d(theta) points outward for this parametrisation.
            tris.push([a, b, cc]);
            tris.push([a, cc, d]);
        }
    }
    (pos, tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A calibrated camera at the origin looking along +Z with image down = +Y, so world
    /// coordinates are OpenCV's camera coordinates.
    fn calibrated() -> (Camera, Intrinsics) {
        let k = Intrinsics {
            fx: 3600.0,
            fy: 3610.0,
            cx: 615.5,
            cy: 508.25,
            width: 1224,
            height: 1025,
            distortion: Distortion {
                k1: -0.12,
                k2: 0.08,
                p1: 1.0e-3,
                p2: -5.0e-4,
                k3: 0.01,
            },
        };
        let cam = Camera::look(Vec3::ZERO, Vec3::Z, -Vec3::Y, 10.0, 4, 4).with_intrinsics(&k);
        (cam, k)
    }

    /// OpenCV's projectPoints written out in f64, independently of `Distortion`.
    fn opencv_pixel(k: &Intrinsics, p: [f64; 3]) -> (f64, f64) {
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let d = k.distortion;
        let (k1, k2, p1, p2, k3) = (
            d.k1 as f64,
            d.k2 as f64,
            d.p1 as f64,
            d.p2 as f64,
            d.k3 as f64,
        );
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        (k.fx * xd + k.cx, k.fy * yd + k.cy)
    }

    #[test]
    fn projection_is_opencvs() {
        let (cam, k) = calibrated();
        // By hand: (0.1, -0.05, 1): r^2 = 0.0125, radial = 1 - 0.12 * 0.0125
        // + 0.08 * 0.0125^2 + 0.01 * 0.0125^3 = 0.998512519531; x'' = 0.1 * radial
        // + 2e-3 * (-0.005) - 5e-4 * (0.0125 + 0.02) = 0.0998250019531; y'' = -0.05 *
        // radial + 1e-3 * (0.0125 + 0.005) + 2 * (-5e-4) * (-0.005) = -0.0499031259766;
        // u = 3600 x'' + 615.5 = 974.870007031, v = 3610 y'' + 508.25 = 328.099715225.
        let got = cam.project(Vec3::new(0.1, -0.05, 1.0)).unwrap();
        // Camera::project gives the image position; OpenCV's pixel is 0.5 less.
        assert!((got.x as f64 - 0.5 - 974.870007031).abs() < 2e-3, "{got}");
        assert!((got.y as f64 - 0.5 - 328.099715225).abs() < 2e-3, "{got}");
        // The written-out formula agrees with the hand numbers (coefficients are f32).
        let (u, v) = opencv_pixel(&k, [0.1, -0.05, 1.0]);
        assert!((u - 974.870007031).abs() < 1e-5 && (v - 328.099715225).abs() < 1e-5);
        for p in [
            [0.0, 0.0, 50.0],
            [-3.0, 4.0, 60.0],
            [7.5, 6.0, 80.0],
            [-8.0, -6.5, 75.0],
            [2.0, -7.0, 90.0],
        ] {
            let (u, v) = opencv_pixel(&k, p);
            let got = cam
                .project(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
                .unwrap();
            let err = (got.x as f64 - 0.5 - u).hypot(got.y as f64 - 0.5 - v);
            // f32 camera arithmetic on 1000-pixel coordinates: a few 1e-4 px.
            assert!(err < 2e-3, "{p:?}: {got} vs OpenCV ({u}, {v}) + 0.5");
            // The camera ray through that pixel passes through the point.
            let d = cam.dir(got.x, got.y);
            let to = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32).normalize();
            assert!(
                d.angle_between(to) < 2e-6,
                "{p:?}: ray misses by {}",
                d.angle_between(to)
            );
        }
        assert!(cam.project(Vec3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn the_default_camera_keeps_its_rays() {
        let body = crate::scene::testbody(crate::scene::Variant::B);
        let face = crate::scene::face_frames(&body)[0];
        let cfg = CameraConfig::default();
        let view = crate::scene::config::parse_view("A20").unwrap();
        let cam = Camera::for_view(&face, view, &cfg);
        assert!(cam.is_centred_pinhole());
        // The original formula, verbatim.
        for (x, y) in [(0.5, 0.5), (611.7, 300.2), (1223.5, 1024.5)] {
            let nx = x / cam.width as f32 * 2.0 - 1.0;
            let ny = y / cam.height as f32 * 2.0 - 1.0;
            let old = (cam.forward + nx * cam.tan_half_w * cam.right
                - ny * cam.tan_half_h * cam.up)
                .normalize();
            assert_eq!(cam.dir(x, y), old);
        }
        // A centred calibration without distortion gives the same rays within rounding.
        let pitch = cfg.pixel_um as f64 * 1e-3;
        let k = Intrinsics {
            fx: cfg.focal_mm as f64 / pitch,
            fy: cfg.focal_mm as f64 / pitch,
            cx: (cfg.width as f64 - 1.0) / 2.0,
            cy: (cfg.height as f64 - 1.0) / 2.0,
            width: cfg.width,
            height: cfg.height,
            distortion: Distortion::default(),
        };
        let c2 = Camera::for_view(
            &face,
            view,
            &CameraConfig {
                intrinsics: Some(k),
                ..cfg.clone()
            },
        );
        assert!(c2.is_centred_pinhole());
        assert!(c2.dir(10.0, 20.0).angle_between(cam.dir(10.0, 20.0)) < 1e-6);
    }

    #[test]
    fn ring_light_normals_point_outward() {
        let l = LightConfig::default();
        let (p, t) = ring_light(Vec3::new(1.0, 2.0, 3.0), Vec3::Z, &l);
        for tri in &t {
            let [a, b, c] = tri.map(|i| p[i as usize]);
            let n = (b - a).cross(c - a);
            let m = (a + b + c) / 3.0 - Vec3::new(1.0, 2.0, 3.0);
            // Outward: away from the tube centre line.
            let radial = Vec3::new(m.x, m.y, 0.0).normalize() * l.major_radius_mm;
            assert!(n.dot(m - radial) > 0.0);
        }
    }
}
