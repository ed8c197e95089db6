//! Materials per region of the object (`[[material.region]]`, docs/scene-format.md):
//! a rough conductor (a preset metal or an explicit complex IOR, its own roughness, with
//! or without the finish's slope map) or a Lambertian diffuse material, chosen for parts
//! of the object by the selectors of `[object] inspect` (label, `"region:<id>"`, normal
//! with tolerance) or by glTF material name (`{ gltf_material = "name" }`).
//!
//! Entries are checked against their documented ranges when the scene file is read
//! ([`resolve`]); which triangles they cover is decided when the stage is built
//! ([`assign`]): a triangle chosen by two entries takes the earlier one, a triangle no
//! entry chooses keeps the `[material]` conductor.

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use super::config::{ConfigError, MaterialConfig};
use super::inspect::{NormalSelector, Selector};
use super::mesh::{FACE_OTHER, TriLabel, face_from_name, face_name};

const FIELD: &str = "material.region";

/// Most entries (the low byte of the per-triangle material word holds the entry, after
/// the table, light and `[material]` ids).
pub const MAX_ENTRIES: usize = 250;

/// A metal with a tabulated complex index of refraction at 550 nm (docs/scene-format.md,
/// "Conductor presets", gives sources).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    Aluminium,
    Steel,
    Copper,
    Titanium,
    Brass,
}

/// Wavelength of the preset table, nm.
pub const PRESET_WAVELENGTH_NM: f64 = 550.0;
/// How far `sensor.wavelength_nm` may be from it for a preset to be used, nm.
pub const PRESET_WAVELENGTH_TOLERANCE_NM: f64 = 10.0;

pub const PRESET_NAMES: &str = "\"aluminium\", \"steel\", \"copper\", \"titanium\", \"brass\"";

impl Preset {
    pub const ALL: [Preset; 5] = [
        Preset::Aluminium,
        Preset::Steel,
        Preset::Copper,
        Preset::Titanium,
        Preset::Brass,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Aluminium => "aluminium",
            Preset::Steel => "steel",
            Preset::Copper => "copper",
            Preset::Titanium => "titanium",
            Preset::Brass => "brass",
        }
    }

    /// By name; "aluminum" and "iron" are accepted too.
    pub fn from_name(s: &str) -> Option<Preset> {
        match s {
            "aluminium" | "aluminum" => Some(Preset::Aluminium),
            "steel" | "iron" => Some(Preset::Steel),
            "copper" => Some(Preset::Copper),
            "titanium" => Some(Preset::Titanium),
            "brass" => Some(Preset::Brass),
            _ => None,
        }
    }

    /// (n, k) at 550 nm:
    /// - aluminium: Rakic 1995 (the `[material]` default, unchanged);
    /// - steel: iron, Johnson & Christy 1974, the 2.26 eV (548.6 nm) row;
    /// - copper: Johnson & Christy 1972, the 2.26 eV (548.6 nm) row;
    /// - titanium: Rakic et al. 1998 Lorentz-Drude model evaluated at 550 nm;
    /// - brass (CuZn): Querry 1987, the 550 nm node.
    pub fn ior(self) -> (f32, f32) {
        match self {
            Preset::Aluminium => (super::config::AL_N_550, super::config::AL_K_550),
            Preset::Steel => (2.95, 2.93),
            Preset::Copper => (1.02, 2.577),
            Preset::Titanium => (1.79, 3.00),
            Preset::Brass => (0.527, 2.765),
        }
    }
}

/// Which BSDF an entry has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceKind {
    /// GGX rough conductor (as `[material]`).
    Conductor = 0,
    /// Lambertian.
    Diffuse = 1,
}

/// Whether the region carries the finish's slope map (`[texture]`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Finish {
    /// The slope map the region gets from `[texture]` / the dataset's finish (default for
    /// conductors).
    Texture,
    /// No slope map: the geometric normal (a polished region; default for diffuse).
    None,
}

/// One selector of an entry's `select` list as written.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum MaterialSelector {
    /// "A", "B", "C" (the inspected faces) or `"region:<id>"`.
    Name(String),
    /// `{ normal = [0, 0, 1], tolerance_deg = 5 }`.
    Normal(NormalSelector),
    /// `{ gltf_material = "name" }`: the triangles of glTF primitives with that material.
    Gltf(GltfMaterialSelector),
}

