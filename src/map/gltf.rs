//! glTF 2.0 loading (`.gltf` JSON or `.glb` binary) into a gray [`Mesh`].
//!
//! Takes a path, gives out a validated [`Mesh`] or a [`MapError`] naming the
//! file and the problem. The document goes through the `gltf` crate (which
//! validates the JSON's cross-references); buffers and images are read here,
//! so each failure names its file: the GLB's `BIN` chunk, `data:` URIs
//! (base64) and files relative to the glTF.
//!
//! The default scene (else the first, else every mesh at the origin) is
//! walked with each node's transform, so the mesh comes out in the file's
//! frame: glTF is y-up in meters by convention, which `star map align` and
//! `[map.world_from_mesh]` turn z-up. Triangle lists, strips and fans are
//! read; points and lines are skipped with a warning. A vertex's gray is
//! the Rec.601 luma of its `COLOR_0` (white without) times the material's
//! base-color factor; a base-color texture becomes a gray texture that the
//! vertex gray modulates, with the primitive's `TEXCOORD_n` (glTF's v
//! already points down the image, as the mesh's does).
//!
//! Refused, naming the file: a truncated or unparsable file, a buffer that
//! is missing or shorter than declared, an accessor outside its buffer, a
//! primitive without positions, an index out of range, a missing or
//! undecodable texture, required extensions star does not read (Draco,
//! meshopt), and (through the mesh check) NaN or infinite values.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use base64::Engine;
use gltf::mesh::Mode;

use super::error::MapError;
use super::format::check_regular_file;
use super::obj::{gray_texture, luma601_255};
use super::Mesh;

/// The format's name for messages: `GLB` for `.glb`, else `glTF`.
fn format_name(path: &Path) -> &'static str {
    match path.extension().map(|e| e.to_ascii_lowercase()) {
        Some(e) if e == "glb" => "GLB",
        _ => "glTF",
    }
}

fn malformed(path: &Path, reason: impl Into<String>) -> MapError {
    MapError::Malformed {
        path: path.to_path_buf(),
        format: format_name(path),
        reason: reason.into(),
    }
}

/// Bytes of a `data:` URI, or `None` when `uri` is not one.
fn data_uri(uri: &str) -> Option<Result<Vec<u8>, String>> {
    let rest = uri.strip_prefix("data:")?;
    let Some((_, payload)) = rest.split_once(";base64,") else {
        return Some(Err("a data URI that is not base64".into()));
    };
    Some(
        base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| format!("bad base64 in a data URI: {e}")),
    )
}

/// A file URI relative to the glTF's folder (`%20` and friends decoded).
fn relative_file(dir: &Path, uri: &str) -> PathBuf {
    let mut bytes = Vec::with_capacity(uri.len());
    let raw = uri.strip_prefix("file://").unwrap_or(uri).as_bytes();
    let mut i = 0;
    while i < raw.len() {
        let hex = raw
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (raw[i], hex) {
            (b'%', Some(b)) => {
                bytes.push(b);
                i += 3;
            }
            (c, _) => {
                bytes.push(c);
                i += 1;
            }
        }
    }
    dir.join(String::from_utf8_lossy(&bytes).as_ref())
}

