//! The watertight ray/triangle test (Woop, Benthin, Wald 2013), the same arithmetic as
//! `trace_leaf` in glsl/common/trace.glsl (operation for operation, no fused
//! multiply-adds), so CPU reference and software backend agree bit for bit.

use glam::Vec3;

/// A ray prepared for the test: origin, axis permutation and shear.
#[derive(Clone, Copy, Debug)]
pub struct ShearedRay {
    pub o: Vec3,
    pub k: [usize; 3],
    pub s: Vec3,
}

impl ShearedRay {
    pub fn new(o: Vec3, d: Vec3) -> Self {
        let a = d.abs();
        let kz = if a.x > a.y {
            if a.x > a.z { 0 } else { 2 }
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / d[kz];
        ShearedRay {
            o,
            k: [kx, ky, kz],
            s: Vec3::new(d[kx] * sz, d[ky] * sz, sz),
        }
    }

    /// Distance and barycentrics (weights of v1, v2) of a hit in [tmin, tmax).
    pub fn intersect(
        &self,
        v0: Vec3,
        v1: Vec3,
        v2: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, [f32; 2])> {
        let [kx, ky, kz] = self.k;
        let (a, b, c) = (v0 - self.o, v1 - self.o, v2 - self.o);
        let ax = a[kx] - self.s.x * a[kz];
        let ay = a[ky] - self.s.y * a[kz];
        let bx = b[kx] - self.s.x * b[kz];
        let by = b[ky] - self.s.y * b[kz];
        let cx = c[kx] - self.s.x * c[kz];
        let cy = c[ky] - self.s.y * c[kz];
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let tt = (u * (self.s.z * a[kz]) + v * (self.s.z * b[kz])) + w * (self.s.z * c[kz]);
        let t = tt / det;
        (t >= tmin && t < tmax).then_some((t, [v / det, w / det]))
    }
}
