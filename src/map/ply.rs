//! Stanford PLY loading into a gray [`Mesh`], streamed element by element.
//!
//! Takes a `.ply` path (ASCII, binary little or big endian), gives out a
//! validated [`Mesh`] or a [`MapError`] naming the file and the problem.
//! The header goes through `ply-rs-bw`; the payload is then read one
//! element at a time with the same crate, straight into the mesh's arrays,
//! so a large binary scan needs the mesh's memory plus a fixed buffer, never
//! a copy of the file or a per-element map. The arrays are reserved with
//! `try_reserve` from the header's counts after checking that the file is
//! long enough to hold them, so a header that declares a billion faces in a
//! short file is a "truncated" error, not an abort.
//!
//! Read: `vertex` (`x`, `y`, `z`; colors `red`/`green`/`blue`, also `r`,
//! `g`, `b` or `diffuse_red`..., as `uchar` 0..=255, `ushort` 0..=65535, or
//! `float`/`double` 0..1, read as 0..255 when some exceed 1) and `face`
//! (`vertex_indices` or `vertex_index`, polygons triangulated as fans).
//! Other elements and properties (normals, alpha, edges, texture
//! coordinates) are read past. Gray is the Rec.601 luma of the color, 255
//! without colors (with a warning: flat white gives the tracker nothing).
//! PLY has no standard for textures: a `TextureFile` comment is warned
//! about and ignored.
//!
//! Elements are numbered from 0, as the file's face indices are.
//!
//! Refused, naming the file: a missing `vertex` or `face` element or an
//! empty one, a missing coordinate, a face of fewer than three corners or
//! with an index outside the vertices, coordinates beyond
//! ±[`MAX_VERTEX_COORDINATE`], colors out of range, a file that ends before
//! the header's counts, and (through the mesh check) NaN or infinite values.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{
    ElementDef, Encoding, Header, Property, PropertyAccess, PropertyType, ScalarType,
};

use super::error::MapError;
use super::format::check_regular_file;
use super::obj::{luma601_255, MAX_VERTEX_COORDINATE};
use super::Mesh;

const FORMAT: &str = "PLY";

/// Counts the bytes read from the file, to know where the header ended.
struct Counting<R> {
    inner: R,
    bytes: u64,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.bytes += n as u64;
        Ok(n)
    }
}

/// One vertex as the parser fills it.
#[derive(Debug, Default)]
struct PlyVertex {
    position: [f64; 3],
    rgb: [f64; 3],
}

fn scalar(property: &Property) -> f64 {
    match *property {
        Property::Char(v) => v.into(),
        Property::UChar(v) => v.into(),
        Property::Short(v) => v.into(),
        Property::UShort(v) => v.into(),
        Property::Int(v) => v.into(),
        Property::UInt(v) => v.into(),
        Property::Float(v) => v.into(),
        Property::Double(v) => v,
        _ => f64::NAN,
    }
}

/// Which vertex slot a property name fills.
fn vertex_slot(name: &str) -> Option<(bool, usize)> {
    match name {
        "x" => Some((false, 0)),
        "y" => Some((false, 1)),
        "z" => Some((false, 2)),
        "red" | "r" | "diffuse_red" => Some((true, 0)),
        "green" | "g" | "diffuse_green" => Some((true, 1)),
        "blue" | "b" | "diffuse_blue" => Some((true, 2)),
        _ => None,
    }
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) {
        match vertex_slot(name) {
            Some((false, k)) => self.position[k] = scalar(&property),
            Some((true, k)) => self.rgb[k] = scalar(&property),
            None => {}
        }
    }
}

/// One face as the parser fills it: its index list, as read.
#[derive(Debug, Default)]
struct PlyFace {
    indices: Option<Property>,
}

const FACE_INDEX_NAMES: [&str; 2] = ["vertex_indices", "vertex_index"];

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) {
        if FACE_INDEX_NAMES.contains(&name) {
            self.indices = Some(property);
        }
    }
}

/// An element read past.
struct Ignored;

impl PropertyAccess for Ignored {
    fn new() -> Self {
        Ignored
    }
}