/// Reads every buffer of the document.
fn load_buffers(
    path: &Path,
    document: &gltf::Document,
    blob: Option<Vec<u8>>,
) -> Result<Vec<Vec<u8>>, MapError> {
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut blob = blob;
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let i = buffer.index();
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                malformed(
                    path,
                    format!("buffer {i} refers to the GLB's BIN chunk, which is missing"),
                )
            })?,
            gltf::buffer::Source::Uri(uri) => match data_uri(uri) {
                Some(bytes) => bytes.map_err(|e| malformed(path, format!("buffer {i}: {e}")))?,
                None => {
                    let file = relative_file(&dir, uri);
                    check_regular_file(&file)
                        .and_then(|_| {
                            std::fs::read(&file).map_err(|source| MapError::Read {
                                path: file.clone(),
                                source,
                            })
                        })
                        .map_err(|e| malformed(path, format!("buffer {i}: {e}")))?
                }
            },
        };
        if data.len() < buffer.length() {
            return Err(malformed(
                path,
                format!(
                    "truncated: buffer {i} holds {} bytes but declares {}",
                    data.len(),
                    buffer.length()
                ),
            ));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// Decodes image `image` of the document into a gray texture.
fn load_image(
    path: &Path,
    image: &gltf::Image,
    buffers: &[Vec<u8>],
    material: &str,
) -> Result<super::GrayTexture, MapError> {
    let i = image.index();
    let label = PathBuf::from(format!("{} (image {i})", path.display()));
    let decode = |bytes: &[u8], label: PathBuf| {
        image::load_from_memory(bytes)
            .map(|img| gray_texture(&img))
            .map_err(|source| MapError::TextureDecode {
                path: label,
                source,
            })
            .map_err(|e| malformed(path, format!("material {material}: {e}")))
    };
    match image.source() {
        gltf::image::Source::View { view, .. } => {
            let bytes = buffers
                .get(view.buffer().index())
                .and_then(|b| b.get(view.offset()..view.offset().checked_add(view.length())?))
                .ok_or_else(|| {
                    malformed(
                        path,
                        format!("image {i}: its buffer view lies outside its buffer (truncated?)"),
                    )
                })?;
            decode(bytes, label)
        }
        gltf::image::Source::Uri { uri, .. } => match data_uri(uri) {
            Some(bytes) => decode(
                &bytes.map_err(|e| malformed(path, format!("image {i}: {e}")))?,
                label,
            ),
            None => {
                let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
                let file = relative_file(&dir, uri);
                if !file.is_file() {
                    return Err(malformed(
                        path,
                        format!(
                            "image {i} of material {material}: texture {} does not exist",
                            file.display()
                        ),
                    ));
                }
                super::load_gray_texture(&file)
                    .map_err(|e| malformed(path, format!("image {i} of material {material}: {e}")))
            }
        },
    }
}

/// What a loaded primitive adds to the mesh.
struct Builder<'a> {
    path: &'a Path,
    buffers: &'a [Vec<u8>],
    mesh: Mesh,
    /// Triangle buckets by texture, in order of first appearance.
    buckets: Vec<(Option<u32>, Vec<u32>)>,
    /// Image index to texture index.
    textures: HashMap<usize, u32>,
    any_color: bool,
    skipped: usize,
}

type Matrix = nalgebra::Matrix4<f64>;

