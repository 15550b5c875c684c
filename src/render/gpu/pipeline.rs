//! The render pipeline of the wgpu renderer: bind group layouts and the
//! pipeline built from `shaders/mesh.wgsl`.
//!
//! Takes a device; gives out the view uniform layout (group 0: the
//! `clip_from_world` matrix) and the pipeline: triangle lists, drawing both
//! sides or culling back faces (counter-clockwise on the image is the
//! front, as [`crate::map::Mesh::indices`] says), two `R32Float` color targets (gray, metric depth) and a reversed
//! `Depth32Float` z-buffer (`Greater` wins, cleared to 0).

use super::frame::{COLOR_FORMAT, DEPTH_FORMAT};
use super::projection::VIEW_UNIFORM_BYTES;
use super::upload::VERTEX_LAYOUT;

/// The WGSL source of the pipeline.
const SHADER: &str = include_str!("../../../shaders/mesh.wgsl");

/// Layout of group 0: the 64-byte `View` uniform read by the vertex shader
/// ([`super::projection::ViewUniform`]).
pub fn view_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("star view"),
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: wgpu::BufferSize::new(VIEW_UNIFORM_BYTES),
            },
            count: None,
        }],
    })
}

/// The keyframe pipeline for `view_layout` (group 0) and `texture_layout`
/// (group 1); with `cull_back_faces`, triangles clockwise on the image are
/// not drawn.
pub fn create(
    device: &wgpu::Device,
    view_layout: &wgpu::BindGroupLayout,
    texture_layout: &wgpu::BindGroupLayout,
    cull_back_faces: bool,
) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("shaders/mesh.wgsl"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("star keyframe"),
        bind_group_layouts: &[Some(view_layout), Some(texture_layout)],
        immediate_size: 0,
    });
    let target = Some(wgpu::ColorTargetState {
        format: COLOR_FORMAT,
        blend: None,
        write_mask: wgpu::ColorWrites::ALL,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(if cull_back_faces {
            "star keyframe (back faces culled)"
        } else {
            "star keyframe"
        }),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(VERTEX_LAYOUT)],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            front_face: wgpu::FrontFace::Ccw,
            cull_mode: cull_back_faces.then_some(wgpu::Face::Back),
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Greater),
            stencil: wgpu::StencilState::default(),
            bias: wgpu::DepthBiasState::default(),
        }),
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[target.clone(), target],
        }),
        multiview_mask: None,
        cache: None,
    })
}
