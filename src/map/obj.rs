//! Wavefront OBJ loading into a gray [`Mesh`].
//!
//! Takes an `.obj` path (with optional `mtllib` material libraries and
//! diffuse textures), gives out a validated [`Mesh`] or a [`MapError`] naming
//! the file and the problem. Parsing goes through `tobj` (triangulated,
//! single index so positions and uvs share indices), which reads an object
//! of more than [`PART_FACES`] faces in parts so that its face buffer stays
//! small (a vertex two parts share is then a vertex of each); before that a pre-scan
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
//! to align to. The text is read line by line, twice (checked, then
//! parsed), never held whole; the mesh's arrays are reserved with
//! `try_reserve`, so a mesh too large for memory is a
//! [`MapError::OutOfMemory`] naming the bytes, not an abort.

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

/// Opens the OBJ file for one pass over its lines, refusing what is not
/// a regular file (a FIFO would block). The text is read twice (checked,
/// then parsed), never held whole: a 2 cm scan of a floor is 700 MB of it.
fn open_obj(path: &Path) -> Result<std::io::BufReader<std::fs::File>, MapError> {
    super::format::check_regular_file(path)?;
    let file = std::fs::File::open(path).map_err(|source| MapError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(std::io::BufReader::with_capacity(1 << 16, file))
}

/// Longest line accepted, bytes: no OBJ statement comes near it, and a
/// binary or corrupt file (a terabyte of zeros) is refused at its first
/// megabyte instead of being read whole as one line.
pub const MAX_LINE_BYTES: u64 = 1 << 20;

/// Why a line of the OBJ text could not be read.
#[derive(Debug)]
enum LineError {
    /// Longer than [`MAX_LINE_BYTES`].
    TooLong,
    /// Not UTF-8, or the read failed.
    Io(std::io::Error),
}

impl From<LineError> for std::io::Error {
    fn from(e: LineError) -> Self {
        match e {
            LineError::TooLong => std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("a line longer than {MAX_LINE_BYTES} bytes"),
            ),
            LineError::Io(e) => e,
        }
    }
}

/// Reads the next line of `reader` into `line` (cleared first), with its
/// newline; `Ok(false)` at the end of the text.
fn read_obj_line(reader: &mut impl std::io::BufRead, line: &mut String) -> Result<bool, LineError> {
    use std::io::{BufRead, Read};
    line.clear();
    let n = reader
        .by_ref()
        .take(MAX_LINE_BYTES + 1)
        .read_line(line)
        .map_err(LineError::Io)?;
    if n as u64 > MAX_LINE_BYTES {
        return Err(LineError::TooLong);
    }
    Ok(n > 0)
}

/// The error of line `line` of `path`, which could not be read.
fn line_error(path: &Path, line: usize, e: LineError) -> MapError {
    let parse = |reason| MapError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    match e {
        LineError::TooLong => parse(format!(
            "longer than {MAX_LINE_BYTES} bytes: not OBJ text (a binary or corrupt file?)"
        )),
        LineError::Io(e) if e.kind() == std::io::ErrorKind::InvalidData => {
            parse(format!("not UTF-8 text: {e}"))
        }
        LineError::Io(source) => MapError::Read {
            path: path.to_path_buf(),
            source,
        },
    }
}

/// Rec.601 luma of an RGB color in 0..1, scaled to 0..=255.
#[inline]
pub fn luma601_255(rgb: [f32; 3]) -> f32 {
    (0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]) * 255.0
}

/// Faces `tobj` holds at once, at most: the parser keeps every face of the
/// object it is reading (about 100 bytes each, in a vector that doubles) and
/// exports them when the object ends, so a scan written as one object of
/// 14.7 M triangles took 2-3 GB for its faces alone. [`Parts`] ends an
/// object every this many faces.
pub const PART_FACES: usize = 1 << 16;

