// Hierarchical stencil descriptor (Kallweit 2017 §4.2), one invocation per output float.
// Mirrors crates/rpnn/src/descriptor.rs (layout, frame, lookups) in the same f32 arithmetic.
// Imports the shared constants (stencil size, workgroup size) and the local frame.
//
// Rows: min(D.n_configs, count[0]); the whole-sample renderer's count is written on the GPU
// by its shading pass, other callers bind 0xffffffff.
#import constants
#import rpnn_frame

struct DescParams {
    aabb_min: vec3<f32>, mfp: f32,
    aabb_max: vec3<f32>, n_configs: u32,
    // Pyramid level read by stencil levels 1..10 (packed 4 per vec4).
    level_of: array<vec4<u32>, 3>,
};

struct LevelInfo { res: vec3<u32>, offset: u32 };

struct Config { x: vec4<f32>, view: vec4<f32>, to_light: vec4<f32> };

@group(0) @binding(0) var<uniform> D: DescParams;
@group(0) @binding(1) var<storage, read> levels: array<f32>;
@group(0) @binding(2) var<storage, read> level_info: array<LevelInfo>;
@group(0) @binding(3) var<storage, read> configs: array<Config>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;
@group(0) @binding(5) var<storage, read> count: array<u32>;

fn lookup(li: u32, p: vec3<f32>) -> f32 {
    if (!(all(p >= D.aabb_min) && all(p <= D.aabb_max))) { return 0.0; }
    let info = level_info[li];
    let resf = vec3<f32>(info.res);
    let u = (p - D.aabb_min) / (D.aabb_max - D.aabb_min) * resf - vec3<f32>(0.5);
    let b = floor(u);
    let f = u - b;
    let hi = resf - vec3<f32>(1.0);
    let i0 = vec3<u32>(clamp(b, vec3<f32>(0.0), hi));
    let i1 = vec3<u32>(clamp(b + vec3<f32>(1.0), vec3<f32>(0.0), hi));
    let r = info.res;
    let o = info.offset;
    let c000 = levels[o + (i0.z * r.y + i0.y) * r.x + i0.x];
    let c100 = levels[o + (i0.z * r.y + i0.y) * r.x + i1.x];
    let c010 = levels[o + (i0.z * r.y + i1.y) * r.x + i0.x];
    let c110 = levels[o + (i0.z * r.y + i1.y) * r.x + i1.x];
    let c001 = levels[o + (i1.z * r.y + i0.y) * r.x + i0.x];
    let c101 = levels[o + (i1.z * r.y + i0.y) * r.x + i1.x];
    let c011 = levels[o + (i1.z * r.y + i1.y) * r.x + i0.x];
    let c111 = levels[o + (i1.z * r.y + i1.y) * r.x + i1.x];
    let c00 = c000 * (1.0 - f.x) + c100 * f.x;
    let c10 = c010 * (1.0 - f.x) + c110 * f.x;
    let c01 = c001 * (1.0 - f.x) + c101 * f.x;
    let c11 = c011 * (1.0 - f.x) + c111 * f.x;
    let c0 = c00 * (1.0 - f.y) + c10 * f.y;
    let c1 = c01 * (1.0 - f.y) + c11 * f.y;
    return c0 * (1.0 - f.z) + c1 * f.z;
}

@compute @workgroup_size(WG)
fn descriptor(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * WG;
    let c = i / DESCRIPTOR_LEN;
    if (c >= min(D.n_configs, count[0])) { return; }
    let j = i % DESCRIPTOR_LEN;
    let cfg = configs[c];
    let view = normalize(cfg.view.xyz);
    let z = normalize(cfg.to_light.xyz);
    if (j == DESCRIPTOR_LEN - 1u) {
        out[i] = atan2(length(cross(view, z)), dot(view, z));
        return;
    }
    let f = rpnn_frame(view, z);
    let x = f[0];
    let y = f[1];
    let k = j / STENCIL_POINTS;          // 0-based stencil level
    let p = j % STENCIL_POINTS;
    let s = vec3<f32>(-1.0 + f32(p % 5u) * 0.5, -1.0 + f32((p / 5u) % 5u) * 0.5, -1.0 + f32(p / 25u) * 0.5);
    let scale = f32(1u << k) * D.mfp;
    let q = cfg.x.xyz + (x * s.x + y * s.y + z * s.z) * scale;
    out[i] = lookup(D.level_of[k / 4u][k % 4u], q);
}
