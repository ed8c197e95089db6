//! glTF 2.0 import and export of labelled meshes (.gltf with a .bin beside it, or .glb).
//!
//! Labels: a primitive may carry `extras: {"synosis": {"face": "A", "class": 1,
//! "instance": 3}}`; every triangle of that primitive gets that label. All primitives of
//! an exported mesh share one POSITION accessor and differ only by their index accessor,
//! so the mesh stays watertight by index across label boundaries. Without extras, a
//! primitive whose mesh or node is named "A", "B", "C" (or "face_A", ...) gets that face.
//! See docs/mesh-format.md.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

use super::mesh::{Mesh, TriLabel, face_from_name, face_name};

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: file not found")]
    NotFound { path: PathBuf },
    #[error("{path}: not a valid glTF 2.0 file: {reason}")]
    Malformed { path: PathBuf, reason: String },
    #[error("{path}: the mesh has no triangles (only triangle-list primitives are read)")]
    Empty { path: PathBuf },
    #[error(
        "{path}: {count} degenerate (zero-area) triangle(s), first at triangle {first}; \
         fix the mesh (`synosis defects` and `synosis raycast` can drop them with --drop-degenerate)"
    )]
    Degenerate {
        path: PathBuf,
        count: usize,
        first: usize,
    },
    #[error("{path}: vertex {index} has a non-finite position")]
    NonFinite { path: PathBuf, index: usize },
    #[error("{path}: primitive {primitive} of mesh {mesh}: {reason}")]
    BadLabel {
        path: PathBuf,
        mesh: usize,
        primitive: usize,
        reason: String,
    },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: unsupported extension for writing (use .gltf, .glb or .stl)")]
    Extension { path: PathBuf },
    #[error("{path}: unsupported mesh format (allowed: .gltf, .glb, .obj, .stl, .ply)")]
    Format { path: PathBuf },
    #[error("{path}: not a valid {format} file: {reason}")]
    Parse {
        path: PathBuf,
        format: &'static str,
        reason: String,
    },
}

/// What to do with zero-area triangles on import.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Degenerates {
    /// Refuse the mesh with an error naming the first one.
    #[default]
    Reject,
    /// Drop them (they cannot be hit anyway) and report how many were dropped.
    Drop,
}

/// An imported mesh and what import had to say about it.
pub struct Imported {
    pub mesh: Mesh,
    pub dropped_degenerate: usize,
    /// glTF `asset.generator` (None for other formats or when absent): files synosis
    /// wrote say `"synosis <version>"` and are in millimetres (docs/mesh-format.md).
    pub generator: Option<String>,
    /// glTF only: each triangle's material name (`[[material.region]]` selects by it).
    pub materials: Option<crate::scene::materials::GltfMaterials>,
}

#[derive(serde::Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct LabelExtras {
    #[serde(default)]
    face: Option<String>,
    #[serde(default)]
    class: u8,
    #[serde(default)]
    instance: u16,
}

/// Whether mesh file `path` exists (else `NotFound`) and is within
/// `limits::MAX_MESH_BYTES` (else `too_large`'s error, given the reason: each reader
/// names its own format).
pub(crate) fn check_mesh_file(
    path: &Path,
    too_large: impl FnOnce(String) -> MeshError,
) -> Result<(), MeshError> {
    if !path.exists() {
        return Err(MeshError::NotFound {
            path: path.to_path_buf(),
        });
    }
    let len = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let limit = crate::limits::MAX_MESH_BYTES;
    if len > limit {
        return Err(too_large(format!(
            "{len} bytes: over the limit for mesh files ({limit} bytes)"
        )));
    }
    Ok(())
}

