// Draws the encoded panel frame (RGBA8 code values, one texel per panel
// pixel) onto a render target with nearest-pixel scaling: a panel-sized
// target shows every code value unchanged. The target format must be a
// non-sRGB unorm format: the codes are already encoded by the panel's
// transfer curve (runtime/service/src/present/transfer.rs).

@group(0) @binding(0) var panel: texture_2d<f32>;

struct VertexOut {
    @builtin(position) position: vec4<f32>,
}

// One triangle covering the viewport.
@vertex
fn vs_main(@builtin(vertex_index) index: u32) -> VertexOut {
    let uv = vec2<f32>(f32((index << 1u) & 2u), f32(index & 2u));
    var out: VertexOut;
    out.position = vec4<f32>(uv * 2.0 - 1.0, 0.0, 1.0);
    return out;
}

struct Target {
    size: vec2<f32>,
}
@group(0) @binding(1) var<uniform> target_size: Target;

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let dims = vec2<f32>(textureDimensions(panel));
    let texel = vec2<i32>(floor(in.position.xy * dims / target_size.size));
    let clamped = clamp(texel, vec2<i32>(0), vec2<i32>(dims) - 1);
    return textureLoad(panel, clamped, 0);
}
