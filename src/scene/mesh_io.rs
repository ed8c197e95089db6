//! Mesh files of any common format: glTF/GLB (`gltf_io`), Wavefront OBJ (`tobj`), STL,
//! binary and ASCII (`stl_io`), and PLY, ASCII and binary (`ply-rs-bw`), read into one
//! [`Mesh`] in millimetres with a declared unit. docs/mesh-format.md.
//!
//! Units: positions are multiplied by the unit's millimetres (1, 1000 or 25.4) in f64 and
//! rounded once to f32, so a file in millimetres loads bit-exactly as written. A glTF
//! file without a declared unit is in metres by the glTF specification, except files
//! synosis wrote (their `asset.generator` starts with "synosis"; they are millimetres)
//! and files named by the old scene key `gltf = ...`, read in millimetres as before.
//! OBJ, STL and PLY carry no unit; without one they are read in millimetres.
//!
//! Labels: glTF as `gltf_io` reads them; OBJ objects or groups named `A`, `B`, `C` (or
//! `face_A`, ...) mark their triangles as that face; STL and PLY carry none (the scene's
//! `inspect` selection labels them, `scene::inspect`).

use std::io::BufReader;
use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::gltf_io::{
    Degenerates, Imported, MeshError, check_imported, check_mesh_file, import_mesh,
};
use super::mesh::{Mesh, TriLabel, face_from_name};

/// The length unit of a mesh file's coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshUnit {
    /// Millimetres (the scene unit).
    Mm,
    /// Metres (glTF's unit by its specification).
    M,
    /// Inches (25.4 mm).
    In,
}

impl MeshUnit {
    /// Millimetres per unit.
    pub fn mm(self) -> f64 {
        match self {
            MeshUnit::Mm => 1.0,
            MeshUnit::M => 1000.0,
            MeshUnit::In => 25.4,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            MeshUnit::Mm => "mm",
            MeshUnit::M => "m",
            MeshUnit::In => "in",
        }
    }
}

/// A mesh file format, by extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    Gltf,
    Obj,
    Stl,
    Ply,
}

impl MeshFormat {
    /// The format of `path` by its extension; an error names the file and the allowed ones.
    pub fn of(path: &Path) -> Result<MeshFormat, MeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        match ext.as_str() {
            "gltf" | "glb" => Ok(MeshFormat::Gltf),
            "obj" => Ok(MeshFormat::Obj),
            "stl" => Ok(MeshFormat::Stl),
            "ply" => Ok(MeshFormat::Ply),
            _ => Err(MeshError::Format {
                path: path.to_path_buf(),
            }),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            MeshFormat::Gltf => "glTF",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Stl => "STL",
            MeshFormat::Ply => "PLY",
        }
    }
}

/// How a glTF file without a declared unit is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GltfUnitDefault {
    /// Metres (the glTF specification), millimetres for files synosis wrote.
    Spec,
    /// Millimetres: the old `gltf = ...` key and job meshes, read so before units existed.
    Millimetres,
}

/// A loaded mesh and the unit it was read in.
pub struct LoadedMesh {
    pub imported: Imported,
    pub unit: MeshUnit,
    pub format: MeshFormat,
}

/// Reads any supported mesh file into millimetres: `unit` as declared, else the
/// format's default (module docs). Degenerate triangles as `degenerates` says; every
/// error names the file.
pub fn load_mesh(
    path: &Path,
    unit: Option<MeshUnit>,
    gltf_default: GltfUnitDefault,
    degenerates: Degenerates,
) -> Result<LoadedMesh, MeshError> {
    let format = MeshFormat::of(path)?;
    let (imported, unit) = match format {
        MeshFormat::Gltf => {
            // import_mesh checks the file itself.
            let mut imported = import_mesh(path, degenerates)?;
            let synosis_file = imported
                .generator
                .as_deref()
                .is_some_and(|g| g.starts_with("synosis"));
            let unit = unit.unwrap_or(match gltf_default {
                GltfUnitDefault::Millimetres => MeshUnit::Mm,
                GltfUnitDefault::Spec if synosis_file => MeshUnit::Mm,
                GltfUnitDefault::Spec => MeshUnit::M,
            });
            if unit != MeshUnit::Mm {
                let s = unit.mm();
                for p in &mut imported.mesh.positions {
                    *p = (p.as_dvec3() * s).as_vec3();
                }
            }
            (imported, unit)
        }
        _ => {
            check_mesh_file(path, |reason| MeshError::Parse {
                path: path.to_path_buf(),
                format: format.name(),
                reason,
            })?;
            let unit = unit.unwrap_or(MeshUnit::Mm);
            let mesh = match format {
                MeshFormat::Obj => read_obj(path, unit.mm())?,
                MeshFormat::Stl => read_stl(path, unit.mm())?,
                _ => read_ply(path, unit.mm())?,
            };
            (check_imported(path, mesh, degenerates)?, unit)
        }
    };
    Ok(LoadedMesh {
        imported,
        unit,
        format,
    })
}

