//! Inspection camera poses from the viewpoint plan, and the ring light mounted on it.

use glam::{DVec3, Vec3};

use super::config::{CameraConfig, LightConfig, View};
use super::testbody::FaceFrame;

/// A pinhole camera: eye, orthonormal forward/right/up, and the half extents of the
/// image plane at distance 1 (sensor half size / focal length).
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

impl Camera {
    /// The view `view` of `face`: the camera sits at the working distance from the face
    /// centre, tilted by `angle` from the face normal towards the face's `u` axis (the
    /// up-slope direction, so tilted views look down rather than up from the table), and
    /// aims at the centre. Image up is the tilted `u`.
    pub fn for_view(face: &FaceFrame, view: View, cam: &CameraConfig) -> Camera {
        let th = (view.angle_deg as f64).to_radians();
        let n = face.normal.as_dvec3();
        let u = face.u.as_dvec3();
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
