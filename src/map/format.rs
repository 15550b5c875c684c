//! Which loader reads a map file: the format comes from the extension and
//! is checked against the file's first bytes.
//!
//! Takes a path, gives out a [`Mesh`] through [`load_mesh`] (OBJ, PLY,
//! glTF or GLB), or a [`MapError`] naming the file: an unknown extension
//! ([`MapError::UnknownFormat`]), or content that is another format than
//! the extension says ([`MapError::FormatMismatch`]: a GLB renamed `.ply`,
//! a PLY renamed `.obj`).

use std::io::Read;
use std::path::Path;

use super::error::MapError;
use super::Mesh;

/// The map formats star reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapFormat {
    /// Wavefront OBJ (+ MTL + textures).
    Obj,
    /// Stanford PLY, ASCII or binary.
    Ply,
    /// glTF 2.0, JSON with external or embedded buffers.
    Gltf,
    /// glTF 2.0 binary container.
    Glb,
}

/// What the first bytes of a file look like.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Content {
    Ply,
    Glb,
    Json,
    Other,
}

impl MapFormat {
    /// The format the extension of `path` names (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self, MapError> {
        let extension = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match extension.as_str() {
            "obj" => Ok(MapFormat::Obj),
            "ply" => Ok(MapFormat::Ply),
            "gltf" => Ok(MapFormat::Gltf),
            "glb" => Ok(MapFormat::Glb),
            _ => Err(MapError::UnknownFormat {
                path: path.to_path_buf(),
                extension,
            }),
        }
    }

    /// The format's name in messages.
    pub fn name(self) -> &'static str {
        match self {
            MapFormat::Obj => "OBJ",
            MapFormat::Ply => "PLY",
            MapFormat::Gltf => "glTF",
            MapFormat::Glb => "GLB",
        }
    }

    fn accepts(self, content: Content) -> bool {
        match self {
            MapFormat::Obj => content == Content::Other,
            MapFormat::Ply => content == Content::Ply,
            MapFormat::Gltf => content == Content::Json,
            MapFormat::Glb => content == Content::Glb,
        }
    }
}

impl Content {
    fn of(head: &[u8]) -> Self {
        let text = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
        if head.starts_with(b"ply\n") || head.starts_with(b"ply\r") {
            Content::Ply
        } else if head.starts_with(b"glTF") {
            Content::Glb
        } else if text.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{') {
            Content::Json
        } else {
            Content::Other
        }
    }

    fn describe(self, head: &[u8]) -> String {
        match self {
            Content::Ply => "starts with a PLY header".into(),
            Content::Glb => "starts with the binary glTF (GLB) magic".into(),
            Content::Json => "is JSON (a .gltf file?)".into(),
            Content::Other if head.is_empty() => "is empty".into(),
            Content::Other => {
                let shown: String = head
                    .iter()
                    .take(16)
                    .map(|&b| {
                        if b.is_ascii_graphic() || b == b' ' {
                            b as char
                        } else {
                            '.'
                        }
                    })
                    .collect();
                format!("starts with '{shown}'")
            }
        }
    }
}

/// Refuses what is not a regular file (a FIFO would block a reader).
pub(super) fn check_regular_file(path: &Path) -> Result<u64, MapError> {
    let read_err = |source| MapError::Read {
        path: path.to_path_buf(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(read_err)?;
    if !meta.is_file() {
        return Err(read_err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file",
        )));
    }
    Ok(meta.len())
}

/// Checks that the content of `path` is `format`.
pub fn check_content(path: &Path, format: MapFormat) -> Result<(), MapError> {
    check_regular_file(path)?;
    let mut head = Vec::with_capacity(64);
    std::fs::File::open(path)
        .and_then(|f| f.take(64).read_to_end(&mut head))
        .map_err(|source| MapError::Read {
            path: path.to_path_buf(),
            source,
        })?;
    let content = Content::of(&head);
    if format.accepts(content) {
        return Ok(());
    }
    Err(MapError::FormatMismatch {
        path: path.to_path_buf(),
        expected: format.name(),
        found: content.describe(&head),
    })
}

/// Loads a map mesh in the format its extension names (see the module
/// docs), in the file's own frame and units.
pub fn load_mesh(path: &Path) -> Result<Mesh, MapError> {
    let format = MapFormat::from_path(path)?;
    check_content(path, format)?;
    match format {
        MapFormat::Obj => super::load_obj(path),
        MapFormat::Ply => super::load_ply(path),
        MapFormat::Gltf | MapFormat::Glb => super::load_gltf(path),
    }
}

/// The last step of every loader: the triangles of each texture bucket
/// (`None`: vertex colors) become one group each, the mesh is checked
/// ([`Mesh::find_problem`]), and the load is logged. `no_colors`: what is
/// missing when the file has no colors at all, warned as a map the tracker
/// cannot use.
pub(crate) fn finish_mesh(
    mesh: &mut Mesh,
    buckets: Vec<(Option<u32>, Vec<u32>)>,
    path: &Path,
    no_colors: Option<&str>,
) -> Result<(), MapError> {
    for (texture, indices) in buckets {
        if indices.is_empty() {
            continue;
        }
        mesh.groups.push(super::MeshGroup {
            first_index: mesh.indices.len() as u32,
            index_count: indices.len() as u32,
            texture,
        });
        mesh.indices.extend(indices);
    }
    mesh.find_problem().map_err(|problem| MapError::Invalid {
        path: path.to_path_buf(),
        problem,
    })?;
    if let Some(missing) = no_colors {
        tracing::warn!(
            map = %path.display(),
            "the mesh has no colors ({missing}): every surface renders the same flat white, which gives the tracker nothing to align to"
        );
    }
    tracing::info!(
        path = %path.display(),
        triangles = mesh.triangle_count(),
        vertices = mesh.positions.len(),
        textures = mesh.textures.len(),
        "mesh loaded"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_is_recognized_from_the_first_bytes() {
        assert_eq!(Content::of(b"ply\nformat ascii 1.0\n"), Content::Ply);
        assert_eq!(Content::of(b"ply\r\nformat"), Content::Ply);
        assert_eq!(Content::of(b"glTF\x02\0\0\0"), Content::Glb);
        assert_eq!(Content::of(b"\xEF\xBB\xBF  {\"asset\""), Content::Json);
        assert_eq!(Content::of(b"# OBJ\nv 0 0 0\n"), Content::Other);
        assert_eq!(Content::of(b"plywood"), Content::Other);
    }

    #[test]
    fn the_extension_names_the_format() {
        assert_eq!(
            MapFormat::from_path(Path::new("a/b.PLY")).ok(),
            Some(MapFormat::Ply)
        );
        assert_eq!(
            MapFormat::from_path(Path::new("b.glb")).ok(),
            Some(MapFormat::Glb)
        );
        let e = MapFormat::from_path(Path::new("scan.stl")).expect_err("stl");
        assert!(e.to_string().contains("scan.stl") && e.to_string().contains("'stl'"));
    }
}
