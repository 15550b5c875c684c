//! PLY writing of a gray [`Mesh`], the inverse of [`crate::map::load_ply`],
//! streamed element by element through `ply-rs-bw`'s writer.
//!
//! Takes a valid mesh, a path and an encoding; writes `float x y z`,
//! `uchar red green blue` (gray, rounded, in all three) and `face` lists of
//! `uint vertex_indices`. PLY has no standard for textures: a textured
//! mesh's textures are not written (a warning says so), only its vertex
//! gray.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Header, PropertyAccess, PropertyDef, PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use super::error::MapError;
use super::Mesh;

/// How the PLY payload is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Text, one element per line.
    Ascii,
    /// Binary, little endian (what most tools write).
    BinaryLittleEndian,
    /// Binary, big endian.
    BinaryBigEndian,
}

impl From<PlyEncoding> for Encoding {
    fn from(e: PlyEncoding) -> Self {
        match e {
            PlyEncoding::Ascii => Encoding::Ascii,
            PlyEncoding::BinaryLittleEndian => Encoding::BinaryLittleEndian,
            PlyEncoding::BinaryBigEndian => Encoding::BinaryBigEndian,
        }
    }
}

struct OutVertex {
    position: [f32; 3],
    gray: u8,
}

impl PropertyAccess for OutVertex {
    fn new() -> Self {
        OutVertex {
            position: [0.0; 3],
            gray: 0,
        }
    }

    fn get_float(&self, name: &str) -> Option<f32> {
        match name {
            "x" => Some(self.position[0]),
            "y" => Some(self.position[1]),
            "z" => Some(self.position[2]),
            _ => None,
        }
    }

    fn get_uchar(&self, name: &str) -> Option<u8> {
        matches!(name, "red" | "green" | "blue").then_some(self.gray)
    }
}

struct OutFace {
    indices: [u32; 3],
}

impl PropertyAccess for OutFace {
    fn new() -> Self {
        OutFace { indices: [0; 3] }
    }

    fn get_list_uint(&self, name: &str) -> Option<&[u32]> {
        (name == "vertex_indices").then_some(&self.indices[..])
    }
}

fn header(mesh: &Mesh, encoding: PlyEncoding) -> Header {
    let mut header = Header::new();
    header.encoding = encoding.into();
    header
        .comments
        .push("written by star: gray mesh, red = green = blue = gray".into());
    let mut vertex = ElementDef::new("vertex".into());
    vertex.count = mesh.positions.len();
    for axis in ["x", "y", "z"] {
        vertex.properties.add(PropertyDef::new(
            axis.into(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    for channel in ["red", "green", "blue"] {
        vertex.properties.add(PropertyDef::new(
            channel.into(),
            PropertyType::Scalar(ScalarType::UChar),
        ));
    }
    header.elements.add(vertex);
    let mut face = ElementDef::new("face".into());
    face.count = mesh.triangle_count();
    face.properties.add(PropertyDef::new(
        "vertex_indices".into(),
        PropertyType::List(ScalarType::UChar, ScalarType::UInt),
    ));
    header.elements.add(face);
    header
}

/// Writes `mesh` to `path` as PLY with `encoding`.
pub fn write_ply(mesh: &Mesh, path: &Path, encoding: PlyEncoding) -> Result<(), MapError> {
    mesh.validate()?;
    if mesh.groups.iter().any(|g| g.texture.is_some()) {
        tracing::warn!(path = %path.display(), "PLY has no textures: only the vertex gray of the textured mesh is written");
    }
    let write_err = |source| MapError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut out = BufWriter::with_capacity(1 << 20, File::create(path).map_err(write_err)?);
    let header = header(mesh, encoding);
    let (Some(vertex_def), Some(face_def)) =
        (header.elements.get("vertex"), header.elements.get("face"))
    else {
        return Err(write_err(std::io::Error::other(
            "PLY header without elements",
        )));
    };
    let vertex_writer = Writer::<OutVertex>::new();
    vertex_writer
        .write_header(&mut out, &header)
        .map_err(write_err)?;
    let write_element =
        |out: &mut BufWriter<File>,
         element: &dyn Fn(&mut BufWriter<File>) -> std::io::Result<usize>| {
            element(out).map(|_| ()).map_err(write_err)
        };
    for (p, &gray) in mesh.positions.iter().zip(&mesh.gray) {
        let v = OutVertex {
            position: *p,
            gray: gray.round().clamp(0.0, 255.0) as u8,
        };
        write_element(&mut out, &|o| match encoding {
            PlyEncoding::Ascii => vertex_writer.write_ascii_element(o, &v, vertex_def),
            PlyEncoding::BinaryLittleEndian => {
                vertex_writer.write_little_endian_element(o, &v, vertex_def)
            }
            PlyEncoding::BinaryBigEndian => {
                vertex_writer.write_big_endian_element(o, &v, vertex_def)
            }
        })?;
    }
    let face_writer = Writer::<OutFace>::new();
    for t in mesh.indices.chunks_exact(3) {
        let f = OutFace {
            indices: [t[0], t[1], t[2]],
        };
        write_element(&mut out, &|o| match encoding {
            PlyEncoding::Ascii => face_writer.write_ascii_element(o, &f, face_def),
            PlyEncoding::BinaryLittleEndian => {
                face_writer.write_little_endian_element(o, &f, face_def)
            }
            PlyEncoding::BinaryBigEndian => face_writer.write_big_endian_element(o, &f, face_def),
        })?;
    }
    out.flush().map_err(write_err)?;
    tracing::info!(
        path = %path.display(),
        triangles = mesh.triangle_count(),
        ?encoding,
        "mesh written"
    );
    Ok(())
}
