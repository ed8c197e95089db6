//! Conforming longest-edge bisection (Rivara's LEPP algorithm).
//!
//! A triangle is only ever split across its longest edge, together with the triangle on
//! the other side of that edge, so the mesh never gets a T-junction: it stays watertight
//! by index, whatever is refined. Splitting an edge on a face border splits the
//! neighbouring face's triangle too (its geometry is unchanged, the new vertex lies on
//! the shared edge). Shapes stay well graded: angles are bounded away from 0.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::DVec3;

use super::DefectError;
use crate::scene::TriLabel;

const NONE: u32 = u32::MAX;

/// Multiplicative hashing for packed edge keys (SipHash dominated the run time).
#[derive(Default)]
struct EdgeHasher(u64);

impl Hasher for EdgeHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x100_0000_01B3);
        }
    }
    fn write_u64(&mut self, x: u64) {
        let h = x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 = h ^ (h >> 29);
    }
}

fn key(a: u32, b: u32) -> u64 {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    ((lo as u64) << 32) | hi as u64
}

pub(crate) struct Refiner {
    pub positions: Vec<DVec3>,
    pub tris: Vec<[u32; 3]>,
    pub labels: Vec<TriLabel>,
    edges: HashMap<u64, [u32; 2], BuildHasherDefault<EdgeHasher>>,
    /// Triangles created or changed since the caller last drained it.
    pub touched: Vec<u32>,
    limit: usize,
}

impl Refiner {
    pub fn new(
        positions: Vec<DVec3>,
        tris: Vec<[u32; 3]>,
        labels: Vec<TriLabel>,
        limit: usize,
    ) -> Result<Self, DefectError> {
        let mut edges: HashMap<u64, [u32; 2], BuildHasherDefault<EdgeHasher>> = HashMap::default();
        edges.reserve(tris.len() * 2);
        for (t, tri) in tris.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let slot = edges.entry(key(a, b)).or_insert([NONE, NONE]);
                if slot[0] == NONE {
                    slot[0] = t as u32;
                } else if slot[1] == NONE {
                    slot[1] = t as u32;
                } else {
                    return Err(DefectError::NonManifold { a, b });
                }
            }
        }
        Ok(Refiner {
            positions,
            tris,
            labels,
            edges,
            touched: Vec::new(),
            limit,
        })
    }

    fn len2(&self, a: u32, b: u32) -> f64 {
        self.positions[a as usize].distance_squared(self.positions[b as usize])
    }

    /// Longest edge of `t` as (from, to) in winding order. Ties are broken by the edge
    /// key, so both triangles sharing an edge agree on which of their edges is longest.
    pub fn longest(&self, t: u32) -> (u32, u32, f64) {
        let tri = self.tris[t as usize];
        let mut best = (tri[0], tri[1], self.len2(tri[0], tri[1]));
        for k in 1..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let l = self.len2(a, b);
            if l > best.2 || (l == best.2 && key(a, b) > key(best.0, best.1)) {
                best = (a, b, l);
            }
        }
        best
    }

    fn other(&self, a: u32, b: u32, t: u32) -> Option<u32> {
        let s = self.edges.get(&key(a, b))?;
        let o = if s[0] == t { s[1] } else { s[0] };
        (o != NONE).then_some(o)
    }

    fn slot_replace(&mut self, k: u64, old: u32, new: u32) {
        if let Some(s) = self.edges.get_mut(&k) {
            if s[0] == old {
                s[0] = new;
            } else if s[1] == old {
                s[1] = new;
            }
        }
    }

    fn slot_add(&mut self, k: u64, t: u32) {
        let s = self.edges.entry(k).or_insert([NONE, NONE]);
        if s[0] == NONE {
            s[0] = t;
        } else {
            s[1] = t;
        }
    }

    /// Splits edge (a, b) at its midpoint, with both triangles sharing it.
    fn bisect(&mut self, a: u32, b: u32) {
        let k = key(a, b);
        let Some(slots) = self.edges.remove(&k) else {
            return;
        };
        let m = self.positions.len() as u32;
        self.positions
            .push(0.5 * (self.positions[a as usize] + self.positions[b as usize]));
        for t in slots {
            if t == NONE {
                continue;
            }
            let tri = self.tris[t as usize];
            let i = (0..3)
                .find(|&i| key(tri[i], tri[(i + 1) % 3]) == k)
                .expect("edge map and triangles agree");
            let (p, q, c) = (tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]);
            let t2 = self.tris.len() as u32;
            self.tris[t as usize] = [p, m, c];
            self.tris.push([m, q, c]);
            self.labels.push(self.labels[t as usize]);
            self.slot_replace(key(q, c), t, t2);
            self.slot_add(key(p, m), t);
            self.slot_add(key(m, q), t2);
            self.slot_add(key(m, c), t);
            self.slot_add(key(m, c), t2);
            self.touched.push(t);
            self.touched.push(t2);
        }
    }

    /// Bisects `t0` across its longest edge, first refining along the longest-edge
    /// propagation path until the edge is also the longest of the triangle beyond it.
    pub fn refine(&mut self, t0: u32) -> Result<(), DefectError> {
        let (ta, tb, _) = self.longest(t0);
        let target = key(ta, tb);
        loop {
            if self.tris.len() > self.limit {
                return Err(DefectError::TooLarge { limit: self.limit });
            }
            let mut cur = t0;
            let (a, b) = loop {
                let (a, b, _) = self.longest(cur);
                match self.other(a, b, cur) {
                    None => break (a, b),
                    Some(n) => {
                        let (c, d, _) = self.longest(n);
                        if key(c, d) == key(a, b) {
                            break (a, b);
                        }
                        cur = n;
                    }
                }
            };
            self.bisect(a, b);
            if key(a, b) == target {
                return Ok(());
            }
        }
    }
}
