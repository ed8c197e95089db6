//! Imprinting a defect set: refine each inspected face around its defects by conforming
//! bisection, then move the face's vertices along -normal by the tools' height field.
//!
//! On a planar face the Boolean difference "solid minus tool" is exactly a height field
//! below the face, so displacing a refined face gives its piecewise-linear interpolant:
//! exact at every vertex, watertight by construction (bisection never leaves a
//! T-junction, and border vertices never move), and never flipped (a height field keeps
//! every triangle's projection onto the face).

use glam::{DVec2, DVec3, Vec3};

use super::DefectError;
use super::refine::Refiner;
use super::region::Region;
use super::sample::{Defect, DefectSet, Shape};
use super::slice::{Pieces, slice_scratch};
use super::tool::{DefectTool, combined_height};
use crate::scene::Mesh;
use crate::scene::mesh::{CLASS_DENT, CLASS_SCRATCH, FaceId, TriLabel};

/// Upper bound on output triangles, so a silly spec fails cleanly instead of exhausting
/// memory.
const TRIANGLE_LIMIT: usize = 20_000_000;

/// What imprinting did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImprintStats {
    pub triangles_in: usize,
    pub triangles_out: usize,
    pub vertices_displaced: usize,
    pub triangles_labelled: usize,
}

/// How a scratch is meshed (docs/defects.md, "Imprint").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScratchMesh {
    /// Long triangles along the path, rows of vertices at fixed offsets across it: the
    /// resolution across as with `Isotropic`, far fewer triangles.
    #[default]
    Anisotropic,
    /// Every triangle near the scratch bisected until its longest edge is at most
    /// `width / resolution` (the meshes before issue 15; kept for comparison).
    Isotropic,
}

/// Options of [`imprint_with_options`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ImprintOptions {
    pub scratch_mesh: ScratchMesh,
}

/// A set may come from a user's JSON file: check what the tools index or divide by.
fn check_defect(d: &Defect) -> Result<(), DefectError> {
    let bad = |what: &str| {
        Err(DefectError::BadSet(format!(
            "defect instance {}: {what}",
            d.instance
        )))
    };
    let pos = |x: f64| x.is_finite() && x > 0.0;
    if d.instance == 0 {
        return bad("instance must be 1 or more");
    }
    match &d.shape {
        Shape::Dent(s) => {
            if d.class != CLASS_DENT {
                return bad("a dent must have class 1");
            }
            if !(pos(s.diameter_mm) && pos(s.minor_mm) && pos(s.depth_mm))
                || s.minor_mm > s.diameter_mm
            {
                return bad(
                    "diameter_mm, minor_mm, depth_mm must be positive, minor_mm <= diameter_mm",
                );
            }
            let finite =
                s.centre_uv_mm
                    .iter()
                    .chain([&s.rotation_deg, &s.rim_height_mm, &s.rim_width]);
            if finite.into_iter().any(|x| !x.is_finite())
                || s.rim_height_mm < 0.0
                || s.rim_width < 0.0
            {
                return bad("centre, rotation and rim must be finite, rim non-negative");
            }
        }
        Shape::Scratch(s) => {
            if d.class != CLASS_SCRATCH {
                return bad("a scratch must have class 2");
            }
            if s.path_uv_mm.len() < 2 || s.depth_mm.len() != s.path_uv_mm.len() {
                return bad("path_uv_mm needs at least 2 points and depth_mm one value per point");
            }
            if !pos(s.width_mm)
                || s.path_uv_mm.iter().flatten().any(|x| !x.is_finite())
                || s.depth_mm.iter().any(|&x| !(x.is_finite() && x >= 0.0))
            {
                return bad(
                    "width_mm must be positive, path finite, depths finite and non-negative",
                );
            }
        }
    }
    Ok(())
}

/// Imprints `set` into `mesh`; see [`imprint_with_stats`].
pub fn imprint(mesh: &Mesh, set: &DefectSet) -> Result<Mesh, DefectError> {
    imprint_with_stats(mesh, set).map(|(m, _)| m)
}