/// Writes `mesh` by its extension: glTF/GLB with labels (`export_mesh`), or binary STL
/// (geometry only, facet normals from the winding), atomically. Millimetres.
pub fn write_mesh(mesh: &Mesh, path: &Path) -> Result<(), MeshError> {
    match MeshFormat::of(path)? {
        MeshFormat::Gltf => super::gltf_io::export_mesh(mesh, path),
        MeshFormat::Stl => {
            let tris: Vec<stl_io::Triangle> = (0..mesh.triangles.len())
                .map(|t| stl_io::Triangle {
                    normal: stl_io::Normal::new(mesh.area_normal(t).normalize_or_zero().to_array()),
                    vertices: mesh.corners(t).map(|p| stl_io::Vertex::new(p.to_array())),
                })
                .collect();
            let mut bytes = Vec::new();
            stl_io::write_stl(&mut bytes, tris.iter()).map_err(|source| MeshError::Write {
                path: path.to_path_buf(),
                source,
            })?;
            crate::util::write_atomic(path, &bytes).map_err(|source| MeshError::Write {
                path: path.to_path_buf(),
                source,
            })
        }
        _ => Err(MeshError::Extension {
            path: path.to_path_buf(),
        }),
    }
}

fn parse_err(path: &Path, format: MeshFormat, reason: impl ToString) -> MeshError {
    MeshError::Parse {
        path: path.to_path_buf(),
        format: format.name(),
        reason: reason.to_string(),
    }
}

fn to_mm(x: f64, y: f64, z: f64, scale: f64) -> Vec3 {
    Vec3::new((x * scale) as f32, (y * scale) as f32, (z * scale) as f32)
}

/// Appends a polygon as a triangle fan, after checking its indices.
fn push_polygon(
    mesh: &mut Mesh,
    poly: &[u32],
    base: u32,
    nverts: u32,
    label: TriLabel,
) -> Result<(), String> {
    if poly.len() < 3 {
        return Ok(()); // points and lines are skipped, as in glTF
    }
    if let Some(&bad) = poly.iter().find(|&&i| i >= nverts) {
        return Err(format!("index {bad} out of range ({nverts} vertices)"));
    }
    for k in 1..poly.len() - 1 {
        mesh.triangles
            .push([poly[0] + base, poly[k] + base, poly[k + 1] + base]);
        mesh.labels.push(label);
    }
    Ok(())
}

fn read_obj(path: &Path, scale: f64) -> Result<Mesh, MeshError> {
    let err = |r: String| parse_err(path, MeshFormat::Obj, r);
    let opts = tobj::LoadOptions {
        triangulate: false,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    // Materials (.mtl) are not used; a missing one is no error.
    let (models, _materials) = tobj::load_obj(path, &opts).map_err(|e| err(e.to_string()))?;
    let mut mesh = Mesh::default();
    for model in &models {
        let m = &model.mesh;
        let base = mesh.positions.len() as u32;
        let nverts = (m.positions.len() / 3) as u32;
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| to_mm(p[0], p[1], p[2], scale)),
        );
        let face = face_from_name(model.name.strip_prefix("face_").unwrap_or(&model.name))
            .filter(|&f| f != 0)
            .unwrap_or(0);
        let label = TriLabel {
            face,
            ..Default::default()
        };
        if m.face_arities.is_empty() {
            for t in m.indices.chunks(3) {
                push_polygon(&mut mesh, t, base, nverts, label).map_err(err)?;
            }
        } else {
            let mut at = 0usize;
            for &n in &m.face_arities {
                let end = at + n as usize;
                let poly = m
                    .indices
                    .get(at..end)
                    .ok_or_else(|| err("face list shorter than its arities".into()))?;
                push_polygon(&mut mesh, poly, base, nverts, label).map_err(err)?;
                at = end;
            }
        }
    }
    Ok(mesh)
}