impl Builder<'_> {
    fn node(&mut self, node: gltf::Node, parent: &Matrix) -> Result<(), MapError> {
        let m = node.transform().matrix();
        let local = Matrix::from_fn(|r, c| f64::from(m[c][r]));
        let world_from_node = parent * local;
        if let Some(mesh) = node.mesh() {
            self.add_mesh(&mesh, &world_from_node)?;
        }
        for child in node.children() {
            self.node(child, &world_from_node)?;
        }
        Ok(())
    }

    fn add_mesh(&mut self, mesh: &gltf::Mesh, transform: &Matrix) -> Result<(), MapError> {
        let name = mesh.name().map_or_else(
            || format!("mesh {}", mesh.index()),
            |n| format!("mesh {} '{n}'", mesh.index()),
        );
        for primitive in mesh.primitives() {
            let what = format!("{name} primitive {}", primitive.index());
            self.add_primitive(&primitive, transform, &what)?;
        }
        Ok(())
    }

    fn add_primitive(
        &mut self,
        primitive: &gltf::Primitive,
        transform: &Matrix,
        what: &str,
    ) -> Result<(), MapError> {
        let path = self.path;
        let mode = primitive.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            self.skipped += 1;
            return Ok(());
        }
        let buffers = self.buffers;
        let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
        let outside = |attribute: &str| {
            malformed(
                path,
                format!("{what}: the {attribute} accessor lies outside its buffer (truncated?)"),
            )
        };
        if primitive.get(&gltf::Semantic::Positions).is_none() {
            return Err(malformed(path, format!("{what} has no POSITION attribute")));
        }
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| outside("POSITION"))?
            .collect();
        let n = positions.len();
        let material = primitive.material();
        let material_name = material
            .name()
            .map(|n| format!("'{n}'"))
            .or_else(|| material.index().map(|i| i.to_string()))
            .unwrap_or_else(|| "(default)".into());
        let pbr = material.pbr_metallic_roughness();
        let factor = pbr.base_color_factor();
        let colors: Option<Vec<[f32; 3]>> = match primitive.get(&gltf::Semantic::Colors(0)) {
            Some(_) => Some(
                reader
                    .read_colors(0)
                    .ok_or_else(|| outside("COLOR_0"))?
                    .into_rgb_f32()
                    .collect(),
            ),
            None => None,
        };
        if colors.as_ref().is_some_and(|c| c.len() != n) {
            return Err(malformed(
                path,
                format!("{what}: COLOR_0 and POSITION have different counts"),
            ));
        }
        self.any_color |= colors.is_some() || factor[..3] != [1.0, 1.0, 1.0];
        let texture = match pbr.base_color_texture() {
            Some(info) => {
                let set = info.tex_coord();
                if primitive.get(&gltf::Semantic::TexCoords(set)).is_none() {
                    return Err(malformed(
                        path,
                        format!("{what}: material {material_name} has a base-color texture but the primitive has no TEXCOORD_{set}"),
                    ));
                }
                let image = info.texture().source();
                let index = match self.textures.get(&image.index()) {
                    Some(&t) => t,
                    None => {
                        let t = load_image(path, &image, buffers, &material_name)?;
                        let index = self.mesh.textures.len() as u32;
                        self.mesh.textures.push(t);
                        self.textures.insert(image.index(), index);
                        index
                    }
                };
                let uvs: Vec<[f32; 2]> = reader
                    .read_tex_coords(set)
                    .ok_or_else(|| outside("TEXCOORD"))?
                    .into_f32()
                    .collect();
                if uvs.len() != n {
                    return Err(malformed(
                        path,
                        format!("{what}: TEXCOORD_{set} and POSITION have different counts"),
                    ));
                }
                self.any_color = true;
                Some((index, uvs))
            }
            None => None,
        };
        let indices: Vec<u32> = match primitive.indices() {
            Some(_) => reader
                .read_indices()
                .ok_or_else(|| outside("indices"))?
                .into_u32()
                .collect(),
            None => (0..n as u32).collect(),
        };
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
            return Err(malformed(
                path,
                format!("{what}: index {bad} is out of range ({n} vertices)"),
            ));
        }
        let triangles = match mode {
            Mode::Triangles => {
                if indices.len() % 3 != 0 {
                    return Err(malformed(
                        path,
                        format!("{what}: {} indices is not a multiple of 3", indices.len()),
                    ));
                }
                indices
            }
            Mode::TriangleStrip => (2..indices.len())
                .flat_map(|k| {
                    if k % 2 == 0 {
                        [indices[k - 2], indices[k - 1], indices[k]]
                    } else {
                        [indices[k - 1], indices[k - 2], indices[k]]
                    }
                })
                .collect(),
            _ => (2..indices.len())
                .flat_map(|k| [indices[0], indices[k - 1], indices[k]])
                .collect(),
        };

        let base = self.mesh.positions.len() as u32;
        for (v, p) in positions.iter().enumerate() {
            let w = transform
                * nalgebra::Vector4::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]), 1.0);
            self.mesh
                .positions
                .push([w.x as f32, w.y as f32, w.z as f32]);
            let c = colors
                .as_ref()
                .and_then(|c| c.get(v))
                .copied()
                .unwrap_or([1.0; 3]);
            self.mesh.gray.push(luma601_255([
                c[0] * factor[0],
                c[1] * factor[1],
                c[2] * factor[2],
            ]));
            self.mesh.uvs.push(
                texture
                    .as_ref()
                    .and_then(|(_, uvs)| uvs.get(v))
                    .copied()
                    .unwrap_or([0.0, 0.0]),
            );
        }
        let key = texture.map(|(t, _)| t);
        let bucket = match self.buckets.iter().position(|(t, _)| *t == key) {
            Some(i) => i,
            None => {
                self.buckets.push((key, Vec::new()));
                self.buckets.len() - 1
            }
        };
        if let Some((_, b)) = self.buckets.get_mut(bucket) {
            b.extend(triangles.iter().map(|&i| i + base));
        }
        Ok(())
    }
}

