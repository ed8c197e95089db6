//! Choosing the inspected faces of a mesh (`[object] inspect`, docs/scene-format.md): by
//! label (`"A"`, as glTF extras or OBJ group names carry them), by planar region id
//! (`"region:7"`, `scene::regions`), or by a normal direction with a tolerance (every
//! planar region whose normal is within it). The chosen triangles are relabelled as the
//! inspected faces A, B, C (ids 1, 2, 3 in the face-id mask); every other triangle of the
//! object becomes "other". Defect labels (class, instance) are kept.
//!
//! Letters: a label selector keeps its letter; the other selectors take the letters not
//! used by a label selector, A, B, C in order. At most three entries; a triangle chosen by
//! two entries belongs to the earlier one.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::config::ConfigError;
use super::mesh::{FACE_A, FACE_OTHER, FaceId, Mesh, face_from_name, face_name};
use super::regions::{PlanarRegion, RegionTolerance, planar_regions};

/// Default of `tolerance_deg` in a normal selector, degrees.
pub const DEFAULT_NORMAL_TOLERANCE_DEG: f64 = 5.0;

/// One `inspect` entry as written.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum InspectEntry {
    /// "A", "B", "C" or `"region:<id>"`.
    Name(String),
    /// `{ normal = [0, 0, 1], tolerance_deg = 5 }`.
    Normal(NormalSelector),
}

/// Every planar region whose outward normal is within `tolerance_deg` of `normal`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct NormalSelector {
    /// Direction (any length > 0), world axes of the mesh file.
    pub normal: [f64; 3],
    /// Degrees, [0, 90], default 5.
    #[serde(default = "default_tol")]
    pub tolerance_deg: f64,
}

fn default_tol() -> f64 {
    DEFAULT_NORMAL_TOLERANCE_DEG
}

/// A checked selector.
#[derive(Clone, Debug, PartialEq)]
pub enum Selector {
    Label(FaceId),
    Region(u32),
    Normal { normal: DVec3, tolerance_deg: f64 },
}

impl Selector {
    pub fn describe(&self) -> String {
        match self {
            Selector::Label(f) => format!("label {}", face_name(*f)),
            Selector::Region(r) => format!("region:{r}"),
            Selector::Normal {
                normal,
                tolerance_deg,
            } => format!(
                "normal [{:.4}, {:.4}, {:.4}] within {tolerance_deg} deg",
                normal.x, normal.y, normal.z
            ),
        }
    }
}

const FIELD: &str = "object.inspect";

fn invalid(i: usize, message: String) -> ConfigError {
    ConfigError::Invalid {
        field: FIELD,
        message: format!("entry {i}: {message}"),
    }
}

/// Checks the entries (syntax and ranges; region ids are checked against the mesh by
/// [`apply`]) and gives each its face letter. Result: (face id, selector) per entry.
pub fn parse(entries: &[InspectEntry]) -> Result<Vec<(FaceId, Selector)>, ConfigError> {
    if entries.is_empty() || entries.len() > 3 {
        return Err(ConfigError::Invalid {
            field: FIELD,
            message: format!(
                "{} entries; allowed 1 to 3 (the inspected faces A, B, C)",
                entries.len()
            ),
        });
    }
    let mut sels = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let s = match e {
            InspectEntry::Name(n) => {
                if let Some(id) = n.strip_prefix("region:") {
                    let id: u32 = id.trim().parse().map_err(|_| {
                        invalid(
                            i,
                            format!("{n:?}: a region id is an integer >= 0, e.g. \"region:7\""),
                        )
                    })?;
                    Selector::Region(id)
                } else {
                    match face_from_name(n) {
                        Some(f) if f != FACE_OTHER => Selector::Label(f),
                        _ => {
                            return Err(invalid(
                                i,
                                format!(
                                    "{n:?}: allowed \"A\", \"B\", \"C\", \"region:<id>\" or {{ normal = [x, y, z], tolerance_deg = 5 }}"
                                ),
                            ));
                        }
                    }
                }
            }
            InspectEntry::Normal(ns) => {
                let n = DVec3::from(ns.normal);
                if !n.is_finite() || n.length() < 1e-9 {
                    return Err(invalid(
                        i,
                        format!("normal = {:?}: a finite non-zero vector", ns.normal),
                    ));
                }
                let t = ns.tolerance_deg;
                if !(t.is_finite() && (0.0..=90.0).contains(&t)) {
                    return Err(invalid(
                        i,
                        format!("tolerance_deg = {t}: allowed [0, 90] degrees"),
                    ));
                }
                Selector::Normal {
                    normal: n.normalize(),
                    tolerance_deg: t,
                }
            }
        };
        sels.push(s);
    }
    let mut used: Vec<FaceId> = Vec::new();
    for (i, s) in sels.iter().enumerate() {
        if let Selector::Label(f) = s {
            if used.contains(f) {
                return Err(invalid(i, format!("label {} chosen twice", face_name(*f))));
            }
            used.push(*f);
        }
    }
    let mut free = (FACE_A..=3).filter(|f| !used.contains(f));
    Ok(sels
        .into_iter()
        .map(|s| match s {
            Selector::Label(f) => (f, s),
            other => (free.next().expect("at most 3 entries"), other),
        })
        .collect())
}