#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GltfMaterialSelector {
    pub gltf_material: String,
}

/// One `[[material.region]]` entry as written.
#[derive(Clone, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RegionMaterialConfig {
    /// Which triangles (at least one selector).
    #[serde(default)]
    pub select: Vec<MaterialSelector>,
    /// "conductor" (default) or "diffuse".
    pub kind: Option<String>,
    /// Conductor: a metal name ([`PRESET_NAMES`]); exclusive with `ior_n`/`ior_k`.
    pub preset: Option<String>,
    /// Conductor: explicit complex IOR (both or neither), (0, 10] and [0, 20].
    pub ior_n: Option<f32>,
    pub ior_k: Option<f32>,
    /// Conductor: GGX alpha (0, 1], or `roughness` r (0, 1] with alpha = r^2; neither:
    /// `[material]`'s alpha.
    pub alpha: Option<f32>,
    pub roughness: Option<f32>,
    /// Diffuse: Lambertian albedo, [0, 1], default 0.5.
    pub albedo: Option<f32>,
    /// "texture" (conductor default) or "none" (diffuse default).
    pub finish: Option<String>,
}

/// A checked selector.
#[derive(Clone, Debug, PartialEq)]
pub enum RegionSelector {
    /// `inspect`'s selectors: label (inspected face), region id, normal.
    Inspect(Selector),
    Gltf(String),
}

/// A checked entry: what the renderer needs.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMaterial {
    pub kind: SurfaceKind,
    /// GGX alpha (conductor).
    pub alpha: f32,
    /// Complex IOR (conductor).
    pub ior_n: f32,
    pub ior_k: f32,
    /// Lambertian albedo (diffuse).
    pub albedo: f32,
    pub finish: Finish,
    /// The preset it came from, if any.
    pub preset: Option<Preset>,
}

/// An entry with its selectors.
#[derive(Clone, Debug, PartialEq)]
pub struct RegionMaterial {
    pub selectors: Vec<RegionSelector>,
    pub material: SurfaceMaterial,
}

fn invalid(i: usize, message: String) -> ConfigError {
    ConfigError::Invalid {
        field: FIELD,
        message: format!("entry {i}: {message}"),
    }
}

fn in_range(
    i: usize,
    name: &str,
    v: f32,
    lo: f32,
    hi: f32,
    lo_open: bool,
    range: &str,
) -> Result<f32, ConfigError> {
    let ok = v.is_finite() && v <= hi && if lo_open { v > lo } else { v >= lo };
    if ok {
        Ok(v)
    } else {
        Err(invalid(
            i,
            format!("{name} = {v} is out of range: allowed {range}"),
        ))
    }
}

fn parse_selector(i: usize, s: &MaterialSelector) -> Result<RegionSelector, ConfigError> {
    match s {
        MaterialSelector::Name(n) => {
            if let Some(id) = n.strip_prefix("region:") {
                let id: u32 = id.trim().parse().map_err(|_| {
                    invalid(
                        i,
                        format!("select {n:?}: a region id is an integer >= 0, e.g. \"region:7\""),
                    )
                })?;
                return Ok(RegionSelector::Inspect(Selector::Region(id)));
            }
            match face_from_name(n) {
                Some(f) if f != FACE_OTHER => Ok(RegionSelector::Inspect(Selector::Label(f))),
                _ => Err(invalid(
                    i,
                    format!(
                        "select {n:?}: allowed \"A\", \"B\", \"C\", \"region:<id>\", {{ normal = [x, y, z], tolerance_deg = 5 }} or {{ gltf_material = \"name\" }}"
                    ),
                )),
            }
        }
        MaterialSelector::Normal(ns) => {
            let n = DVec3::from(ns.normal);
            if !n.is_finite() || n.length() < 1e-9 {
                return Err(invalid(
                    i,
                    format!("select normal = {:?}: a finite non-zero vector", ns.normal),
                ));
            }
            let t = ns.tolerance_deg;
            if !(t.is_finite() && (0.0..=90.0).contains(&t)) {
                return Err(invalid(
                    i,
                    format!("select tolerance_deg = {t}: allowed [0, 90] degrees"),
                ));
            }
            Ok(RegionSelector::Inspect(Selector::Normal {
                normal: n.normalize(),
                tolerance_deg: t,
            }))
        }
        MaterialSelector::Gltf(g) => {
            if g.gltf_material.is_empty() {
                return Err(invalid(i, "select gltf_material: an empty name".into()));
            }
            Ok(RegionSelector::Gltf(g.gltf_material.clone()))
        }
    }
}