/// Reads every triangle primitive of the default scene (node transforms applied).
pub fn import_mesh(path: &Path, degenerates: Degenerates) -> Result<Imported, MeshError> {
    let malformed = |reason: String| MeshError::Malformed {
        path: path.to_path_buf(),
        reason,
    };
    check_mesh_file(path, malformed)?;
    let limit = crate::limits::MAX_MESH_BYTES;
    let gltf = gltf::Gltf::open(path).map_err(|e| malformed(e.to_string()))?;
    for b in gltf.document.buffers() {
        if b.length() as u64 > limit {
            return Err(malformed(format!(
                "buffer {} declares {} bytes: over the limit for mesh buffers ({limit} bytes)",
                b.index(),
                b.length()
            )));
        }
    }
    let buffers = gltf::import_buffers(&gltf.document, path.parent(), gltf.blob.clone())
        .map_err(|e| malformed(e.to_string()))?;
    let mut mesh = Mesh::default();
    let scene = gltf
        .document
        .default_scene()
        .or_else(|| gltf.document.scenes().next());
    let roots: Vec<gltf::Node> = match scene {
        Some(s) => s.nodes().collect(),
        None => gltf.document.nodes().collect(),
    };
    let mut stack: Vec<(gltf::Node, Mat4)> =
        roots.into_iter().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut shared = std::collections::HashMap::new();
    // Material index per triangle (u32::MAX: none) and the names, in the file's order;
    // an unnamed material is called "material <index>".
    let names: Vec<String> = gltf
        .document
        .materials()
        .map(|m| {
            m.name().map_or_else(
                || format!("material {}", m.index().unwrap_or(0)),
                str::to_string,
            )
        })
        .collect();
    let mut tri_material: Vec<u32> = Vec::new();
    while let Some((node, parent)) = stack.pop() {
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        for child in node.children() {
            stack.push((child, world));
        }
        let Some(gmesh) = node.mesh() else { continue };
        for prim in gmesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let label = primitive_label(path, &node, &gmesh, &prim)?;
            let material = prim.material().index().map_or(u32::MAX, |i| i as u32);
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos_accessor) = prim.get(&gltf::Semantic::Positions) else {
                return Err(malformed(format!(
                    "primitive {} of mesh {} has no POSITION",
                    prim.index(),
                    gmesh.index()
                )));
            };
            // Primitives sharing a POSITION accessor under one node share vertices, so
            // a mesh split by label stays watertight by index.
            let key = (node.index(), pos_accessor.index());
            let (base, nverts) = match shared.get(&key) {
                Some(&v) => v,
                None => {
                    let pos = reader
                        .read_positions()
                        .ok_or_else(|| malformed("unreadable POSITION accessor".into()))?;
                    let base = mesh.positions.len() as u32;
                    mesh.positions
                        .extend(pos.map(|p| world.transform_point3(Vec3::from(p))));
                    let v = (base, mesh.positions.len() as u32 - base);
                    shared.insert(key, v);
                    v
                }
            };
            let indices: Vec<u32> = match reader.read_indices() {
                Some(ix) => ix.into_u32().collect(),
                None => (0..nverts).collect(),
            };
            if !indices.len().is_multiple_of(3) {
                return Err(malformed(format!(
                    "index count {} is not a multiple of 3",
                    indices.len()
                )));
            }
            if let Some(&bad) = indices.iter().find(|&&i| i >= nverts) {
                return Err(malformed(format!(
                    "index {bad} out of range ({nverts} vertices)"
                )));
            }
            // A mirroring transform flips winding; keep outward normals outward.
            let flip = world.determinant() < 0.0;
            for t in indices.chunks_exact(3) {
                let tri = if flip {
                    [t[0], t[2], t[1]]
                } else {
                    [t[0], t[1], t[2]]
                };
                mesh.triangles.push(tri.map(|i| i + base));
                mesh.labels.push(label);
                tri_material.push(material);
            }
        }
    }
    let generator = gltf.document.as_json().asset.generator.clone();
    // The degenerate triangles check_imported drops, dropped here from the materials too.
    if degenerates == Degenerates::Drop {
        let mut keep = vec![true; tri_material.len()];
        for t in mesh.degenerate_triangles() {
            keep[t] = false;
        }
        let mut k = 0;
        tri_material.retain(|_| {
            k += 1;
            keep[k - 1]
        });
    }
    let mut imported = check_imported(path, mesh, degenerates)?;
    imported.generator = generator;
    imported.materials = Some(crate::scene::materials::GltfMaterials {
        names,
        of_triangle: tri_material,
    });
    Ok(imported)
}

/// The checks every importer ends with: triangles present, finite positions, and
/// zero-area triangles refused (with the count and the first) or dropped.
pub(crate) fn check_imported(
    path: &Path,
    mut mesh: Mesh,
    degenerates: Degenerates,
) -> Result<Imported, MeshError> {
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty {
            path: path.to_path_buf(),
        });
    }
    if let Some(index) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(MeshError::NonFinite {
            path: path.to_path_buf(),
            index,
        });
    }
    let degenerate = mesh.degenerate_triangles();
    let dropped_degenerate = degenerate.len();
    if !degenerate.is_empty() {
        match degenerates {
            Degenerates::Reject => {
                return Err(MeshError::Degenerate {
                    path: path.to_path_buf(),
                    count: degenerate.len(),
                    first: degenerate[0],
                });
            }
            Degenerates::Drop => mesh.remove_triangles(&degenerate),
        }
        if mesh.triangles.is_empty() {
            return Err(MeshError::Empty {
                path: path.to_path_buf(),
            });
        }
    }
    Ok(Imported {
        mesh,
        dropped_degenerate,
        generator: None,
        materials: None,
    })
}

