// Lookups in the photon map's light volumes at light resolution (`P.light_res`, from the light
// bricks' pools: `lib/light_bricks.wgsl`): J (upsampled fluences or view-dependent
// in-scattering, `photon_upsample.wgsl`), the sun transmittance T_sun, and the flux lobes of
// Elek 2012 Appendix C, each trilinear. Shared by the ray marcher (`photon_raymarch_core`) and
// the final gathering (`photon_gather_core`), which declare P and the density.
#import params
#import grid
#import light_bricks
#import hg

@group(0) @binding(2) var<storage, read> j_in: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> t_sun: array<f32>;
// Per density voxel (flux axes only): the upsampled mean propagation vector of the low-order
// (or, without a split, all) sun light with the high-order fluence, and that of the high-order
// sun light (photon_upsample.wgsl).
@group(0) @binding(5) var<storage, read> j_dir: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> j_hi: array<vec4<f32>>;
// The light bricks' index and slots (`lib/light_bricks.wgsl`).
@group(0) @binding(9) var<storage, read> light_map: array<u32>;

// The eight pool entries (`lib/light_bricks.wgsl`) of a trilinear lookup in the light
// volumes at p, and its weights: found once per step, read by J, T_sun and the flux lobes.
struct Corners {
    i000: u32, i100: u32, i010: u32, i110: u32,
    i001: u32, i101: u32, i011: u32, i111: u32,
    f: vec3<f32>,
};

fn light_corners(p: vec3<f32>) -> Corners {
    let t = trilinear(p, P.light_res);
    return Corners(
        light_at(t.i0.x, t.i0.y, t.i0.z), light_at(t.i1.x, t.i0.y, t.i0.z),
        light_at(t.i0.x, t.i1.y, t.i0.z), light_at(t.i1.x, t.i1.y, t.i0.z),
        light_at(t.i0.x, t.i0.y, t.i1.z), light_at(t.i1.x, t.i0.y, t.i1.z),
        light_at(t.i0.x, t.i1.y, t.i1.z), light_at(t.i1.x, t.i1.y, t.i1.z),
        t.f);
}

fn interp_dir(c: Corners, hi: bool) -> vec4<f32> {
    let f = c.f;
    if (hi) {
        let c00 = mix(j_hi[c.i000], j_hi[c.i100], f.x);
        let c10 = mix(j_hi[c.i010], j_hi[c.i110], f.x);
        let c01 = mix(j_hi[c.i001], j_hi[c.i101], f.x);
        let c11 = mix(j_hi[c.i011], j_hi[c.i111], f.x);
        return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
    }
    let c00 = mix(j_dir[c.i000], j_dir[c.i100], f.x);
    let c10 = mix(j_dir[c.i010], j_dir[c.i110], f.x);
    let c01 = mix(j_dir[c.i001], j_dir[c.i101], f.x);
    let c11 = mix(j_dir[c.i011], j_dir[c.i111], f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

// HG(ω | g·|v|) for a lobe v (axis × g') seen along the camera ray d: light along v scattered
// towards the camera (−d).
fn lobe_phase(v: vec3<f32>, d: vec3<f32>) -> f32 {
    let gl = length(v);
    var mu = 0.0;
    if (gl > 1.0e-6) { mu = dot(-d, v / gl); }
    return hg_eval(P.g * min(gl, 0.999), mu);
}

// Sun fluence per unit irradiance times the phase of its lobes towards the camera: one lobe
// along the sun with J's g' (the paper), or per-cell flux lobes — one for all orders, or one
// for the low and one for the high orders (`P.lobe_split`).
fn sun_in_scatter(c: Corners, jv: vec4<f32>, d: vec3<f32>) -> f32 {
    if (P.lobe_axis == 0u) { return jv.x * lobe_phase(-P.sun_dir * jv.z, d); }
    let lo = interp_dir(c, false);
    if (P.lobe_split == 0u) { return jv.x * lobe_phase(lo.xyz, d); }
    let hi = interp_dir(c, true);
    let f_hi = clamp(lo.w, 0.0, jv.x);
    return (jv.x - f_hi) * lobe_phase(lo.xyz, d) + f_hi * lobe_phase(hi.xyz, d);
}

fn t_sun_at(c: Corners) -> f32 {
    let f = c.f;
    let c00 = mix(t_sun[c.i000], t_sun[c.i100], f.x);
    let c10 = mix(t_sun[c.i010], t_sun[c.i110], f.x);
    let c01 = mix(t_sun[c.i001], t_sun[c.i101], f.x);
    let c11 = mix(t_sun[c.i011], t_sun[c.i111], f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

fn j_at(c: Corners) -> vec4<f32> {
    let f = c.f;
    let c00 = mix(j_in[c.i000], j_in[c.i100], f.x);
    let c10 = mix(j_in[c.i010], j_in[c.i110], f.x);
    let c01 = mix(j_in[c.i001], j_in[c.i101], f.x);
    let c11 = mix(j_in[c.i011], j_in[c.i111], f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}
