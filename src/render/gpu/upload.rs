//! Mesh upload for the wgpu renderer: done once, at construction.
//!
//! Takes a [`Mesh`], its [`ChunkedMesh`] and a device; checks that the mesh
//! is safe to draw ([`Mesh::validate`], and sizes within the adapter's
//! limits) and gives out [`GpuMesh`]: the chunked mesh as an interleaved
//! vertex buffer and a `u32` index buffer (or, when they exceed the GPU
//! budget, a [`StreamPool`] of chunk slots), one texture (see
//! [`TextureFormat`]) and bind group per mesh texture, a bilinear repeat
//! sampler, and the chunks to draw (box, index range and bind group each),
//! from which each render picks those in the view frustum.

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::occlusion::GpuOcclusion;
use super::stream::{self, StreamPlan, StreamPool};
use super::GpuError;
use crate::map::Mesh;
use crate::render::chunks::{ChunkedMesh, MeshChunk, NO_GROUP};

/// One vertex as the shader reads it (`VertexIn` in `shaders/mesh.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuVertex {
    /// World position, meters.
    pub position_m: [f32; 3],
    /// Gray intensity, 0..=255.
    pub gray: f32,
    /// Texture coordinates, v down.
    pub uv: [f32; 2],
}

/// The vertex buffer layout matching [`GpuVertex`].
pub const VERTEX_LAYOUT: wgpu::VertexBufferLayout<'static> = wgpu::VertexBufferLayout {
    array_stride: std::mem::size_of::<GpuVertex>() as wgpu::BufferAddress,
    step_mode: wgpu::VertexStepMode::Vertex,
    attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32, 2 => Float32x2],
};

/// The mesh's vertex and index data on the device.
#[derive(Debug)]
pub enum Geometry {
    /// All of it, uploaded once.
    Resident {
        /// Interleaved [`GpuVertex`] data.
        vertices: wgpu::Buffer,
        /// Triangle indices, `u32`.
        indices: wgpu::Buffer,
    },
    /// A pool of chunk slots filled per render.
    Streamed(Box<StreamPool>),
}

/// The mesh as it lives on the device.
#[derive(Debug)]
pub struct GpuMesh {
    /// Vertices and indices.
    pub geometry: Geometry,
    /// Bind groups (group 1): one per mesh texture, then a 1x1 white texel
    /// used by untextured groups.
    pub texture_groups: Vec<wgpu::BindGroup>,
    /// The chunks, in index-buffer order (mesh group order).
    pub chunks: Vec<MeshChunk>,
    /// Which chunks are coarse copies of which ([`crate::render::lod`]).
    pub lod: crate::render::lod::LodTable,
    /// Per chunk, its bind group in `texture_groups`, or `None` when it is
    /// not drawn (triangles outside every group of a mesh with groups).
    pub chunk_texture: Vec<Option<usize>>,
    /// Bytes of the vertex and index buffers (the slot pool when streamed).
    pub buffer_bytes: u64,
    /// Bytes the vertex and index buffers take when wholly resident.
    pub resident_bytes: u64,
    /// Bytes of the textures.
    pub texture_bytes: u64,
    /// The clusters and scratch of the occlusion cull, for a resident
    /// mesh (a streamed one is drawn with the frustum cull only).
    pub occlusion: Option<GpuOcclusion>,
    /// Kept alive for the bind groups.
    _textures: Vec<wgpu::Texture>,
}

/// The layout of the texture bind group (group 1).
pub fn texture_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("star gray texture"),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: true },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 1,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                count: None,
            },
        ],
    })
}

/// Bytes of the vertex and index buffers of `chunked` when wholly
/// resident (an empty buffer is padded to one element).
fn resident_bytes(chunked: &ChunkedMesh) -> (u64, u64) {
    let vertex_bytes = (chunked.positions.len().max(1) * std::mem::size_of::<GpuVertex>()) as u64;
    let index_bytes = (chunked.indices.len().max(3) * 4) as u64;
    (vertex_bytes, index_bytes)
}