/// Loads a glTF or GLB mesh (see the module docs).
pub fn load_gltf(path: &Path) -> Result<Mesh, MapError> {
    let bytes_len = check_regular_file(path)?;
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(usize::try_from(bytes_len).unwrap_or(usize::MAX))
        .map_err(|_| MapError::OutOfMemory {
            path: path.to_path_buf(),
            what: "the glTF file",
            needed_bytes: bytes_len,
        })?;
    std::io::Read::read_to_end(
        &mut std::fs::File::open(path).map_err(|source| MapError::Read {
            path: path.to_path_buf(),
            source,
        })?,
        &mut bytes,
    )
    .map_err(|source| MapError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    // The crate's GLB reader subtracts header lengths unchecked: a panic
    // on a hostile file is caught and reported as a bad file.
    let parsed = std::panic::catch_unwind(|| gltf::Gltf::from_slice(&bytes)).map_err(|_| {
        malformed(
            path,
            "the glTF parser failed on this file (corrupt header?)",
        )
    })?;
    let gltf = parsed.map_err(|e| {
        let reason = match e {
            gltf::Error::Binary(e) => format!("truncated or corrupt GLB container: {e}"),
            gltf::Error::Deserialize(e) => format!("JSON: {e}"),
            gltf::Error::Validation(errors) => {
                let list: Vec<String> = errors
                    .iter()
                    .take(5)
                    .map(|(p, e)| format!("{}: {e}", p.as_str()))
                    .collect();
                format!("invalid document: {}", list.join("; "))
            }
            other => other.to_string(),
        };
        malformed(path, reason)
    })?;
    drop(bytes);
    let required: Vec<&str> = gltf.document.extensions_required().collect();
    if !required.is_empty() {
        return Err(malformed(
            path,
            format!(
                "requires extensions star does not read: {} (export without compression or quantization)",
                required.join(", ")
            ),
        ));
    }
    let gltf::Gltf { document, blob } = gltf;
    let buffers = load_buffers(path, &document, blob)?;
    let mut builder = Builder {
        path,
        buffers: &buffers,
        mesh: Mesh::default(),
        buckets: Vec::new(),
        textures: HashMap::new(),
        any_color: false,
        skipped: 0,
    };
    let identity = Matrix::identity();
    let walked = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        match document
            .default_scene()
            .or_else(|| document.scenes().next())
        {
            Some(scene) => scene
                .nodes()
                .try_for_each(|node| builder.node(node, &identity)),
            None => document
                .meshes()
                .try_for_each(|mesh| builder.add_mesh(&mesh, &identity)),
        }
    }));
    walked.map_err(|_| {
        malformed(
            path,
            "the glTF reader failed on an accessor (corrupt buffer layout?)",
        )
    })??;
    if builder.skipped > 0 {
        tracing::warn!(map = %path.display(), primitives = builder.skipped, "points and lines in the glTF are not part of the map");
    }
    let Builder {
        mut mesh,
        buckets,
        any_color,
        ..
    } = builder;
    let textured = buckets.iter().any(|(t, _)| t.is_some());
    if !textured {
        mesh.uvs.clear();
    }
    super::format::finish_mesh(
        &mut mesh,
        buckets,
        path,
        (!any_color).then_some("no COLOR_0, base-color factor or texture"),
    )?;
    tracing::info!("glTF is y-up by convention: `star map align` writes the [map.world_from_mesh] that makes it z-up");
    Ok(mesh)
}
