//! Wavefront OBJ loading into a gray [`Mesh`].
//!
//! Takes an `.obj` path (with optional `mtllib` material libraries and
//! diffuse textures), gives out a validated [`Mesh`] or a [`MapError`] naming
//! the file and the problem. Parsing goes through `tobj` (triangulated,
//! single index so positions and uvs share indices); before that a pre-scan
//! checks face indices and vertex lines so bad files give line-numbered
//! errors and never reach a panic inside the parser.
//!
//! Color to gray: Rec.601 luma `0.299 R + 0.587 G + 0.114 B` on a 0..=255
//! scale. A vertex's gray is its vertex color (`v x y z r g b`, floats in
//! 0..1; files whose colors exceed 1 are read as 0..255) when the file has
//! vertex colors, else the material's `Kd` luma, else 255. Triangles whose
//! material has `map_Kd` (resolved relative to the MTL file's folder) are
//! grouped by texture; the surface is then `texel * vertex_gray / 255`.
//! OBJ `vt` v points up, so it is flipped (`1 - v`) to the image convention.
//!
//! Sane bounds, checked with line numbers before parsing: vertex coordinates
//! within ±[`MAX_VERTEX_COORDINATE`] (file units), vertex colors within
//! 0..=255. A `usemtl` naming a material no library defines, or a mesh with
//! no color at all (no vertex colors, no `Kd`, no texture), loads with a
//! warning: such surfaces render flat white, which gives the tracker nothing
//! to align to. The text and the mesh's arrays are reserved with
//! `try_reserve`, so a mesh too large for memory is a [`MapError::OutOfMemory`]
//! naming the bytes, not an abort.

use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::error::MapError;
use super::{GrayTexture, Mesh};

/// Largest vertex coordinate magnitude accepted, in the file's units: a
/// building in millimeters stays within 1e6 (a kilometer).
pub const MAX_VERTEX_COORDINATE: f64 = 1e6;
/// Largest vertex color component accepted (colors are 0..1 or 0..255).
pub const MAX_VERTEX_COLOR: f64 = 255.0;

/// Reserves `additional` more elements of `v`, or says how many bytes the
/// map needed.
fn reserve<T>(
    v: &mut Vec<T>,
    additional: usize,
    path: &Path,
    what: &'static str,
) -> Result<(), MapError> {
    v.try_reserve_exact(additional)
        .map_err(|_| MapError::OutOfMemory {
            path: path.to_path_buf(),
            what,
            needed_bytes: (additional as u64).saturating_mul(std::mem::size_of::<T>() as u64),
        })
}

/// Reads the OBJ text, refusing what is not a regular file (a FIFO would
/// block) and reserving the text's memory first.
fn read_obj_text(path: &Path) -> Result<String, MapError> {
    let read_err = |source| MapError::Read {
        path: path.to_path_buf(),
        source,
    };
    let len_bytes = super::format::check_regular_file(path)?;
    let mut bytes: Vec<u8> = Vec::new();
    let len = usize::try_from(len_bytes).unwrap_or(usize::MAX);
    reserve(&mut bytes, len, path, "the OBJ text")?;
    std::io::Read::read_to_end(
        &mut std::fs::File::open(path).map_err(read_err)?,
        &mut bytes,
    )
    .map_err(read_err)?;
    String::from_utf8(bytes).map_err(|e| MapError::Parse {
        path: path.to_path_buf(),
        line: 0,
        reason: format!("not UTF-8 text: {e}"),
    })
}

/// Rec.601 luma of an RGB color in 0..1, scaled to 0..=255.
#[inline]
pub fn luma601_255(rgb: [f32; 3]) -> f32 {
    (0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]) * 255.0
}

