//! Conforming longest-edge bisection (Rivara's LEPP algorithm).
//!
//! A triangle is only ever split across its longest edge, together with the triangle on
//! the other side of that edge, so the mesh never gets a T-junction: it stays watertight
//! by index, whatever is refined. Splitting an edge on a face border splits the
//! neighbouring face's triangle too (its geometry is unchanged, the new vertex lies on
//! the shared edge). Shapes stay well graded: angles are bounded away from 0.

use std::collections::HashMap;

use glam::DVec3;

use super::DefectError;
use crate::scene::TriLabel;

const NONE: u32 = u32::MAX;

fn key(a: u32, b: u32) -> u64 {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    ((lo as u64) << 32) | hi as u64
}

pub(crate) struct Refiner {
    pub positions: Vec<DVec3>,
    pub tris: Vec<[u32; 3]>,
    pub labels: Vec<TriLabel>,
    /// The input triangle each triangle is a piece of.
    pub origin: Vec<u32>,
    /// `adj[t][k]`: the triangle across edge k = (tri[k], tri[k+1]) of t, or NONE.
    /// Kept per triangle rather than in an edge hash map: bisection only ever touches
    /// the two triangles of an edge and their four neighbours.
    adj: Vec<[u32; 3]>,
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
        let mut edges: HashMap<u64, (u32, u8, u32, u8)> = HashMap::with_capacity(tris.len() * 2);
        for (t, tri) in tris.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let slot = edges.entry(key(a, b)).or_insert((NONE, 0, NONE, 0));
                if slot.0 == NONE {
                    (slot.0, slot.1) = (t as u32, k as u8);
                } else if slot.2 == NONE {
                    (slot.2, slot.3) = (t as u32, k as u8);
                } else {
                    return Err(DefectError::NonManifold { a, b });
                }
            }
        }
        let mut adj = vec![[NONE; 3]; tris.len()];
        for &(t0, k0, t1, k1) in edges.values() {
            if t1 != NONE {
                adj[t0 as usize][k0 as usize] = t1;
                adj[t1 as usize][k1 as usize] = t0;
            }
        }
        let origin = (0..tris.len() as u32).collect();
        Ok(Refiner {
            positions,
            tris,
            labels,
            origin,
            adj,
            touched: Vec::new(),
            limit,
        })
    }

    fn len2(&self, a: u32, b: u32) -> f64 {
        self.positions[a as usize].distance_squared(self.positions[b as usize])
    }

    /// Local index of the longest edge of `t`, and its squared length. Ties are broken
    /// by the edge's vertex ids, so both triangles sharing an edge agree on it.
    pub fn longest(&self, t: u32) -> (usize, f64) {
        let tri = self.tris[t as usize];
        let mut best = (0, self.len2(tri[0], tri[1]));
        for k in 1..3 {
            let l = self.len2(tri[k], tri[(k + 1) % 3]);
            let (bk, bl) = best;
            if l > bl
                || (l == bl && key(tri[k], tri[(k + 1) % 3]) > key(tri[bk], tri[(bk + 1) % 3]))
            {
                best = (k, l);
            }
        }
        best
    }

    /// Local index in `n` of the edge (a, b).
    fn local_edge(&self, n: u32, a: u32, b: u32) -> usize {
        let tri = self.tris[n as usize];
        let k = key(a, b);
        (0..3)
            .find(|&j| key(tri[j], tri[(j + 1) % 3]) == k)
            .expect("adjacent triangles share the edge")
    }

    /// In `x`, points the link that went to `old` across edge (a, b) to `new`.
    fn relink(&mut self, x: u32, a: u32, b: u32, old: u32, new: u32) {
        if x == NONE {
            return;
        }
        let j = self.local_edge(x, a, b);
        debug_assert_eq!(self.adj[x as usize][j], old);
        self.adj[x as usize][j] = new;
    }

    /// Splits edge `k` of `t` at its midpoint, with the triangle on its other side.
    fn bisect(&mut self, t: u32, k: usize) {
        let tri = self.tris[t as usize];
        let (a, b, c) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
        let n = self.adj[t as usize][k];
        let (x, y) = (
            self.adj[t as usize][(k + 1) % 3],
            self.adj[t as usize][(k + 2) % 3],
        );
        let m = self.positions.len() as u32;
        self.positions
            .push(0.5 * (self.positions[a as usize] + self.positions[b as usize]));
        let t2 = self.tris.len() as u32;
        let n2 = if n == NONE { NONE } else { t2 + 1 };
        // The other side runs p -> q along the edge: (b, a) when windings agree.
        let (p, q, d, xn, yn) = if n == NONE {
            (b, a, NONE, NONE, NONE)
        } else {
            let j = self.local_edge(n, a, b);
            let nt = self.tris[n as usize];
            let na = self.adj[n as usize];
            (
                nt[j],
                nt[(j + 1) % 3],
                nt[(j + 2) % 3],
                na[(j + 1) % 3],
                na[(j + 2) % 3],
            )
        };
        let n_child_with = |v: u32| {
            if n == NONE {
                NONE
            } else if p == v {
                n
            } else {
                n2
            }
        };
        // t -> [a, m, c] (keeps its index), t2 -> [m, b, c].
        self.tris[t as usize] = [a, m, c];
        self.adj[t as usize] = [n_child_with(a), t2, y];
        self.tris.push([m, b, c]);
        self.adj.push([n_child_with(b), x, t]);
        self.labels.push(self.labels[t as usize]);
        self.origin.push(self.origin[t as usize]);
        self.relink(x, b, c, t, t2);
        self.touched.extend([t, t2]);
        if n != NONE {
            let t_child_with = |v: u32| if v == a { t } else { t2 };
            // n -> [p, m, d] (keeps its index), n2 -> [m, q, d].
            self.tris[n as usize] = [p, m, d];
            self.adj[n as usize] = [t_child_with(p), n2, yn];
            self.tris.push([m, q, d]);
            self.adj.push([t_child_with(q), xn, n]);
            self.labels.push(self.labels[n as usize]);
            self.origin.push(self.origin[n as usize]);
            self.relink(xn, q, d, n, n2);
            self.touched.extend([n, n2]);
        }
    }

    /// Bisects `t0` across its longest edge, first refining along the longest-edge
    /// propagation path until the edge is also the longest of the triangle beyond it.
    pub fn refine(&mut self, t0: u32) -> Result<(), DefectError> {
        let (k0, _) = self.longest(t0);
        let tri0 = self.tris[t0 as usize];
        let target = key(tri0[k0], tri0[(k0 + 1) % 3]);
        loop {
            if self.tris.len() > self.limit {
                return Err(DefectError::TooLarge { limit: self.limit });
            }
            let mut cur = t0;
            let (t, k) = loop {
                let (k, _) = self.longest(cur);
                let n = self.adj[cur as usize][k];
                if n == NONE {
                    break (cur, k);
                }
                let tri = self.tris[cur as usize];
                let j = self.local_edge(n, tri[k], tri[(k + 1) % 3]);
                if self.longest(n).0 == j {
                    break (cur, k);
                }
                cur = n;
            };
            let tri = self.tris[t as usize];
            let split = key(tri[k], tri[(k + 1) % 3]);
            self.bisect(t, k);
            if split == target {
                return Ok(());
            }
        }
    }
}