/// Checks every entry against its documented range (field names and allowed values in
/// the errors); `base` gives what an entry leaves out (alpha, IOR), `wavelength_nm` is the
/// camera's (presets are tabulated at 550 nm).
pub fn resolve(
    entries: &[RegionMaterialConfig],
    base: &MaterialConfig,
    wavelength_nm: f64,
) -> Result<Vec<RegionMaterial>, ConfigError> {
    if entries.len() > MAX_ENTRIES {
        return Err(ConfigError::Invalid {
            field: FIELD,
            message: format!("{} entries; allowed at most {MAX_ENTRIES}", entries.len()),
        });
    }
    entries
        .iter()
        .enumerate()
        .map(|(i, e)| resolve_one(i, e, base, wavelength_nm))
        .collect()
}

fn resolve_one(
    i: usize,
    e: &RegionMaterialConfig,
    base: &MaterialConfig,
    wavelength_nm: f64,
) -> Result<RegionMaterial, ConfigError> {
    if e.select.is_empty() {
        return Err(invalid(
            i,
            "select: missing or empty; give at least one selector (\"A\", \"region:<id>\", { normal = [x, y, z] }, { gltf_material = \"name\" })".into(),
        ));
    }
    let selectors = e
        .select
        .iter()
        .map(|s| parse_selector(i, s))
        .collect::<Result<Vec<_>, _>>()?;
    let kind = match e.kind.as_deref() {
        None | Some("conductor") => SurfaceKind::Conductor,
        Some("diffuse") => SurfaceKind::Diffuse,
        Some(other) => {
            return Err(invalid(
                i,
                format!("kind = {other:?}: allowed \"conductor\", \"diffuse\""),
            ));
        }
    };
    let finish = match e.finish.as_deref() {
        None if kind == SurfaceKind::Diffuse => Finish::None,
        None | Some("texture") => Finish::Texture,
        Some("none") => Finish::None,
        Some(other) => {
            return Err(invalid(
                i,
                format!("finish = {other:?}: allowed \"texture\", \"none\""),
            ));
        }
    };
    let not_for = |field: &str, what: &str| {
        invalid(
            i,
            format!(
                "{field} is for {what} entries; this one is kind = \"{}\"",
                {
                    match kind {
                        SurfaceKind::Conductor => "conductor",
                        SurfaceKind::Diffuse => "diffuse",
                    }
                }
            ),
        )
    };
    match kind {
        SurfaceKind::Diffuse => {
            for (field, given) in [
                ("preset", e.preset.is_some()),
                ("ior_n", e.ior_n.is_some()),
                ("ior_k", e.ior_k.is_some()),
                ("alpha", e.alpha.is_some()),
                ("roughness", e.roughness.is_some()),
            ] {
                if given {
                    return Err(not_for(field, "conductor"));
                }
            }
            let albedo = in_range(
                i,
                "albedo",
                e.albedo.unwrap_or(0.5),
                0.0,
                1.0,
                false,
                "[0, 1]",
            )?;
            Ok(RegionMaterial {
                selectors,
                material: SurfaceMaterial {
                    kind,
                    alpha: base.alpha,
                    ior_n: base.ior_n,
                    ior_k: base.ior_k,
                    albedo,
                    finish,
                    preset: None,
                },
            })
        }
        SurfaceKind::Conductor => {
            if e.albedo.is_some() {
                return Err(not_for("albedo", "diffuse"));
            }
            let alpha = match (e.alpha, e.roughness) {
                (Some(a), Some(r)) => {
                    return Err(invalid(
                        i,
                        format!(
                            "both alpha = {a} and roughness = {r} given; give one (`roughness` is appleseed's / Disney's r with alpha = r^2, `alpha` is GGX alpha)"
                        ),
                    ));
                }
                (Some(a), None) => in_range(i, "alpha", a, 0.0, 1.0, true, "(0, 1]")?,
                (None, Some(r)) => {
                    let r = in_range(i, "roughness", r, 0.0, 1.0, true, "(0, 1] (alpha = r^2)")?;
                    r * r
                }
                (None, None) => base.alpha,
            };
            let (ior_n, ior_k, preset) = match (&e.preset, e.ior_n, e.ior_k) {
                (Some(p), None, None) => {
                    let preset = Preset::from_name(p).ok_or_else(|| {
                        invalid(i, format!("preset = {p:?}: allowed {PRESET_NAMES}"))
                    })?;
                    if (wavelength_nm - PRESET_WAVELENGTH_NM).abs() > PRESET_WAVELENGTH_TOLERANCE_NM
                    {
                        return Err(invalid(
                            i,
                            format!(
                                "preset = {p:?}: presets are tabulated at {PRESET_WAVELENGTH_NM} nm (within {PRESET_WAVELENGTH_TOLERANCE_NM} nm) and the camera's wavelength is {wavelength_nm} nm; give ior_n and ior_k for it"
                            ),
                        ));
                    }
                    let (n, k) = preset.ior();
                    (n, k, Some(preset))
                }
                (Some(_), _, _) => {
                    return Err(invalid(
                        i,
                        "preset and ior_n / ior_k given; give a preset or both ior_n and ior_k"
                            .into(),
                    ));
                }
                (None, Some(n), Some(k)) => (
                    in_range(i, "ior_n", n, 0.0, 10.0, true, "(0, 10]")?,
                    in_range(i, "ior_k", k, 0.0, 20.0, false, "[0, 20]")?,
                    None,
                ),
                (None, Some(_), None) | (None, None, Some(_)) => {
                    return Err(invalid(i, "give both ior_n and ior_k (or a preset)".into()));
                }
                (None, None, None) => (base.ior_n, base.ior_k, None),
            };
            Ok(RegionMaterial {
                selectors,
                material: SurfaceMaterial {
                    kind,
                    alpha,
                    ior_n,
                    ior_k,
                    albedo: 0.0,
                    finish,
                    preset,
                },
            })
        }
    }
}

