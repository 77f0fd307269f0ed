// The 3D view's one material: a colour times a texture (white when none), unlit, or shaded by a fixed light when
// `shade.x` is 1. Cheap on purpose: under software rendering the view's cost is its fragment shader.
#import bevy_pbr::forward_io::VertexOutput

struct ViewMaterial {
    color: vec4<f32>,
    shade: vec4<f32>,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> material: ViewMaterial;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var base_texture: texture_2d<f32>;
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var base_sampler: sampler;

@fragment
fn fragment(in: VertexOutput) -> @location(0) vec4<f32> {
#ifdef VERTEX_UVS_A
    var c = material.color * textureSample(base_texture, base_sampler, in.uv);
#else
    var c = material.color;
#endif
    if material.shade.x > 0.5 {
        // light from above and behind the viewer's left: half ambient, half Lambert
        let n = normalize(in.world_normal);
        let l = normalize(vec3<f32>(-0.4, 0.8, 0.45));
        c = vec4<f32>(c.rgb * (0.45 + 0.55 * max(dot(n, l), 0.0)), c.a);
    }
    return c;
}