fn primitive_label(
    path: &Path,
    node: &gltf::Node,
    gmesh: &gltf::Mesh,
    prim: &gltf::Primitive,
) -> Result<TriLabel, MeshError> {
    let bad = |reason: String| MeshError::BadLabel {
        path: path.to_path_buf(),
        mesh: gmesh.index(),
        primitive: prim.index(),
        reason,
    };
    if let Some(raw) = prim.extras() {
        let v: serde_json::Value =
            serde_json::from_str(raw.get()).map_err(|e| bad(format!("extras: {e}")))?;
        if let Some(s) = v.get("synosis") {
            let ex: LabelExtras = serde_json::from_value(s.clone())
                .map_err(|e| bad(format!("extras.synosis: {e}")))?;
            let face = match ex.face.as_deref() {
                None => 0,
                Some(n) => face_from_name(n).ok_or_else(|| {
                    bad(format!(
                        "extras.synosis.face = {n:?}; allowed: \"A\", \"B\", \"C\", \"other\""
                    ))
                })?,
            };
            if ex.class > 2 {
                return Err(bad(format!(
                    "extras.synosis.class = {}; allowed: 0 (none), 1 (dent), 2 (scratch)",
                    ex.class
                )));
            }
            return Ok(TriLabel {
                face,
                class: ex.class,
                instance: ex.instance,
            });
        }
    }
    let by_name = |n: Option<&str>| {
        n.and_then(|n| face_from_name(n.strip_prefix("face_").unwrap_or(n)))
            .filter(|&f| f != 0)
    };
    let face = by_name(gmesh.name())
        .or_else(|| by_name(node.name()))
        .unwrap_or(0);
    Ok(TriLabel {
        face,
        ..TriLabel::default()
    })
}

/// Writes `mesh` as .glb or .gltf (+ .bin), chosen by the extension, atomically: to a
/// temporary name first, renamed when complete.
pub fn export_mesh(mesh: &Mesh, path: &Path) -> Result<(), MeshError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let write_err = |p: &Path, source| MeshError::Write {
        path: p.to_path_buf(),
        source,
    };

    // Group triangles by label, keeping first-appearance order (deterministic output).
    let mut groups: Vec<(TriLabel, Vec<u32>)> = Vec::new();
    let mut index_of = std::collections::HashMap::new();
    for (t, l) in mesh.triangles.iter().zip(&mesh.labels) {
        let g = *index_of.entry(*l).or_insert_with(|| {
            groups.push((*l, Vec::new()));
            groups.len() - 1
        });
        groups[g].1.extend_from_slice(t);
    }

    let mut bin: Vec<u8> = Vec::new();
    let (lo, hi) = mesh.bounds();
    for p in &mesh.positions {
        bin.extend_from_slice(bytemuck::cast_slice(&p.to_array()));
    }
    let pos_len = bin.len();
    let mut views = vec![
        serde_json::json!({"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962}),
    ];
    let mut accessors = vec![serde_json::json!({
        "bufferView": 0, "componentType": 5126, "count": mesh.positions.len(), "type": "VEC3",
        "min": lo.to_array(), "max": hi.to_array()
    })];
    let mut prims = Vec::new();
    for (label, idx) in &groups {
        let off = bin.len();
        bin.extend_from_slice(bytemuck::cast_slice(idx));
        views.push(serde_json::json!({"buffer": 0, "byteOffset": off, "byteLength": idx.len() * 4, "target": 34963}));
        accessors.push(serde_json::json!({
            "bufferView": views.len() - 1, "componentType": 5125, "count": idx.len(), "type": "SCALAR"
        }));
        prims.push(serde_json::json!({
            "attributes": {"POSITION": 0}, "indices": accessors.len() - 1, "mode": 4,
            "extras": {"synosis": {"face": face_name(label.face), "class": label.class, "instance": label.instance}}
        }));
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let bin_name = path.with_extension("bin");
    let mut buffer = serde_json::json!({"byteLength": bin.len()});
    if ext == "gltf" {
        let name = bin_name
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("mesh.bin");
        buffer["uri"] = serde_json::Value::from(name);
    }
    let doc = serde_json::json!({
        "asset": {"version": "2.0", "generator": concat!("synosis ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "synosis-mesh"}],
        "meshes": [{"primitives": prims}],
        "buffers": [buffer],
        "bufferViews": views,
        "accessors": accessors,
    });
    let mut json = serde_json::to_vec(&doc).expect("serialising a json! value cannot fail");
    match ext.as_str() {
        "glb" => {
            while !json.len().is_multiple_of(4) {
                json.push(b' ');
            }
            let total = 12 + 8 + json.len() + 8 + bin.len();
            let mut out = Vec::with_capacity(total);
            out.extend_from_slice(b"glTF");
            out.extend_from_slice(&2u32.to_le_bytes());
            out.extend_from_slice(&(total as u32).to_le_bytes());
            out.extend_from_slice(&(json.len() as u32).to_le_bytes());
            out.extend_from_slice(b"JSON");
            out.extend_from_slice(&json);
            out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
            out.extend_from_slice(b"BIN\0");
            out.extend_from_slice(&bin);
            crate::util::write_atomic(path, &out).map_err(|e| write_err(path, e))
        }
        "gltf" => {
            crate::util::write_atomic(&bin_name, &bin).map_err(|e| write_err(&bin_name, e))?;
            crate::util::write_atomic(path, &json).map_err(|e| write_err(path, e))
        }
        _ => Err(MeshError::Extension {
            path: path.to_path_buf(),
        }),
    }
}