/// Loads an OBJ mesh (see the module docs for how colors become gray).
pub fn load_obj(path: &Path) -> Result<Mesh, MapError> {
    let text = read_obj_text(path)?;
    let scan = prescan_obj(&text, path)?;
    let mut mesh = Mesh::default();
    // Triangulated and single-indexed, the mesh has at most one vertex per
    // face corner and three indices per corner.
    reserve(&mut mesh.positions, scan.corners, path, "vertex positions")?;
    reserve(&mut mesh.gray, scan.corners, path, "vertex gray")?;
    reserve(&mut mesh.uvs, scan.corners, path, "texture coordinates")?;
    reserve(
        &mut mesh.indices,
        scan.corners.saturating_mul(3),
        path,
        "triangle indices",
    )?;
    let obj_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();

    // Material libraries: remember where each material came from (textures
    // are relative to the MTL's folder) and any failure, with its path.
    let mtl_records: RefCell<Vec<MtlRecord>> = RefCell::new(Vec::new());
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let parsed = tobj::load_obj_buf(&mut text.as_bytes(), &options, |mtl: &Path| {
        let full = obj_dir.join(mtl);
        let (result, record) = load_mtl_checked(&full);
        mtl_records.borrow_mut().push(record);
        result
    });
    let (models, materials) = parsed.map_err(|e| MapError::Parse {
        path: path.to_path_buf(),
        line: 0,
        reason: format!("OBJ parser: {e}"),
    })?;
    let records = mtl_records.into_inner();
    if let Some(bad) = records.iter().find(|r| r.error.is_some()) {
        return Err(MapError::Material {
            path: bad.path.clone(),
            obj: path.to_path_buf(),
            reason: bad.error.clone().unwrap_or_default(),
        });
    }
    let materials = materials.map_err(|e| MapError::Material {
        path: obj_dir.clone(),
        obj: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let mtl_dir_of: HashMap<&str, &Path> = records
        .iter()
        .flat_map(|r| r.names.iter().map(move |n| (n.as_str(), r.dir.as_path())))
        .collect();

    let defined: std::collections::HashSet<&str> =
        materials.iter().map(|m| m.name.as_str()).collect();
    let mut warned: std::collections::HashSet<&str> = std::collections::HashSet::new();
    for (line, name) in &scan.used_materials {
        if !defined.contains(name.as_str()) && warned.insert(name.as_str()) {
            tracing::warn!(
                map = %path.display(),
                line,
                material = name.as_str(),
                "material is not defined in the map's material libraries (mtllib): its triangles have no color and render flat white, which gives the tracker nothing to align to"
            );
        }
    }
    let mut any_color = false;
    let mut texture_of_path: HashMap<PathBuf, u32> = HashMap::new();
    // Triangle buckets by texture, in order of first appearance.
    let mut buckets: Vec<(Option<u32>, Vec<u32>)> = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let vertex_count = m.positions.len() / 3;
        let material = m.material_id.and_then(|i| materials.get(i));
        let textured = material.and_then(|mat| Some((mat, mat.diffuse_texture.as_deref()?)));
        let texture = match textured {
            Some((mat, name)) => {
                let dir = mtl_dir_of
                    .get(mat.name.as_str())
                    .copied()
                    .unwrap_or(&obj_dir);
                Some(texture_index(
                    dir,
                    name,
                    &mat.name,
                    &mut texture_of_path,
                    &mut mesh,
                )?)
            }
            None => None,
        };
        let kd_gray = material
            .and_then(|mat| mat.diffuse)
            .map_or(255.0, luma601_255);
        let colors = (m.vertex_color.len() == vertex_count * 3).then_some(&m.vertex_color);
        any_color |= colors.is_some()
            || texture.is_some()
            || material.is_some_and(|mat| mat.diffuse.is_some());
        let color_scale = match colors {
            Some(c) if c.iter().any(|&x| x > 1.0) => 1.0 / 255.0,
            _ => 1.0,
        };
        if !m.texcoords.is_empty() && m.texcoords.len() != vertex_count * 2 {
            return Err(MapError::Parse {
                path: path.to_path_buf(),
                line: 0,
                reason: format!(
                    "object '{}': some face vertices have texture coordinates and others do not",
                    model.name
                ),
            });
        }
        let base = mesh.positions.len() as u32;
        for v in 0..vertex_count {
            let p = &m.positions[3 * v..3 * v + 3];
            mesh.positions.push([p[0], p[1], p[2]]);
            mesh.gray.push(match colors {
                Some(c) => luma601_255([
                    c[3 * v] * color_scale,
                    c[3 * v + 1] * color_scale,
                    c[3 * v + 2] * color_scale,
                ]),
                None => kd_gray,
            });
            mesh.uvs.push(match m.texcoords.get(2 * v..2 * v + 2) {
                Some(t) => [t[0], 1.0 - t[1]],
                None => [0.0, 0.0],
            });
        }
        let bucket = match buckets.iter_mut().position(|(t, _)| *t == texture) {
            Some(i) => i,
            None => {
                buckets.push((texture, Vec::new()));
                buckets.len() - 1
            }
        };
        let whole = m.indices.len() / 3 * 3;
        buckets[bucket]
            .1
            .extend(m.indices[..whole].iter().map(|&i| i + base));
    }
    super::format::finish_mesh(
        &mut mesh,
        buckets,
        path,
        (!any_color).then_some("no vertex colors, no material Kd, no texture"),
    )?;
    Ok(mesh)
}

/// One material library the parser asked for.
struct MtlRecord {
    path: PathBuf,
    dir: PathBuf,
    names: Vec<String>,
    error: Option<String>,
}

/// Loads an MTL file after checking the lines `tobj` would choke on.
fn load_mtl_checked(path: &Path) -> (tobj::MTLLoadResult, MtlRecord) {
    let mut record = MtlRecord {
        path: path.to_path_buf(),
        dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
        names: Vec::new(),
        error: None,
    };
    // A FIFO would block the read forever.
    let regular = std::fs::metadata(path).map(|m| m.is_file());
    if let Ok(false) = regular {
        record.error = Some("not a regular file".into());
        return (Err(tobj::LoadError::OpenFileFailed), record);
    }
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) => {
            record.error = Some(format!("cannot read: {e}"));
            return (Err(tobj::LoadError::OpenFileFailed), record);
        }
    };
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            let found = words.count();
            if found < 3 {
                record.error = Some(format!(
                    "line {}: {key} needs 3 numbers, found {found}",
                    i + 1
                ));
                return (Err(tobj::LoadError::MaterialParseError), record);
            }
        }
    }
    let result = tobj::load_mtl_buf(&mut text.as_bytes());
    match &result {
        Ok((materials, _)) => record.names = materials.iter().map(|m| m.name.clone()).collect(),
        Err(e) => record.error = Some(e.to_string()),
    }
    (result, record)
}

