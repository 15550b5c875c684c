// Keyframe rendering of the gray mesh (render::gpu).
//
// In:  vertex buffer (world position in meters, gray 0..=255, texture uv
//      with v down), `View` uniform (clip_from_world, built on the CPU from
//      the pinhole intrinsics and the pose, see src/render/gpu/projection.rs),
//      per mesh group one gray texture holding intensity / 255 (R32Float
//      where the adapter filters it, else R8Unorm; a 1x1 texel of 1.0 for
//      groups without a texture) and a bilinear, repeat-addressed sampler
//      without mipmaps: texel centers at (i + 0.5) / size, as the CPU
//      rasterizer samples.
// Out: location 0: gray intensity 0..=255, texel * vertex gray (R32Float);
//      location 1: metric depth, the z coordinate in the camera optical frame
//      (R32Float). The z-buffer (Depth32Float, reversed: greater is nearer)
//      resolves occlusion only.

struct View {
    clip_from_world: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> view: View;
@group(1) @binding(0) var gray_texture: texture_2d<f32>;
@group(1) @binding(1) var gray_sampler: sampler;

struct VertexIn {
    @location(0) position_m: vec3<f32>,
    @location(1) gray: f32,
    @location(2) uv: vec2<f32>,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) depth_m: f32,
    @location(1) gray: f32,
    @location(2) uv: vec2<f32>,
};

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = view.clip_from_world * vec4<f32>(v.position_m, 1.0);
    // w_clip is z in the camera optical frame; interpolated perspective-
    // correctly it is the exact metric depth of the fragment.
    out.depth_m = out.clip.w;
    out.gray = v.gray;
    out.uv = v.uv;
    return out;
}

struct FragmentOut {
    @location(0) gray: f32,
    @location(1) depth_m: f32,
};

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    // Level 0 always: no mipmaps, and valid in non-uniform control flow.
    let texel = textureSampleLevel(gray_texture, gray_sampler, in.uv, 0.0).r;
    var out: FragmentOut;
    out.gray = texel * in.gray;
    out.depth_m = in.depth_m;
    return out;
}
