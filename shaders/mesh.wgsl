// Keyframe rendering of the gray mesh (render::gpu).
//
// In:  vertex buffer (world position in meters, gray 0..=255, texture uv
//      with v down), `View` uniform (clip_from_world, built on the CPU from
//      the pinhole intrinsics and the pose, see src/render/gpu/projection.rs),
//      one R32Float gray texture per mesh group (a 1x1 texel of 255 for
//      groups without a texture).
// Out: location 0: gray intensity 0..=255 (R32Float);
//      location 1: metric depth, the z coordinate in the camera optical frame
//      (R32Float). The z-buffer (Depth32Float, reversed: greater is nearer)
//      resolves occlusion only.
//
// Texture sampling is bilinear with repeat addressing, done by hand with
// textureLoad: R32Float is not filterable on every adapter, and doing it by
// hand fixes the convention to the CPU rasterizer's (texel centers at
// (i + 0.5) / size in uv).

struct View {
    clip_from_world: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> view: View;
@group(1) @binding(0) var gray_texture: texture_2d<f32>;

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

// Repeat addressing: i modulo n, non-negative.
fn wrap(i: i32, n: i32) -> i32 {
    let r = i % n;
    return select(r, r + n, r < 0);
}

fn texel(x: i32, y: i32, size: vec2<i32>) -> f32 {
    return textureLoad(gray_texture, vec2<i32>(wrap(x, size.x), wrap(y, size.y)), 0).r;
}

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    let size = vec2<i32>(textureDimensions(gray_texture));
    let p = in.uv * vec2<f32>(size) - vec2<f32>(0.5, 0.5);
    let p0 = floor(p);
    let f = p - p0;
    let i = vec2<i32>(p0);
    let top = mix(texel(i.x, i.y, size), texel(i.x + 1, i.y, size), f.x);
    let bottom = mix(texel(i.x, i.y + 1, size), texel(i.x + 1, i.y + 1, size), f.x);
    let tex = mix(top, bottom, f.y);
    var out: FragmentOut;
    out.gray = tex * in.gray / 255.0;
    out.depth_m = in.depth_m;
    return out;
}