/// The lines of an OBJ text as `tobj` reads them, with the current object
/// or group started again (`g NAME`, the same name) before every
/// [`Parts::part_faces`]-th face line since the object began: `tobj` then
/// exports the faces in parts and reuses its face buffer. The triangles,
/// their order, materials and names are those of the file; a vertex used
/// by two parts is a vertex of each (single-index meshes are per object).
struct Parts<R> {
    inner: R,
    part_faces: usize,
    /// Face lines since the object, group or part began.
    faces: usize,
    /// Name of the current object or group (`tobj`'s default without one).
    name: String,
    /// The last line read.
    line: String,
    /// What is handed out: the last line, after a `g` line when a part
    /// ends there.
    buf: String,
    pos: usize,
}

impl<R: std::io::BufRead> Parts<R> {
    fn new(inner: R, part_faces: usize) -> Self {
        Self {
            inner,
            part_faces: part_faces.max(1),
            faces: 0,
            name: "unnamed_object".to_string(),
            line: String::new(),
            buf: String::new(),
            pos: 0,
        }
    }
}

impl<R: std::io::BufRead> std::io::Read for Parts<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let n = {
            let available = std::io::BufRead::fill_buf(self)?;
            let n = available.len().min(out.len());
            out[..n].copy_from_slice(&available[..n]);
            n
        };
        std::io::BufRead::consume(self, n);
        Ok(n)
    }
}

impl<R: std::io::BufRead> std::io::BufRead for Parts<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.pos >= self.buf.len() {
            self.buf.clear();
            self.pos = 0;
            self.line.clear();
            if read_obj_line(&mut self.inner, &mut self.line)? {
                let mut words = self.line.split_whitespace();
                match words.next() {
                    Some("o" | "g") => {
                        let name = self.line.trim_start().get(1..).unwrap_or("").trim();
                        self.name = if name.is_empty() {
                            "unnamed_object".to_string()
                        } else {
                            name.to_string()
                        };
                        self.faces = 0;
                    }
                    Some("f") => {
                        if self.faces == self.part_faces {
                            self.buf.push_str("g ");
                            self.buf.push_str(&self.name);
                            self.buf.push('\n');
                            self.faces = 0;
                        }
                        self.faces += 1;
                    }
                    _ => {}
                }
                self.buf.push_str(&self.line);
            }
        }
        Ok(self.buf.as_bytes().get(self.pos..).unwrap_or(&[]))
    }

    fn consume(&mut self, amount: usize) {
        self.pos = (self.pos + amount).min(self.buf.len());
    }
}

/// Loads an OBJ mesh (see the module docs for how colors become gray).
pub fn load_obj(path: &Path) -> Result<Mesh, MapError> {
    load_obj_in_parts(path, PART_FACES)
}

/// [`load_obj`], `tobj` reading at most `part_faces` faces at once
/// ([`Parts`]).
fn load_obj_in_parts(path: &Path, part_faces: usize) -> Result<Mesh, MapError> {
    let scan = prescan_obj(open_obj(path)?, path)?;
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
    let mut parts = Parts::new(open_obj(path)?, part_faces);
    let parsed = tobj::load_obj_buf(&mut parts, &options, |mtl: &Path| {
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
    // Colors above 1 anywhere in the file: the file's colors are 0..255.
    let color_scale = if models
        .iter()
        .any(|m| m.mesh.vertex_color.iter().any(|&x| x > 1.0))
    {
        1.0 / 255.0
    } else {
        1.0
    };
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
    if mesh.textures.is_empty() {
        // Texture coordinates only place textures: without any, none are
        // kept (8 bytes a vertex, in this mesh and in every renderer's copy).
        mesh.uvs = Vec::new();
    }
    // Reserved for one vertex per face corner: give back what the shared
    // vertices did not use.
    mesh.positions.shrink_to_fit();
    mesh.gray.shrink_to_fit();
    mesh.uvs.shrink_to_fit();
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

fn prescan_obj(mut text: impl std::io::BufRead, path: &Path) -> Result<Prescan, MapError> {
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
    let mut read = String::new();
    for line_no in 1.. {
        if !read_obj_line(&mut text, &mut read).map_err(|e| line_error(path, line_no, e))? {
            break;
        }
        let line = read.trim_end_matches(['\n', '\r']);
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