/// The face's corners as signed integers, into `out`.
fn corners(property: Option<&Property>, out: &mut Vec<i64>) -> bool {
    out.clear();
    match property {
        Some(Property::ListChar(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        Some(Property::ListUChar(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        Some(Property::ListShort(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        Some(Property::ListUShort(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        Some(Property::ListInt(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        Some(Property::ListUInt(v)) => out.extend(v.iter().map(|&i| i64::from(i))),
        _ => return false,
    }
    true
}

fn scalar_bytes(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// The fewest bytes one element can take in the payload.
fn min_element_bytes(def: &ElementDef, encoding: Encoding) -> u64 {
    def.properties
        .values()
        .map(|p| match (&p.data_type, encoding) {
            // A number and a separator.
            (_, Encoding::Ascii) => 2,
            (PropertyType::Scalar(t), _) => scalar_bytes(t),
            (PropertyType::List(count, _), _) => scalar_bytes(count),
        })
        .sum::<u64>()
        .max(1)
}

/// The scale that brings a color property's values to 0..=1 (floats are
/// 0..1 as written; a file whose float colors exceed 1 is rescaled later).
fn color_scale(def: &ElementDef, path: &Path) -> Result<Option<f64>, MapError> {
    let mut scale = None;
    for (name, p) in &def.properties {
        if !matches!(vertex_slot(name), Some((true, _))) {
            continue;
        }
        let s = match &p.data_type {
            PropertyType::Scalar(ScalarType::UChar) => 1.0 / 255.0,
            PropertyType::Scalar(ScalarType::UShort) => 1.0 / 65535.0,
            PropertyType::Scalar(ScalarType::Float | ScalarType::Double) => 1.0,
            other => {
                return Err(malformed(
                    path,
                    format!("vertex color property '{name}' is {other:?}: expected uchar, ushort, float or double"),
                ))
            }
        };
        match scale {
            Some(previous) if previous != s => {
                return Err(malformed(
                    path,
                    "the vertex color properties have different types".to_string(),
                ))
            }
            _ => scale = Some(s),
        }
    }
    Ok(scale)
}

fn malformed(path: &Path, reason: String) -> MapError {
    MapError::Malformed {
        path: path.to_path_buf(),
        format: FORMAT,
        reason,
    }
}

fn reserve<T>(v: &mut Vec<T>, n: usize, path: &Path, what: &'static str) -> Result<(), MapError> {
    v.try_reserve_exact(n).map_err(|_| MapError::OutOfMemory {
        path: path.to_path_buf(),
        what,
        needed_bytes: (n as u64).saturating_mul(std::mem::size_of::<T>() as u64),
    })
}

/// Reads one element in the header's encoding.
fn read_element<E: PropertyAccess, R: BufRead>(
    parser: &Parser<E>,
    reader: &mut R,
    def: &ElementDef,
    encoding: Encoding,
    line: &mut String,
) -> std::io::Result<E> {
    match encoding {
        Encoding::Ascii => {
            line.clear();
            if reader.read_line(line)? == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            parser.read_ascii_element(line, def)
        }
        Encoding::BinaryLittleEndian => parser.read_little_endian_element(reader, def),
        Encoding::BinaryBigEndian => parser.read_big_endian_element(reader, def),
    }
}

/// The error of element `i` of `def`: "truncated" when the file has ended.
fn element_error<R: BufRead>(
    path: &Path,
    def: &ElementDef,
    i: usize,
    e: &std::io::Error,
    reader: &mut R,
) -> MapError {
    let ended = e.kind() == std::io::ErrorKind::UnexpectedEof
        || reader.fill_buf().map(|b| b.is_empty()).unwrap_or(false);
    if ended {
        malformed(
            path,
            format!(
                "truncated: the file ends in {} {i}, of the {} the header declares ({e})",
                def.name, def.count
            ),
        )
    } else {
        malformed(path, format!("{} {i}: {e}", def.name))
    }
}

/// Loads a PLY mesh (see the module docs).
pub fn load_ply(path: &Path) -> Result<Mesh, MapError> {
    let file_bytes = check_regular_file(path)?;
    let file = File::open(path).map_err(|source| MapError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let mut reader = BufReader::with_capacity(
        1 << 20,
        Counting {
            inner: file,
            bytes: 0,
        },
    );
    let header: Header = Parser::<Ignored>::new()
        .read_header(&mut reader)
        .map_err(|e| malformed(path, format!("header: {e}")))?;
    let header_bytes = reader.get_ref().bytes - reader.buffer().len() as u64;
    let payload_bytes = file_bytes.saturating_sub(header_bytes);
    let encoding = header.encoding;

    let vertex_def = header
        .elements
        .get("vertex")
        .ok_or_else(|| malformed(path, "no `vertex` element in the header".to_string()))?;
    for axis in ["x", "y", "z"] {
        match vertex_def.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            _ => {
                return Err(malformed(
                    path,
                    format!("the vertex element has no scalar `{axis}` property"),
                ))
            }
        }
    }
    let face_def = match header.elements.get("face") {
        Some(def) if def.count > 0 => def,
        found => {
            return Err(malformed(
                path,
                format!(
                    "no faces ({}; {} vertices): a map must be a mesh, not a point cloud (mesh it first, e.g. by TSDF fusion or Poisson reconstruction)",
                    if found.is_some() {
                        "the face element is empty"
                    } else {
                        "no `face` element"
                    },
                    vertex_def.count
                ),
            ))
        }
    };
    match FACE_INDEX_NAMES
        .iter()
        .find_map(|n| face_def.properties.get(*n))
        .map(|p| &p.data_type)
    {
        Some(PropertyType::List(_, t)) if !matches!(t, ScalarType::Float | ScalarType::Double) => {}
        _ => {
            return Err(malformed(
                path,
                "the face element has no integer list `vertex_indices` (or `vertex_index`)"
                    .to_string(),
            ))
        }
    }
    let scale = color_scale(vertex_def, path)?;
    if header
        .comments
        .iter()
        .any(|c| c.trim_start().starts_with("TextureFile"))
    {
        tracing::warn!(map = %path.display(), "the PLY names a texture (TextureFile): PLY textures are not read, only vertex colors");
    }

    // The payload must be able to hold what the header declares.
    let mut needed: u64 = 0;
    for def in header.elements.values() {
        needed = needed
            .saturating_add((def.count as u64).saturating_mul(min_element_bytes(def, encoding)));
    }
    if needed > payload_bytes {
        return Err(malformed(
            path,
            format!(
                "truncated: the header declares {} vertices and {} faces, at least {needed} bytes of data, but only {payload_bytes} bytes follow the header",
                vertex_def.count, face_def.count
            ),
        ));
    }

    let mut mesh = Mesh::default();
    reserve(
        &mut mesh.positions,
        vertex_def.count,
        path,
        "vertex positions",
    )?;
    reserve(&mut mesh.gray, vertex_def.count, path, "vertex gray")?;
    reserve(
        &mut mesh.indices,
        face_def.count.saturating_mul(3),
        path,
        "triangle indices",
    )?;
    let mut line = String::new();
    let mut face_corners: Vec<i64> = Vec::new();
    let mut max_color = 0.0f64;
    for def in header.elements.values() {
        match def.name.as_str() {
            "vertex" => {
                let parser = Parser::<PlyVertex>::new();
                for i in 0..def.count {
                    let v = read_element(&parser, &mut reader, def, encoding, &mut line)
                        .map_err(|e| element_error(path, def, i, &e, &mut reader))?;
                    if let Some(c) = v
                        .position
                        .iter()
                        .find(|c| c.abs() > MAX_VERTEX_COORDINATE && c.is_finite())
                    {
                        return Err(malformed(
                            path,
                            format!("vertex {i}: coordinate {c} is outside the sane range -1e6..=1e6 (file units)"),
                        ));
                    }
                    mesh.positions.push(v.position.map(|c| c as f32));
                    let gray = match scale {
                        Some(s) => {
                            let rgb = v.rgb.map(|c| c * s);
                            for c in rgb {
                                if !(0.0..=255.0).contains(&c) {
                                    return Err(malformed(
                                        path,
                                        format!(
                                            "vertex {i}: color {c} is outside 0..=1 (or 0..=255)"
                                        ),
                                    ));
                                }
                                max_color = max_color.max(c);
                            }
                            luma601_255(rgb.map(|c| c as f32))
                        }
                        None => 255.0,
                    };
                    mesh.gray.push(gray);
                }
            }
            "face" => {
                let parser = Parser::<PlyFace>::new();
                let vertex_count = vertex_def.count as i64;
                for i in 0..def.count {
                    let face = read_element(&parser, &mut reader, def, encoding, &mut line)
                        .map_err(|e| element_error(path, def, i, &e, &mut reader))?;
                    if !corners(face.indices.as_ref(), &mut face_corners) {
                        return Err(malformed(path, format!("face {i}: no vertex index list")));
                    }
                    if face_corners.len() < 3 {
                        return Err(malformed(
                            path,
                            format!(
                                "face {i} has {} corners: at least 3 are needed",
                                face_corners.len()
                            ),
                        ));
                    }
                    if let Some(bad) = face_corners.iter().find(|&&c| c < 0 || c >= vertex_count) {
                        return Err(malformed(
                            path,
                            format!(
                                "face {i} refers to vertex {bad} but the file has {vertex_count} vertices (0..={})",
                                vertex_count - 1
                            ),
                        ));
                    }
                    // A fan: exact for triangles and convex polygons.
                    for k in 1..face_corners.len() - 1 {
                        for c in [face_corners[0], face_corners[k], face_corners[k + 1]] {
                            mesh.indices.push(c as u32);
                        }
                    }
                }
            }
            _ => {
                let parser = Parser::<Ignored>::new();
                for i in 0..def.count {
                    read_element(&parser, &mut reader, def, encoding, &mut line)
                        .map_err(|e| element_error(path, def, i, &e, &mut reader))?;
                }
            }
        }
    }
    if scale == Some(1.0) && max_color > 1.0 {
        // Float colors written as 0..255: luma is linear.
        for g in &mut mesh.gray {
            *g /= 255.0;
        }
    }
    mesh.find_problem().map_err(|problem| MapError::Invalid {
        path: path.to_path_buf(),
        problem,
    })?;
    if scale.is_none() {
        tracing::warn!(
            map = %path.display(),
            "the mesh has no vertex colors: every surface renders the same flat white, which gives the tracker nothing to align to"
        );
    }
    tracing::info!(
        path = %path.display(),
        triangles = mesh.triangle_count(),
        vertices = mesh.positions.len(),
        encoding = ?encoding,
        "mesh loaded"
    );
    Ok(mesh)
}