/// Imprints every defect of `set` into the face it names, in that face's frame computed
/// from this mesh (so a set sampled on one body re-applies to another with the same
/// labelled faces). Fails if a face is missing or not planar, or a defect does not fit
/// inside its face here.
pub fn imprint_with_stats(
    mesh: &Mesh,
    set: &DefectSet,
) -> Result<(Mesh, ImprintStats), DefectError> {
    imprint_with_options(mesh, set, ImprintOptions::default())
}

/// As [`imprint_with_stats`], with a choice of how scratches are meshed.
pub fn imprint_with_options(
    mesh: &Mesh,
    set: &DefectSet,
    options: ImprintOptions,
) -> Result<(Mesh, ImprintStats), DefectError> {
    imprint_inner(mesh, set, options).map(|(m, s, _)| (m, s))
}

/// As [`imprint`], with the input triangle each output triangle is a piece of (so
/// per-triangle data of the input, e.g. glTF materials, can follow the refinement).
pub fn imprint_traced(mesh: &Mesh, set: &DefectSet) -> Result<(Mesh, Vec<u32>), DefectError> {
    imprint_inner(mesh, set, ImprintOptions::default()).map(|(m, _, o)| (m, o))
}

fn imprint_inner(
    mesh: &Mesh,
    set: &DefectSet,
    options: ImprintOptions,
) -> Result<(Mesh, ImprintStats, Vec<u32>), DefectError> {
    if !(set.resolution.is_finite() && (2.0..=64.0).contains(&set.resolution)) {
        return Err(DefectError::BadSet(format!(
            "resolution = {}: allowed 2 ... 64",
            set.resolution
        )));
    }
    let mut faces: Vec<FaceId> = Vec::new();
    for d in &set.defects {
        check_defect(d)?;
        let f = d.face_id().ok_or_else(|| DefectError::MissingFace {
            instance: d.instance,
            face: d.face.clone(),
        })?;
        if !faces.contains(&f) {
            faces.push(f);
        }
    }
    let regions = Region::of_mesh(mesh, &faces);
    // Tools per face, in the face's frame.
    let mut tools: Vec<DefectTool> = Vec::with_capacity(set.defects.len());
    let mut face_tools: Vec<(usize, Vec<usize>)> = Vec::new(); // (region index, tools)
    for d in &set.defects {
        let f = d.face_id().unwrap_or(0);
        let ri =
            regions
                .iter()
                .position(|r| r.face == f)
                .ok_or_else(|| DefectError::MissingFace {
                    instance: d.instance,
                    face: d.face.clone(),
                })?;
        regions[ri].check_planar(mesh)?;
        let tool = DefectTool::new(d, set.resolution);
        if !tool.fits(&regions[ri]) {
            return Err(DefectError::OutsideFace {
                instance: d.instance,
                face: d.face.clone(),
            });
        }
        tools.push(tool);
        match face_tools.iter_mut().find(|(r, _)| *r == ri) {
            Some((_, v)) => v.push(tools.len() - 1),
            None => face_tools.push((ri, vec![tools.len() - 1])),
        }
    }
    let tools_of = |face: FaceId| -> Option<(&Region, &[usize])> {
        face_tools
            .iter()
            .find(|(ri, _)| regions[*ri].face == face)
            .map(|(ri, v)| (&regions[*ri], v.as_slice()))
    };

    let mut r = Refiner::new(
        mesh.positions.iter().map(|p| p.as_dvec3()).collect(),
        mesh.triangles.clone(),
        mesh.labels.clone(),
        TRIANGLE_LIMIT,
    )?;

    // Refine every triangle of a defected face that comes near a footprint until its
    // longest edge is at most that defect's target edge (for anisotropic scratches the
    // edge along the path there; the rows cut below give the resolution across).
    let anisotropic = options.scratch_mesh == ScratchMesh::Anisotropic;
    let needs = |r: &Refiner, t: u32| -> bool {
        let Some((region, idx)) = tools_of(r.labels[t as usize].face) else {
            return false;
        };
        let (_, l2) = r.longest(t);
        let tri = r.tris[t as usize].map(|i| r.positions[i as usize]);
        let c3 = (tri[0] + tri[1] + tri[2]) / 3.0;
        let reach = tri.iter().map(|p| p.distance(c3)).fold(0.0, f64::max);
        let c = region.to_uv(c3);
        idx.iter().any(|&k| {
            let tool = &tools[k];
            tool.edge_near(c, reach + 0.5 * tool.edge_mm, anisotropic)
                .is_some_and(|h| l2 > h * h)
        })
    };
    let mut work: Vec<u32> = (0..r.tris.len() as u32)
        .filter(|&t| tools_of(r.labels[t as usize].face).is_some())
        .collect();
    while let Some(t) = work.pop() {
        if needs(&r, t) {
            r.refine(t)?;
            work.append(&mut r.touched);
        }
    }

    if anisotropic {
        for (ri, idx) in &face_tools {
            for &k in idx {
                let pieces = Pieces {
                    positions: &mut r.positions,
                    tris: &mut r.tris,
                    labels: &mut r.labels,
                    origin: &mut r.origin,
                };
                slice_scratch(pieces, &regions[*ri], &tools[k], TRIANGLE_LIMIT)?;
            }
        }
    }

    // A vertex moves only if every triangle around it lies on the same defected face:
    // border vertices stay, so neighbouring faces remain attached.
    const MIXED: u8 = u8::MAX;
    const UNSET: u8 = u8::MAX - 1;
    let mut vface = vec![UNSET; r.positions.len()];
    for (tri, l) in r.tris.iter().zip(&r.labels) {
        for &i in tri {
            let v = &mut vface[i as usize];
            if *v == UNSET {
                *v = l.face;
            } else if *v != l.face {
                *v = MIXED;
            }
        }
    }
    let mut height = vec![0.0f64; r.positions.len()];
    let mut winner: Vec<Option<usize>> = vec![None; r.positions.len()];
    let mut displaced = 0;
    for (i, p) in r.positions.iter_mut().enumerate() {
        if vface[i] == MIXED || vface[i] == UNSET {
            continue;
        }
        let Some((region, idx)) = tools_of(vface[i]) else {
            continue;
        };
        let uv: DVec2 = region.to_uv(*p);
        let (h, who) = combined_height(&tools, idx, uv);
        // Below 0.1 nm a displacement is lost in f32 positions anyway; leaving such
        // vertices flat keeps labels to where the surface really moved.
        if who.is_some() && h.abs() > 1e-7 {
            *p += region.normal * h;
            height[i] = h;
            winner[i] = who;
            displaced += 1;
        }
    }

    // A triangle belongs to the defect that displaced its most-displaced vertex.
    let mut labelled = 0;
    for (tri, l) in r.tris.iter().zip(r.labels.iter_mut()) {
        let best = tri
            .iter()
            .filter(|&&i| winner[i as usize].is_some())
            .max_by(|&&a, &&b| {
                height[a as usize]
                    .abs()
                    .total_cmp(&height[b as usize].abs())
            });
        if let Some(&v) = best
            && let Some(k) = winner[v as usize]
        {
            *l = TriLabel {
                face: l.face,
                class: tools[k].class,
                instance: tools[k].instance,
            };
            labelled += 1;
        }
    }

    let stats = ImprintStats {
        triangles_in: mesh.triangles.len(),
        triangles_out: r.tris.len(),
        vertices_displaced: displaced,
        triangles_labelled: labelled,
    };
    let out = Mesh {
        positions: r
            .positions
            .iter()
            .map(|p: &DVec3| -> Vec3 { p.as_vec3() })
            .collect(),
        triangles: r.tris,
        labels: r.labels,
    };
    Ok((out, stats, r.origin))
}
