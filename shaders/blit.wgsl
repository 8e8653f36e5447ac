// Viewer presentation: draws the tone-mapped frame (an 8-bit texture the size of the window)
// with one full-screen triangle. The texture's format matches the surface's colour encoding
// (Rgba8UnormSrgb for an sRGB surface, Rgba8Unorm otherwise), so values pass through unchanged.

@group(0) @binding(0) var frame: texture_2d<f32>;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // (−1, 1), (3, 1), (−1, −3): a triangle covering the screen.
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    return vec4<f32>(x * 2.0 - 1.0, 1.0 - y * 2.0, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let dims = textureDimensions(frame);
    let xy = min(vec2<u32>(p.xy), dims - vec2<u32>(1u, 1u));
    return vec4<f32>(textureLoad(frame, xy, 0).rgb, 1.0);
}