/// Index of the texture `name` (relative to `dir`) in `mesh.textures`,
/// loading it on first use.
fn texture_index(
    dir: &Path,
    name: &str,
    material: &str,
    cache: &mut HashMap<PathBuf, u32>,
    mesh: &mut Mesh,
) -> Result<u32, MapError> {
    let mut path = dir.join(name);
    if !path.is_file() {
        // `map_Kd -s 1 1 1 file.png`: options before the file name.
        if let Some(last) = name.split_whitespace().last() {
            if dir.join(last).is_file() {
                path = dir.join(last);
            }
        }
    }
    if let Some(&i) = cache.get(&path) {
        return Ok(i);
    }
    if !path.is_file() {
        return Err(MapError::MissingTexture {
            path,
            material: material.to_string(),
        });
    }
    let texture = load_gray_texture(&path)?;
    let index = mesh.textures.len() as u32;
    mesh.textures.push(texture);
    cache.insert(path, index);
    Ok(index)
}

/// Decodes an image file (format guessed from its content) into gray.
pub fn load_gray_texture(path: &Path) -> Result<GrayTexture, MapError> {
    let decode_err = |source| MapError::TextureDecode {
        path: path.to_path_buf(),
        source,
    };
    let image = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| decode_err(image::ImageError::IoError(e)))?
        .decode()
        .map_err(decode_err)?;
    Ok(gray_texture(&image))
}

/// A decoded image as a gray texture (Rec.601 luma, 0..=255).
pub fn gray_texture(image: &image::DynamicImage) -> GrayTexture {
    let rgb = image.to_rgb32f();
    let texels = rgb.pixels().map(|p| luma601_255(p.0)).collect();
    GrayTexture {
        width: rgb.width(),
        height: rgb.height(),
        texels,
    }
}