fn read_stl(path: &Path, scale: f64) -> Result<Mesh, MeshError> {
    let err = |r: String| parse_err(path, MeshFormat::Stl, r);
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut reader = BufReader::new(file);
    let stl = stl_io::read_stl(&mut reader).map_err(|e| err(e.to_string()))?;
    let mut mesh = Mesh::default();
    mesh.positions.extend(stl.vertices.iter().map(|v| {
        let [x, y, z] = v.0.map(f64::from);
        to_mm(x, y, z, scale)
    }));
    let nverts = mesh.positions.len() as u32;
    for f in &stl.faces {
        let t = f.vertices.map(|i| i as u32);
        push_polygon(&mut mesh, &t, 0, nverts, TriLabel::default()).map_err(err)?;
    }
    Ok(mesh)
}

fn read_ply(path: &Path, scale: f64) -> Result<Mesh, MeshError> {
    use ply_rs_bw::ply::{DefaultElement, Property};
    let err = |r: String| parse_err(path, MeshFormat::Ply, r);
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut reader = BufReader::new(file);
    let ply = ply_rs_bw::parser::Parser::<DefaultElement>::new()
        .read_ply(&mut reader)
        .map_err(|e| err(e.to_string()))?;
    let scalar = |p: &Property| -> Option<f64> {
        Some(match p {
            Property::Float(v) => *v as f64,
            Property::Double(v) => *v,
            Property::Char(v) => *v as f64,
            Property::UChar(v) => *v as f64,
            Property::Short(v) => *v as f64,
            Property::UShort(v) => *v as f64,
            Property::Int(v) => *v as f64,
            Property::UInt(v) => *v as f64,
            _ => return None,
        })
    };
    let list = |p: &Property| -> Option<Vec<u32>> {
        let neg = |v: i64| u32::try_from(v).ok();
        Some(match p {
            Property::ListChar(v) => v.iter().map(|&i| neg(i as i64)).collect::<Option<_>>()?,
            Property::ListUChar(v) => v.iter().map(|&i| i as u32).collect(),
            Property::ListShort(v) => v.iter().map(|&i| neg(i as i64)).collect::<Option<_>>()?,
            Property::ListUShort(v) => v.iter().map(|&i| i as u32).collect(),
            Property::ListInt(v) => v.iter().map(|&i| neg(i as i64)).collect::<Option<_>>()?,
            Property::ListUInt(v) => v.clone(),
            _ => return None,
        })
    };
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| err("no `vertex` element".into()))?;
    let mut mesh = Mesh::default();
    for (i, v) in vertices.iter().enumerate() {
        let c = |k: &str| {
            v.get(k)
                .and_then(scalar)
                .ok_or_else(|| err(format!("vertex {i}: no numeric property `{k}`")))
        };
        mesh.positions.push(to_mm(c("x")?, c("y")?, c("z")?, scale));
    }
    let nverts = mesh.positions.len() as u32;
    let faces = ply
        .payload
        .get("face")
        .ok_or_else(|| err("no `face` element".into()))?;
    for (i, f) in faces.iter().enumerate() {
        let idx = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(list)
            .ok_or_else(|| {
                err(format!(
                    "face {i}: no integer list `vertex_indices` (or `vertex_index`) with indices >= 0"
                ))
            })?;
        push_polygon(&mut mesh, &idx, 0, nverts, TriLabel::default()).map_err(err)?;
    }
    Ok(mesh)
}
