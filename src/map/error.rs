//! Errors from loading, validating and writing meshes.
//!
//! [`MapError`] names the file (or `<in-memory mesh>` for meshes built in
//! code) and the problem; [`MeshProblem`] is the structural defect that
//! [`crate::map::Mesh::validate`] found, shared by the loader and renderers.

use std::path::PathBuf;

/// Label used as the "file" of a mesh that was built in memory.
pub const IN_MEMORY: &str = "<in-memory mesh>";

/// A structural defect in a [`crate::map::Mesh`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshProblem {
    /// The mesh has no triangles.
    #[error("the mesh has no faces")]
    NoFaces,
    /// `indices.len()` is not a multiple of three.
    #[error("{count} triangle indices is not a multiple of 3")]
    IndexCount {
        /// Number of indices found.
        count: usize,
    },
    /// A per-vertex array does not have one entry per position.
    #[error("{what} has {found} entries but there are {expected} vertices")]
    AttributeCount {
        /// Which array (`gray` or `uvs`).
        what: &'static str,
        /// Expected length (number of positions).
        expected: usize,
        /// Actual length.
        found: usize,
    },
    /// A vertex attribute is NaN or infinite.
    #[error("vertex {vertex} has a non-finite {what}: {value}")]
    NotFinite {
        /// Vertex index (0-based).
        vertex: usize,
        /// Which attribute (`position`, `gray`, `uv`).
        what: &'static str,
        /// The offending value.
        value: f32,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle} refers to vertex {index} but there are {vertex_count} vertices")]
    IndexOutOfRange {
        /// Triangle number (0-based).
        triangle: usize,
        /// The vertex index found.
        index: u32,
        /// Number of vertices.
        vertex_count: usize,
    },
    /// The groups do not cover the indices exactly once, in order.
    #[error("group {group} covers indices {first}..{end} but {expected_first} was expected next (of {index_count})")]
    GroupCoverage {
        /// Group number.
        group: usize,
        /// Its first index.
        first: u32,
        /// One past its last index.
        end: u64,
        /// The index the previous groups ended at.
        expected_first: u64,
        /// Total number of indices.
        index_count: usize,
    },
    /// A group names a texture that does not exist.
    #[error("group {group} uses texture {texture} but there are {texture_count} textures")]
    TextureOutOfRange {
        /// Group number.
        group: usize,
        /// Texture index found.
        texture: u32,
        /// Number of textures.
        texture_count: usize,
    },
    /// A texture's texel buffer does not match its size, or it is empty.
    #[error("texture {texture} is {width}x{height} but holds {found} texels")]
    TextureSize {
        /// Texture number.
        texture: usize,
        /// Width in texels.
        width: u32,
        /// Height in texels.
        height: u32,
        /// Number of texels found.
        found: usize,
    },
    /// A texel is NaN or infinite.
    #[error("texture {texture} texel {texel} is not finite: {value}")]
    TextureNotFinite {
        /// Texture number.
        texture: usize,
        /// Texel offset, row-major.
        texel: usize,
        /// The offending value.
        value: f32,
    },
}

/// Errors from loading, validating or writing a mesh.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// A file could not be opened or read (missing, permissions, ...).
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// An OBJ line could not be parsed.
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The OBJ file.
        path: PathBuf,
        /// 1-based line number (0 when the parser gave none).
        line: usize,
        /// What was expected and what was found.
        reason: String,
    },
    /// A face refers to a vertex or texture coordinate that does not exist.
    #[error(
        "{path}:{line}: face {kind} index {index} is out of range (1..={count} defined so far)"
    )]
    FaceIndex {
        /// The OBJ file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// `vertex`, `texture coordinate` or `normal`.
        kind: &'static str,
        /// The index as written in the file.
        index: i64,
        /// How many of that kind were defined before the face.
        count: usize,
    },
    /// A material library could not be loaded.
    #[error("material library {path} (referenced by {obj}): {reason}")]
    Material {
        /// The MTL file.
        path: PathBuf,
        /// The OBJ that references it.
        obj: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// A texture named by a material does not exist.
    #[error("texture {path} of material '{material}' does not exist")]
    MissingTexture {
        /// The resolved texture path.
        path: PathBuf,
        /// The material naming it.
        material: String,
    },
    /// A texture could not be decoded.
    #[error("cannot decode texture {path}: {source}")]
    TextureDecode {
        /// The texture file.
        path: PathBuf,
        /// The decoder's error.
        source: image::ImageError,
    },
    /// The mesh is structurally invalid (no faces, NaN vertices, ...).
    #[error("{path}: {problem}")]
    Invalid {
        /// The file, or [`IN_MEMORY`].
        path: PathBuf,
        /// The defect.
        problem: MeshProblem,
    },
    /// Memory for the mesh could not be allocated.
    #[error("map {path}: out of memory: {what} needs {needed_bytes} bytes and the allocation failed; use a smaller or decimated mesh, or a machine with more memory")]
    OutOfMemory {
        /// The map file.
        path: PathBuf,
        /// What was being allocated (`the OBJ text`, `vertex positions`, ...).
        what: &'static str,
        /// Bytes asked for.
        needed_bytes: u64,
    },
    /// The file's extension names no map format star reads.
    #[error("{path}: unknown map format '{extension}': expected .obj, .ply, .gltf or .glb")]
    UnknownFormat {
        /// The map file.
        path: PathBuf,
        /// Its extension (empty when it has none).
        extension: String,
    },
    /// The content is not what the extension says.
    #[error("{path}: the extension says {expected} but the content {found}")]
    FormatMismatch {
        /// The map file.
        path: PathBuf,
        /// The format the extension names.
        expected: &'static str,
        /// What the first bytes look like.
        found: String,
    },
    /// A PLY or glTF file breaks its format: truncated, a missing element
    /// or attribute, an index out of range, a bad header or accessor.
    #[error("{path}: bad {format} file: {reason}")]
    Malformed {
        /// The map file.
        path: PathBuf,
        /// `PLY`, `glTF` or `GLB`.
        format: &'static str,
        /// What was expected and what was found.
        reason: String,
    },
    /// A file could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A texture could not be encoded.
    #[error("cannot encode texture {path}: {source}")]
    TextureEncode {
        /// The texture file.
        path: PathBuf,
        /// The encoder's error.
        source: image::ImageError,
    },
}

impl MapError {
    /// The structural problem, when this is [`MapError::Invalid`].
    pub fn problem(&self) -> Option<&MeshProblem> {
        match self {
            MapError::Invalid { problem, .. } => Some(problem),
            _ => None,
        }
    }
}
