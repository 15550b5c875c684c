//! GLB (binary glTF 2.0) writing of a gray [`Mesh`], the inverse of
//! [`crate::map::load_gltf`].
//!
//! Takes a valid mesh and a path; writes one GLB with one mesh of one
//! primitive per mesh group: `POSITION`, `COLOR_0` (gray/255 in all three
//! channels, float), `TEXCOORD_0` when the mesh has uvs, `u32` indices, and
//! per texture an 8-bit gray PNG in the `BIN` chunk as the material's
//! base-color texture (repeat wrapping, linear filtering). The positions are
//! written as they are: the file is in the mesh's frame, not converted to
//! glTF's y-up.

use std::borrow::Cow;
use std::path::Path;

use serde_json::json;

use super::error::MapError;
use super::Mesh;

/// Appends `bytes` to `bin` on a 4-byte boundary; returns the offset.
fn push_aligned(bin: &mut Vec<u8>, bytes: &[u8]) -> usize {
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    offset
}

/// Writes `mesh` to `path` as GLB.
pub fn write_glb(mesh: &Mesh, path: &Path) -> Result<(), MapError> {
    mesh.validate()?;
    let write_err = |source| MapError::Write {
        path: path.to_path_buf(),
        source,
    };
    let n = mesh.positions.len();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &mesh.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();

    let positions: Vec<u8> = bytemuck::cast_slice(&mesh.positions).to_vec();
    views.push(json!({"buffer": 0, "byteOffset": push_aligned(&mut bin, &positions), "byteLength": positions.len(), "target": 34962}));
    accessors.push(json!({"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3", "min": lo, "max": hi}));
    let colors: Vec<f32> = mesh
        .gray
        .iter()
        .flat_map(|&g| [g.clamp(0.0, 255.0) / 255.0; 3])
        .collect();
    let colors: &[u8] = bytemuck::cast_slice(&colors);
    views.push(json!({"buffer": 0, "byteOffset": push_aligned(&mut bin, colors), "byteLength": colors.len(), "target": 34962}));
    accessors.push(json!({"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"}));
    let mut attributes = json!({"POSITION": 0, "COLOR_0": 1});
    if !mesh.uvs.is_empty() {
        let uvs: &[u8] = bytemuck::cast_slice(&mesh.uvs);
        views.push(json!({"buffer": 0, "byteOffset": push_aligned(&mut bin, uvs), "byteLength": uvs.len(), "target": 34962}));
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126, "count": n, "type": "VEC2"}));
        attributes["TEXCOORD_0"] = json!(2);
    }
    let indices: &[u8] = bytemuck::cast_slice(&mesh.indices);
    let index_view = views.len();
    views.push(json!({"buffer": 0, "byteOffset": push_aligned(&mut bin, indices), "byteLength": indices.len(), "target": 34963}));

    let mut images = Vec::new();
    for (i, texture) in mesh.textures.iter().enumerate() {
        let texels: Vec<u8> = texture
            .texels
            .iter()
            .map(|&t| t.round().clamp(0.0, 255.0) as u8)
            .collect();
        let mut png = Vec::new();
        image::GrayImage::from_raw(texture.width, texture.height, texels)
            .ok_or_else(|| {
                write_err(std::io::Error::other(format!(
                    "texture {i} has the wrong size"
                )))
            })?
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|source| MapError::TextureEncode {
                path: path.to_path_buf(),
                source,
            })?;
        views.push(json!({"buffer": 0, "byteOffset": push_aligned(&mut bin, &png), "byteLength": png.len()}));
        images.push(json!({"bufferView": views.len() - 1, "mimeType": "image/png"}));
    }
    let textures: Vec<_> = (0..mesh.textures.len())
        .map(|i| json!({"source": i, "sampler": 0}))
        .collect();
    // Material 0 is untextured; material 1 + t uses texture t.
    let mut materials = vec![
        json!({"name": "untextured", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0}}),
    ];
    for t in 0..mesh.textures.len() {
        materials.push(json!({"name": format!("tex{t}"), "pbrMetallicRoughness": {"baseColorTexture": {"index": t}, "metallicFactor": 0.0}}));
    }
    let whole = [super::MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: None,
    }];
    let groups = if mesh.groups.is_empty() {
        &whole[..]
    } else {
        &mesh.groups[..]
    };
    let mut primitives = Vec::new();
    for g in groups {
        accessors.push(json!({
            "bufferView": index_view,
            "byteOffset": 4 * g.first_index as usize,
            "componentType": 5125,
            "count": g.index_count,
            "type": "SCALAR"
        }));
        primitives.push(json!({
            "attributes": attributes,
            "indices": accessors.len() - 1,
            "material": g.texture.map_or(0, |t| 1 + t as usize),
            "mode": 4
        }));
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let mut root = json!({
        "asset": {"version": "2.0", "generator": "star"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": primitives}],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    if !images.is_empty() {
        root["images"] = json!(images);
        root["textures"] = json!(textures);
        root["samplers"] =
            json!([{"magFilter": 9729, "minFilter": 9729, "wrapS": 10497, "wrapT": 10497}]);
    }
    let mut json_bytes =
        serde_json::to_vec(&root).map_err(|e| write_err(std::io::Error::other(e)))?;
    while json_bytes.len() % 4 != 0 {
        json_bytes.push(b' ');
    }
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0, // computed by the writer
        },
        json: Cow::Owned(json_bytes),
        bin: Some(Cow::Owned(bin)),
    };
    let bytes = glb
        .to_vec()
        .map_err(|e| write_err(std::io::Error::other(e.to_string())))?;
    std::fs::write(path, bytes).map_err(write_err)?;
    tracing::info!(
        path = %path.display(),
        triangles = mesh.triangle_count(),
        textures = mesh.textures.len(),
        "mesh written"
    );
    Ok(())
}