/// glTF material names of a mesh's triangles (docs/mesh-format.md): `names` in the
/// file's order, `of_triangle` an index into it (`u32::MAX`: no material).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GltfMaterials {
    pub names: Vec<String>,
    pub of_triangle: Vec<u32>,
}

/// The entry each object triangle takes (`None`: the `[material]` conductor).
/// `labels`: the object's triangle labels (after `inspect`); `region_normals`: the
/// outward normal of each planar region by id; `region_of`: each object triangle's
/// region (`scene::regions`); `gltf`: the glTF material of each triangle when the object
/// is a glTF file. Errors name the entry and what it could not find.
pub fn assign(
    entries: &[RegionMaterial],
    labels: &[TriLabel],
    region_normals: &[Vec3],
    region_of: &[u32],
    gltf: Option<&GltfMaterials>,
) -> Result<Vec<Option<u16>>, ConfigError> {
    let n = region_of.len();
    let mut out: Vec<Option<u16>> = vec![None; n];
    for (i, e) in entries.iter().enumerate() {
        for sel in &e.selectors {
            let tris: Vec<usize> = match sel {
                RegionSelector::Inspect(Selector::Label(f)) => {
                    (0..n).filter(|&t| labels[t].face == *f).collect()
                }
                RegionSelector::Inspect(Selector::Region(id)) => {
                    if *id as usize >= region_normals.len() {
                        return Err(invalid(
                            i,
                            format!(
                                "select region:{id}: the mesh has {} planar regions; allowed region:0 to region:{}",
                                region_normals.len(),
                                region_normals.len().saturating_sub(1)
                            ),
                        ));
                    }
                    (0..n).filter(|&t| region_of[t] == *id).collect()
                }
                RegionSelector::Inspect(Selector::Normal {
                    normal,
                    tolerance_deg,
                }) => {
                    let cos = tolerance_deg.to_radians().cos();
                    let hit: Vec<bool> = region_normals
                        .iter()
                        .map(|r| r.as_dvec3().dot(*normal) >= cos - 1e-12)
                        .collect();
                    (0..n)
                        .filter(|&t| hit.get(region_of[t] as usize).copied().unwrap_or(false))
                        .collect()
                }
                RegionSelector::Gltf(name) => {
                    let g = gltf.ok_or_else(|| {
                        invalid(
                            i,
                            format!(
                                "select gltf_material {name:?}: the object is not a glTF file (glTF material names need object.path = a .gltf/.glb)"
                            ),
                        )
                    })?;
                    if g.of_triangle.len() != n {
                        return Err(invalid(
                            i,
                            format!(
                                "select gltf_material {name:?}: the object has {n} triangles but its glTF file {}",
                                g.of_triangle.len()
                            ),
                        ));
                    }
                    let idx = g.names.iter().position(|m| m == name).ok_or_else(|| {
                        invalid(
                            i,
                            format!(
                                "select gltf_material {name:?}: the file has no such material; it has {:?}",
                                g.names
                            ),
                        )
                    })? as u32;
                    (0..n).filter(|&t| g.of_triangle[t] == idx).collect()
                }
            };
            if tris.is_empty() {
                return Err(invalid(
                    i,
                    format!(
                        "select {}: chooses no triangle of the object",
                        describe(sel)
                    ),
                ));
            }
            for t in tris {
                if out[t].is_none() {
                    out[t] = Some(i as u16);
                }
            }
        }
    }
    Ok(out)
}