/// Checks `mesh` with [`Mesh::validate`] (indices in range, attributes,
/// groups, textures) and splits it into chunks; decides whether its
/// vertex and index data fit `budget_bytes` (0: no budget) or must stream
/// (see [`stream::plan`]), with coarse copies of runs of its chunks
/// when `levels` ([`crate::render::lod`]); fails when the buffers to allocate exceed the
/// adapter's `limits`, or the budget cannot hold one chunk.
pub fn validate(
    mesh: &Mesh,
    limits: &wgpu::Limits,
    budget_bytes: u64,
    levels: bool,
) -> Result<(ChunkedMesh, Option<StreamPlan>), GpuError> {
    mesh.validate()?;
    let chunked = ChunkedMesh::build_with_levels(mesh, levels)
        .map_err(|e| GpuError::Chunks(e.to_string()))?;
    let max = limits.max_texture_dimension_2d;
    for (t, texture) in mesh.textures.iter().enumerate() {
        if texture.width > max || texture.height > max {
            return Err(GpuError::TextureTooLarge {
                texture: t,
                width: texture.width,
                height: texture.height,
                max_dimension: max,
            });
        }
    }
    let (vertex_bytes, index_bytes) = resident_bytes(&chunked);
    let plan = stream::plan(
        &chunked.chunks,
        vertex_bytes + index_bytes,
        budget_bytes,
        limits.max_buffer_size,
    )?;
    if plan.is_none() {
        for bytes in [vertex_bytes, index_bytes] {
            if bytes > limits.max_buffer_size {
                return Err(GpuError::MeshTooLarge {
                    bytes,
                    max_bytes: limits.max_buffer_size,
                });
            }
        }
    }
    Ok((chunked, plan))
}

/// How mesh textures are stored. Both are sampled by the hardware sampler
/// (bilinear, repeat) and hold intensity / 255, so the shader multiplies by
/// the vertex gray (0..=255).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextureFormat {
    /// `R32Float`, exact; needs `Features::FLOAT32_FILTERABLE`.
    Float32,
    /// `R8Unorm`, filterable everywhere; texels rounded to whole gray levels.
    Unorm8,
}

impl TextureFormat {
    /// `Float32` where the adapter can filter it, else `Unorm8`.
    pub fn for_features(features: wgpu::Features) -> Self {
        if features.contains(wgpu::Features::FLOAT32_FILTERABLE) {
            Self::Float32
        } else {
            Self::Unorm8
        }
    }

    fn wgpu(self) -> wgpu::TextureFormat {
        match self {
            Self::Float32 => wgpu::TextureFormat::R32Float,
            Self::Unorm8 => wgpu::TextureFormat::R8Unorm,
        }
    }
}

/// Texel bytes for `format`: intensity (0..=255) / 255 as f32, or rounded
/// to u8.
fn texel_bytes(format: TextureFormat, texels: &[f32]) -> Vec<u8> {
    match format {
        TextureFormat::Float32 => texels
            .iter()
            .flat_map(|t| (t / 255.0).to_ne_bytes())
            .collect(),
        TextureFormat::Unorm8 => texels
            .iter()
            .map(|t| t.round().clamp(0.0, 255.0) as u8)
            .collect(),
    }
}

fn upload_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    format: TextureFormat,
    width: u32,
    height: u32,
    texels: &[f32],
) -> wgpu::Texture {
    let size = wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: 1,
    };
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("star mesh texture"),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: format.wgpu(),
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let bytes_per_texel = match format {
        TextureFormat::Float32 => 4,
        TextureFormat::Unorm8 => 1,
    };
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &texel_bytes(format, texels),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(width * bytes_per_texel),
            rows_per_image: Some(height),
        },
        size,
    );
    texture
}

