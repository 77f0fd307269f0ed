// The 3D view's picture copied into egui's pass, texel for pixel: no blending, no gamma round trip, no sampler
// (egui's own image shader converts every pixel to gamma and back and blends it, which a CPU renderer pays for
// over the whole view). The viewport is the picture's rectangle; one triangle covers it.
@group(0) @binding(0) var picture: texture_2d<f32>;

struct VertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) uv: vec2<f32>,
}

@vertex
fn vertex(@builtin(vertex_index) index: u32) -> VertexOutput {
    let uv = vec2<f32>(f32((index << 1u) & 2u), f32(index & 2u));
    return VertexOutput(vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 0.0, 1.0), uv);
}

@fragment
fn fragment(in: VertexOutput) -> @location(0) vec4<f32> {
    let size = vec2<f32>(textureDimensions(picture));
    let texel = clamp(vec2<i32>(in.uv * size), vec2<i32>(0), vec2<i32>(size) - 1);
    return textureLoad(picture, texel, 0);
}