/// Checks what `tobj` does not check gracefully: face indices (zero, out of
/// range, not integers) and vertex color consistency, with line numbers.
/// What the pre-scan learned about an OBJ.
struct Prescan {
    /// Face corners in the file (a bound on the mesh's vertices).
    corners: usize,
    /// `usemtl` lines: 1-based line number and material name.
    used_materials: Vec<(usize, String)>,
}

fn prescan_obj(text: &str, path: &Path) -> Result<Prescan, MapError> {
    let parse_err = |line: usize, reason: String| MapError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let (mut nv, mut nvt, mut nvn) = (0usize, 0usize, 0usize);
    let mut colored: Option<bool> = None;
    let mut scan = Prescan {
        corners: 0,
        used_materials: Vec::new(),
    };
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let mut n = 0;
                for (k, word) in words.enumerate() {
                    n += 1;
                    let value: f64 = word.parse().map_err(|_| {
                        parse_err(line_no, format!("vertex value '{word}' is not a number"))
                    })?;
                    let (what, ok, sane) = if k < 3 {
                        (
                            "coordinate",
                            value.abs() <= MAX_VERTEX_COORDINATE,
                            "-1e6..=1e6 (file units)",
                        )
                    } else {
                        (
                            "color",
                            (0.0..=MAX_VERTEX_COLOR).contains(&value),
                            "0..=1, or 0..=255",
                        )
                    };
                    // `v x y z w`: w is a weight, not a color. A NaN or
                    // infinity is left to the mesh check (`NotFinite`).
                    let is_weight = k == 3 && line.split_whitespace().count() == 5;
                    if !ok && !is_weight && value.is_finite() {
                        return Err(parse_err(
                            line_no,
                            format!("vertex {what} {word} is outside the sane range {sane}"),
                        ));
                    }
                }
                if !matches!(n, 3 | 4 | 6) {
                    return Err(parse_err(
                        line_no,
                        format!("vertex needs 3 coordinates (+ w or r g b), found {n} numbers"),
                    ));
                }
                let has_color = n == 6;
                match colored {
                    Some(c) if c != has_color => {
                        return Err(parse_err(
                            line_no,
                            "some vertices have colors and others do not".to_string(),
                        ))
                    }
                    _ => colored = Some(has_color),
                }
                nv += 1;
            }
            Some("vt") => nvt += 1,
            Some("vn") => nvn += 1,
            Some("usemtl") => {
                let name = words.collect::<Vec<_>>().join(" ");
                scan.used_materials.push((line_no, name));
            }
            Some("f") => {
                let corners = line.split_whitespace().count() - 1;
                if corners < 3 {
                    return Err(parse_err(
                        line_no,
                        format!(
                            "face has {corners} corners: at least 3 are needed (a truncated file?)"
                        ),
                    ));
                }
                for corner in words {
                    scan.corners += 1;
                    for (k, field) in corner.split('/').enumerate() {
                        if field.is_empty() && k > 0 {
                            continue;
                        }
                        let (kind, count) = match k {
                            0 => ("vertex", nv),
                            1 => ("texture coordinate", nvt),
                            2 => ("normal", nvn),
                            _ => {
                                return Err(parse_err(
                                    line_no,
                                    format!("face corner '{corner}' has more than 3 fields"),
                                ))
                            }
                        };
                        let index: i64 = field.parse().map_err(|_| {
                            parse_err(
                                line_no,
                                format!("face {kind} index '{field}' is not an integer"),
                            )
                        })?;
                        let ok = if index > 0 {
                            index as u64 <= count as u64
                        } else {
                            index < 0 && index.unsigned_abs() <= count as u64
                        };
                        if !ok {
                            return Err(MapError::FaceIndex {
                                path: path.to_path_buf(),
                                line: line_no,
                                kind,
                                index,
                                count,
                            });
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(scan)
}

#[cfg(test)]
#[path = "obj_tests.rs"]
mod tests;