/// Uploads `mesh` as `chunked`, the chunks [`validate`] gave out: its
/// vertices and indices whole when `plan` is `None`, else a slot pool of
/// that shape, empty, and the host data to fill it from.
pub fn upload(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    layout: &wgpu::BindGroupLayout,
    format: TextureFormat,
    mesh: &Mesh,
    chunked: ChunkedMesh,
    plan: Option<StreamPlan>,
) -> GpuMesh {
    let vertices: Vec<GpuVertex> = chunked
        .positions
        .iter()
        .zip(&chunked.gray)
        .enumerate()
        .map(|(i, (&position_m, &gray))| GpuVertex {
            position_m,
            gray,
            uv: chunked.uvs.get(i).copied().unwrap_or([0.0; 2]),
        })
        .collect();
    let (vertex_bytes, index_bytes) = resident_bytes(&chunked);
    let geometry = match plan {
        Some(plan) => {
            Geometry::Streamed(Box::new(StreamPool::new(device, plan, vertices, &chunked)))
        }
        None => {
            // wgpu buffers may not be empty: pad an empty mesh with one dummy element.
            let dummy_vertex = [GpuVertex::zeroed()];
            let vertex_data: &[GpuVertex] = if vertices.is_empty() {
                &dummy_vertex
            } else {
                &vertices
            };
            let index_data: &[u32] = if chunked.indices.is_empty() {
                &[0, 0, 0]
            } else {
                &chunked.indices
            };
            Geometry::Resident {
                vertices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("star mesh vertices"),
                    contents: bytemuck::cast_slice(vertex_data),
                    usage: wgpu::BufferUsages::VERTEX,
                }),
                indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("star mesh indices"),
                    contents: bytemuck::cast_slice(index_data),
                    usage: wgpu::BufferUsages::INDEX,
                }),
            }
        }
    };

    let mut textures: Vec<wgpu::Texture> = mesh
        .textures
        .iter()
        .map(|t| upload_texture(device, queue, format, t.width, t.height, &t.texels))
        .collect();
    let white = textures.len();
    // Bilinear with repeat addressing and no mipmaps, as the CPU rasterizer.
    let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("star mesh texture"),
        address_mode_u: wgpu::AddressMode::Repeat,
        address_mode_v: wgpu::AddressMode::Repeat,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        ..Default::default()
    });
    textures.push(upload_texture(device, queue, format, 1, 1, &[255.0]));
    let texture_groups = textures
        .iter()
        .map(|texture| {
            let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("star mesh texture"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::Sampler(&sampler),
                    },
                ],
            })
        })
        .collect();

    // Without groups every triangle is drawn, untextured; with groups,
    // only the grouped ones.
    let chunk_texture: Vec<Option<usize>> = chunked
        .chunks
        .iter()
        .map(|c| match mesh.groups.get(c.group as usize) {
            Some(g) => Some(g.texture.map_or(white, |t| t as usize)),
            None if mesh.groups.is_empty() && c.group == NO_GROUP => Some(white),
            None => None,
        })
        .collect();
    let occlusion = match &geometry {
        Geometry::Resident { .. } => Some(GpuOcclusion::new(&chunked, &chunk_texture)),
        Geometry::Streamed(_) => None,
    };

    let texture_bytes = textures
        .iter()
        .map(|t| {
            let per_texel = match format {
                TextureFormat::Float32 => 4,
                TextureFormat::Unorm8 => 1,
            };
            u64::from(t.width()) * u64::from(t.height()) * per_texel
        })
        .sum();
    let buffer_bytes = match &geometry {
        Geometry::Resident { vertices, indices } => vertices.size() + indices.size(),
        Geometry::Streamed(pool) => pool.bytes(),
    };
    GpuMesh {
        buffer_bytes,
        resident_bytes: vertex_bytes + index_bytes,
        texture_bytes,
        geometry,
        texture_groups,
        chunks: chunked.chunks,
        lod: chunked.lod,
        chunk_texture,
        occlusion,
        _textures: textures,
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::map::{GrayTexture, MeshGroup};

    fn triangle() -> Mesh {
        Mesh {
            positions: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
            gray: vec![1.0; 3],
            uvs: vec![[0.0, 0.0]; 3],
            indices: vec![0, 1, 2],
            groups: vec![MeshGroup {
                first_index: 0,
                index_count: 3,
                texture: None,
            }],
            textures: Vec::new(),
        }
    }

    #[test]
    fn texels_are_stored_as_fraction_of_255() {
        let f = texel_bytes(TextureFormat::Float32, &[0.0, 127.5, 255.0]);
        let back: Vec<f32> = f
            .chunks_exact(4)
            .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(back, vec![0.0, 0.5, 1.0]);
        let u = texel_bytes(TextureFormat::Unorm8, &[-3.0, 12.4, 12.6, 300.0]);
        assert_eq!(u, vec![0, 12, 13, 255]);
        assert_eq!(
            TextureFormat::for_features(wgpu::Features::empty()),
            TextureFormat::Unorm8
        );
        assert_eq!(
            TextureFormat::for_features(wgpu::Features::FLOAT32_FILTERABLE),
            TextureFormat::Float32
        );
    }

    #[test]
    fn rejects_bad_meshes_without_panicking() {
        let limits = wgpu::Limits::default();
        assert!(validate(&triangle(), &limits, 0, false).is_ok());
        let mut bad = triangle();
        bad.indices[2] = 7;
        let err = validate(&bad, &limits, 0, false).expect_err("index out of range");
        assert!(err.to_string().contains('7'), "{err}");
        let mut big = triangle();
        big.textures = vec![GrayTexture {
            width: limits.max_texture_dimension_2d + 1,
            height: 1,
            texels: vec![0.0; limits.max_texture_dimension_2d as usize + 1],
        }];
        big.groups[0].texture = Some(0);
        assert!(matches!(
            validate(&big, &limits, 0, false),
            Err(GpuError::TextureTooLarge { .. })
        ));
        let tiny = wgpu::Limits {
            max_buffer_size: 16,
            ..wgpu::Limits::default()
        };
        assert!(matches!(
            validate(&triangle(), &tiny, 0, false),
            Err(GpuError::MeshTooLarge { .. })
        ));
    }
}
