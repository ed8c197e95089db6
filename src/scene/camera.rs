//! Inspection camera poses from the viewpoint plan, and the ring light mounted on it.

use glam::{DVec3, Vec3};

use super::config::{CameraConfig, LightConfig, Pose, View};
use super::testbody::FaceFrame;

/// The camera (one type for every pass): a pinhole with eye, orthonormal
/// forward/right/up, the half extents of the image plane at distance 1 (sensor half
/// size / focal length) and the image size in pixels.
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
        Camera {
            eye: eye.as_vec3(),
            forward: forward.as_vec3(),
            right: right.as_vec3(),
            up: up.as_vec3(),
            tan_half_w: (cam.width as f64 * pitch_mm * 0.5 / cam.focal_mm as f64) as f32,
            tan_half_h: (cam.height as f64 * pitch_mm * 0.5 / cam.focal_mm as f64) as f32,
            width: cam.width,
            height: cam.height,
        }
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
        }
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

    /// Unit direction through image position (x, y) in pixels (row 0 at the top).
    pub fn dir(&self, x: f32, y: f32) -> Vec3 {
        let nx = x / self.width as f32 * 2.0 - 1.0;
        let ny = y / self.height as f32 * 2.0 - 1.0;
        (self.forward + nx * self.tan_half_w * self.right - ny * self.tan_half_h * self.up)
            .normalize()
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