fn describe(s: &RegionSelector) -> String {
    match s {
        RegionSelector::Inspect(Selector::Label(f)) => format!("{:?}", face_name(*f)),
        RegionSelector::Inspect(other) => other.describe(),
        RegionSelector::Gltf(n) => format!("gltf_material {n:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::config::SceneConfig;

    fn err(text: &str) -> String {
        SceneConfig::parse(text).expect_err(text).to_string()
    }

    #[test]
    fn presets_and_defaults() {
        let c = SceneConfig::parse(
            "[material]\nroughness = 0.4\n[[material.region]]\nselect = [\"A\"]\npreset = \"steel\"\n[[material.region]]\nselect = [\"region:2\", { normal = [0, 0, 1] }]\nkind = \"diffuse\"\n",
        )
        .expect("scene");
        let r = resolve(&c.material.region, &c.material, 550.0).expect("entries");
        assert_eq!(r.len(), 2);
        let steel = &r[0].material;
        assert_eq!((steel.ior_n, steel.ior_k), Preset::Steel.ior());
        assert!(
            (steel.alpha - 0.16).abs() < 1e-6,
            "inherits [material] alpha"
        );
        assert_eq!(steel.finish, Finish::Texture);
        let d = &r[1].material;
        assert_eq!(
            (d.kind, d.albedo, d.finish),
            (SurfaceKind::Diffuse, 0.5, Finish::None)
        );
        assert_eq!(r[1].selectors.len(), 2);
        // Aluminium is the [material] default, number for number.
        let al = Preset::Aluminium.ior();
        let m = crate::scene::config::MaterialConfig::default();
        assert_eq!(al, (m.ior_n, m.ior_k));
    }

    #[test]
    fn errors_name_the_field_and_the_allowed_values() {
        let base = "[[material.region]]\nselect = [\"A\"]\n";
        for (extra, want) in [
            (
                "preset = \"bronze\"\n",
                "preset = \"bronze\": allowed \"aluminium\"",
            ),
            (
                "kind = \"glass\"\n",
                "kind = \"glass\": allowed \"conductor\", \"diffuse\"",
            ),
            (
                "finish = \"mirror\"\n",
                "finish = \"mirror\": allowed \"texture\", \"none\"",
            ),
            ("alpha = 0.0\n", "alpha = 0 is out of range: allowed (0, 1]"),
            (
                "roughness = 1.5\n",
                "roughness = 1.5 is out of range: allowed (0, 1]",
            ),
            (
                "alpha = 0.1\nroughness = 0.3\n",
                "both alpha = 0.1 and roughness = 0.3",
            ),
            (
                "ior_n = 11.0\nior_k = 1.0\n",
                "ior_n = 11 is out of range: allowed (0, 10]",
            ),
            ("ior_n = 1.0\n", "give both ior_n and ior_k"),
            (
                "preset = \"copper\"\nior_k = 3.0\n",
                "preset and ior_n / ior_k",
            ),
            ("albedo = 0.5\n", "albedo is for diffuse entries"),
            (
                "kind = \"diffuse\"\nalbedo = 1.5\n",
                "albedo = 1.5 is out of range: allowed [0, 1]",
            ),
            (
                "kind = \"diffuse\"\npreset = \"steel\"\n",
                "preset is for conductor entries",
            ),
        ] {
            let e = err(&format!("{base}{extra}"));
            assert!(
                e.contains("material.region") && e.contains("entry 0"),
                "{e}"
            );
            assert!(e.contains(want), "{extra:?}: {e}");
        }
        let e = err("[[material.region]]\npreset = \"steel\"\n");
        assert!(e.contains("select: missing or empty"), "{e}");
        let e = err("[[material.region]]\nselect = [\"D\"]\n");
        assert!(e.contains("select \"D\": allowed \"A\""), "{e}");
        let e = err("[[material.region]]\nselect = [{ normal = [0, 0, 0] }]\n");
        assert!(e.contains("a finite non-zero vector"), "{e}");
        let e = err(
            "[sensor]\nwavelength_nm = 650\n[[material.region]]\nselect = [\"A\"]\npreset = \"copper\"\n",
        );
        assert!(
            e.contains("tabulated at 550 nm") && e.contains("650"),
            "{e}"
        );
        let e = err("[[material.region]]\nselect = [\"A\"]\nshine = 1\n");
        assert!(e.contains("shine"), "{e}");
    }

    #[test]
    fn selection_on_the_test_body() {
        use crate::scene::regions::{RegionTolerance, planar_regions, region_per_triangle};
        use crate::scene::{Variant, testbody};
        let mesh = testbody(Variant::B);
        let found = planar_regions(&mesh, &RegionTolerance::default());
        let normals: Vec<Vec3> = found.iter().map(|r| r.normal).collect();
        let region_of = region_per_triangle(&mesh, &found);
        let on = |r: &[RegionMaterial], g: Option<&GltfMaterials>| {
            assign(r, &mesh.labels, &normals, &region_of, g)
        };
        let c = SceneConfig::parse(
            "[[material.region]]\nselect = [\"A\"]\npreset = \"copper\"\n[[material.region]]\nselect = [\"A\", { normal = [0, 0, 1] }]\nkind = \"diffuse\"\n",
        )
        .unwrap();
        let r = resolve(&c.material.region, &c.material, 550.0).unwrap();
        let per = on(&r, None).unwrap();
        for (t, m) in per.iter().enumerate() {
            let a = mesh.labels[t].face == crate::scene::mesh::FACE_A;
            let up = mesh.area_normal(t).normalize().z > 0.9999;
            let want = if a {
                Some(0)
            } else if up {
                Some(1)
            } else {
                None
            };
            assert_eq!(*m, want, "triangle {t}");
        }
        assert!(per.contains(&Some(1)), "the top faces are diffuse");
        // Errors: a region past the last, a normal nothing has, glTF names without glTF.
        for (sel, want) in [
            ("\"region:999\"", "allowed region:0 to region:"),
            (
                "{ normal = [0.3, 0.7, 0.1], tolerance_deg = 0 }",
                "chooses no triangle",
            ),
            ("{ gltf_material = \"Steel\" }", "not a glTF file"),
        ] {
            let c =
                SceneConfig::parse(&format!("[[material.region]]\nselect = [{sel}]\n")).unwrap();
            let r = resolve(&c.material.region, &c.material, 550.0).unwrap();
            let e = on(&r, None).unwrap_err().to_string();
            assert!(
                e.contains("material.region") && e.contains(want),
                "{sel}: {e}"
            );
        }
        let g = GltfMaterials {
            names: vec!["Body".into(), "Seat".into()],
            of_triangle: (0..mesh.triangles.len() as u32).map(|t| t % 2).collect(),
        };
        let c =
            SceneConfig::parse("[[material.region]]\nselect = [{ gltf_material = \"Seat\" }]\n")
                .unwrap();
        let r = resolve(&c.material.region, &c.material, 550.0).unwrap();
        let per = on(&r, Some(&g)).unwrap();
        assert!(
            per.iter()
                .enumerate()
                .all(|(t, m)| (*m == Some(0)) == (t % 2 == 1))
        );
        let c = SceneConfig::parse("[[material.region]]\nselect = [{ gltf_material = \"Nut\" }]\n")
            .unwrap();
        let r = resolve(&c.material.region, &c.material, 550.0).unwrap();
        let e = on(&r, Some(&g)).unwrap_err().to_string();
        assert!(e.contains("no such material") && e.contains("Seat"), "{e}");
    }
}