/// What one inspected face became.
#[derive(Clone, Debug, PartialEq)]
pub struct InspectedFace {
    pub face: FaceId,
    pub selector: Selector,
    /// Planar regions it covers (empty for a label selector).
    pub regions: Vec<u32>,
    pub triangles: usize,
    /// mm^2.
    pub area: f64,
}

/// Relabels `mesh` by the selection. Regions are found with `tol` only when a region
/// or normal selector needs them. Errors name `object.inspect`, the entry and the range.
pub fn apply(
    mesh: &mut Mesh,
    selection: &[(FaceId, Selector)],
    tol: &RegionTolerance,
) -> Result<Vec<InspectedFace>, ConfigError> {
    let needs_regions = selection
        .iter()
        .any(|(_, s)| !matches!(s, Selector::Label(_)));
    let regions: Vec<PlanarRegion> = if needs_regions {
        planar_regions(mesh, tol)
    } else {
        Vec::new()
    };
    let n = mesh.triangles.len();
    let mut new_face: Vec<Option<FaceId>> = vec![None; n];
    let mut out = Vec::new();
    for (i, (face, sel)) in selection.iter().enumerate() {
        let (tris, regs): (Vec<usize>, Vec<u32>) = match sel {
            Selector::Label(f) => (
                (0..n).filter(|&t| mesh.labels[t].face == *f).collect(),
                Vec::new(),
            ),
            Selector::Region(id) => {
                let r = regions.get(*id as usize).ok_or_else(|| {
                    invalid(
                        i,
                        format!(
                            "region:{id}: the mesh has {} planar regions; allowed region:0 to region:{}",
                            regions.len(),
                            regions.len().saturating_sub(1)
                        ),
                    )
                })?;
                (
                    r.triangles.iter().map(|&t| t as usize).collect(),
                    vec![r.id],
                )
            }
            Selector::Normal {
                normal,
                tolerance_deg,
            } => {
                let cos = tolerance_deg.to_radians().cos();
                let hit: Vec<&PlanarRegion> = regions
                    .iter()
                    .filter(|r| r.normal.as_dvec3().dot(*normal) >= cos - 1e-12)
                    .collect();
                (
                    hit.iter()
                        .flat_map(|r| r.triangles.iter().map(|&t| t as usize))
                        .collect(),
                    hit.iter().map(|r| r.id).collect(),
                )
            }
        };
        let mut count = 0;
        let mut area = 0.0;
        for t in tris {
            if new_face[t].is_none() {
                new_face[t] = Some(*face);
                count += 1;
                area += 0.5 * mesh.area_normal(t).as_dvec3().length();
            }
        }
        if count == 0 {
            return Err(invalid(
                i,
                format!(
                    "{} selects no triangle of the mesh (or only triangles an earlier entry took)",
                    sel.describe()
                ),
            ));
        }
        out.push(InspectedFace {
            face: *face,
            selector: sel.clone(),
            regions: regs,
            triangles: count,
            area,
        });
    }
    for (l, f) in mesh.labels.iter_mut().zip(new_face) {
        l.face = f.unwrap_or(FACE_OTHER);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mesh::{FACE_B, FACE_C};
    use crate::scene::testbody::{Variant, face_frames, testbody};

    fn entries(toml_text: &str) -> Vec<InspectEntry> {
        #[derive(Deserialize)]
        struct W {
            inspect: Vec<InspectEntry>,
        }
        toml::from_str::<W>(toml_text).unwrap().inspect
    }

    #[test]
    fn letters_labels_regions_normals() {
        let e = entries(r#"inspect = ["B", "region:3", { normal = [0, 0, 2] }]"#);
        let p = parse(&e).unwrap();
        assert_eq!(p[0], (FACE_B, Selector::Label(FACE_B)));
        assert_eq!(p[1], (FACE_A, Selector::Region(3)));
        assert_eq!(p[2].0, FACE_C);
        assert_eq!(
            p[2].1,
            Selector::Normal {
                normal: DVec3::Z,
                tolerance_deg: 5.0
            }
        );
        for bad in [
            r#"inspect = ["D"]"#,
            r#"inspect = ["region:x"]"#,
            r#"inspect = ["A", "A"]"#,
            r#"inspect = []"#,
            r#"inspect = ["A", "B", "C", "region:1"]"#,
            r#"inspect = [{ normal = [0, 0, 0] }]"#,
            r#"inspect = [{ normal = [0, 0, 1], tolerance_deg = 91 }]"#,
        ] {
            let e = parse(&entries(bad)).unwrap_err().to_string();
            assert!(e.contains("object.inspect"), "{bad}: {e}");
        }
    }

    /// Selecting the test body's cut A by region id or by its normal gives the same
    /// triangles and face frame as its label; the top face by normal +Z.
    #[test]
    fn region_and_normal_select_the_labelled_face() {
        let body = testbody(Variant::B);
        let tol = RegionTolerance::default();
        let regions = planar_regions(&body, &tol);
        let ra = regions.iter().find(|r| r.face == FACE_A).unwrap();
        let frame_a = face_frames(&body)[0];
        let by_label = {
            let mut m = body.clone();
            apply(
                &mut m,
                &parse(&entries(r#"inspect = ["A"]"#)).unwrap(),
                &tol,
            )
            .unwrap();
            m
        };
        assert!(face_frames(&by_label).len() == 1);
        let mut m = body.clone();
        let text = format!(r#"inspect = ["region:{}"]"#, ra.id);
        let faces = apply(&mut m, &parse(&entries(&text)).unwrap(), &tol).unwrap();
        // Region A's triangles are face A (id 1): the labelled square and its ring.
        assert_eq!(faces[0].triangles, ra.triangles.len());
        assert!((faces[0].area - ra.area).abs() < 1e-6 * ra.area);
        let f = face_frames(&m);
        assert_eq!((f.len(), f[0].face), (1, FACE_A));
        assert!((f[0].normal - frame_a.normal).length() < 1e-5);
        // The normal selector finds exactly region A.
        let normal = format!(
            "{{ normal = [{}, {}, {}], tolerance_deg = 1 }}",
            ra.normal.x, ra.normal.y, ra.normal.z
        );
        let mut m2 = body.clone();
        let text = format!("inspect = [{normal}]");
        let faces = apply(&mut m2, &parse(&entries(&text)).unwrap(), &tol).unwrap();
        assert_eq!(faces[0].regions, vec![ra.id]);
        assert_eq!(m2.labels, m.labels);
        // After the region entry took it, the normal entry selects nothing: an error.
        let text = format!(r#"inspect = ["region:{}", {normal}]"#, ra.id);
        let e = apply(&mut body.clone(), &parse(&entries(&text)).unwrap(), &tol)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("entry 1") && e.contains("selects no triangle"),
            "{e}"
        );
        // Top face by +Z: one region, area 40 x 40 minus the cuts' share, face A.
        let mut m3 = body.clone();
        let faces = apply(
            &mut m3,
            &parse(&entries(r#"inspect = [{ normal = [0, 0, 1] }]"#)).unwrap(),
            &tol,
        )
        .unwrap();
        assert_eq!(faces[0].regions.len(), 1);
        assert!(m3.labels.iter().all(|l| l.face == FACE_A || l.face == 0));
        // A region id past the last names the range.
        let mut m4 = body.clone();
        let e = apply(
            &mut m4,
            &parse(&entries(r#"inspect = ["region:99"]"#)).unwrap(),
            &tol,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("object.inspect") && e.contains("region:8"),
            "{e}"
        );
    }
}
