// A lat-long environment map's radiance along a direction, as `nimbus_scene::EnvMap::radiance`
// reads it (the nearest texel; u from atan2(x, −z), v from acos(y), the first row at the
// zenith). The importing stage declares `env: array<vec4<f32>>`: the texels, RGB × the map's
// scale, `w` × `h`, rows from the zenith. Used by the GPU path tracer (`pt_core`) and the RPNN
// sample (`rpnn_sample_core`).
#import math

fn env_radiance(d: vec3<f32>, w: u32, h: u32) -> vec3<f32> {
    let u = atan2(d.x, -d.z) / (2.0 * PI) + 0.5;
    let v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    let x = min(u32(max(u, 0.0) * f32(w)), w - 1u);
    let y = min(u32(max(v, 0.0) * f32(h)), h - 1u);
    return env[y * w + x].xyz;
}
