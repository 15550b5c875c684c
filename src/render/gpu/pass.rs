//! One render pass of the wgpu renderer.
//!
//! Takes the frame's targets, the pipeline with its bind groups, the
//! vertex and index buffers to draw from (the resident mesh or the slot
//! pool) and a draw list; records the pass into a command encoder. The
//! first pass of a render clears the targets, later ones (a streamed view
//! drawn in several passes) load them, so several passes draw the image
//! one would.

use super::draws::Draw;
use super::frame::FrameTargets;

/// What one render pass draws with.
pub struct PassInputs<'a> {
    /// The keyframe pipeline.
    pub pipeline: &'a wgpu::RenderPipeline,
    /// Group 0, the view uniform.
    pub view_group: &'a wgpu::BindGroup,
    /// Group 1 per texture, as [`Draw::texture`] numbers them.
    pub texture_groups: &'a [wgpu::BindGroup],
    /// Vertices to draw from.
    pub vertices: &'a wgpu::Buffer,
    /// `u32` indices to draw from.
    pub indices: &'a wgpu::Buffer,
}

/// Records one render pass of `draws` into `frame`'s targets. The `first`
/// pass of a render clears gray, depth and the z-buffer, later ones load
/// them; every pass but the `last` keeps the z-buffer for the next.
pub fn record_pass(
    encoder: &mut wgpu::CommandEncoder,
    frame: &FrameTargets,
    inputs: &PassInputs,
    draws: &[Draw],
    first: bool,
    last: bool,
) {
    let color = |view| {
        Some(wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: if first {
                    wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT)
                } else {
                    wgpu::LoadOp::Load
                },
                store: wgpu::StoreOp::Store,
            },
        })
    };
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("star keyframe"),
        color_attachments: &[color(&frame.gray_view), color(&frame.depth_view)],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &frame.zbuffer_view,
            depth_ops: Some(wgpu::Operations {
                // Reversed depth: 0 is infinitely far.
                load: if first {
                    wgpu::LoadOp::Clear(0.0)
                } else {
                    wgpu::LoadOp::Load
                },
                store: if last {
                    wgpu::StoreOp::Discard
                } else {
                    wgpu::StoreOp::Store
                },
            }),
            stencil_ops: None,
        }),
        ..Default::default()
    });
    pass.set_pipeline(inputs.pipeline);
    pass.set_bind_group(0, inputs.view_group, &[]);
    pass.set_vertex_buffer(0, inputs.vertices.slice(..));
    pass.set_index_buffer(inputs.indices.slice(..), wgpu::IndexFormat::Uint32);
    let mut bound = None;
    for draw in draws {
        let Some(group) = inputs.texture_groups.get(draw.texture) else {
            continue;
        };
        if bound != Some(draw.texture) {
            pass.set_bind_group(1, group, &[]);
            bound = Some(draw.texture);
        }
        pass.draw_indexed(draw.indices.clone(), draw.base_vertex, 0..1);
    }
}
