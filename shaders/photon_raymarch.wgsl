// Ray marching of D and J (Elek 2012 §4.4, Appendix C). Mirrors `reference::raymarch_pixel`.
// Front to back with step `P.step` (default: box diagonal / 300), a per-pixel hashed start
// offset against banding, exact per-step attenuation, early exit below `P.early_exit`
// transmittance (2 %). In-scattered radiance at x for view direction ω (propagation):
//   L_s = σ_s(x) [ E_sun J_sun(x) p_HG(ω·ω_sun | g g'(x)) + L_sky J_sky(x) / 4π ],
// i.e. the incident HG lobe of anisotropy g' convolved with the medium's HG(g) (self-convolution
// property). Behind the cloud: the sky radiance and, for a sun disc, the sun.

@group(0) @binding(2) var<storage, read> j_in: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> image: array<vec4<f32>>;

fn j_at(p: vec3<f32>) -> vec4<f32> {
    let t = trilinear(p, P.d_res);
    let r = P.d_res;
    let f = t.f;
    let c00 = mix(j_in[grid_index(t.i0.x, t.i0.y, t.i0.z, r)], j_in[grid_index(t.i1.x, t.i0.y, t.i0.z, r)], f.x);
    let c10 = mix(j_in[grid_index(t.i0.x, t.i1.y, t.i0.z, r)], j_in[grid_index(t.i1.x, t.i1.y, t.i0.z, r)], f.x);
    let c01 = mix(j_in[grid_index(t.i0.x, t.i0.y, t.i1.z, r)], j_in[grid_index(t.i1.x, t.i0.y, t.i1.z, r)], f.x);
    let c11 = mix(j_in[grid_index(t.i0.x, t.i1.y, t.i1.z, r)], j_in[grid_index(t.i1.x, t.i1.y, t.i1.z, r)], f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

@compute @workgroup_size(8, 8)
fn raymarch(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let px = (f32(gid.x) + 0.5) / f32(P.width) * 2.0 - 1.0;
    let py = 1.0 - (f32(gid.y) + 0.5) / f32(P.height) * 2.0;
    let d = normalize(P.cam_forward + P.cam_right * (px * P.tan_half * P.aspect) + P.cam_up * (py * P.tan_half));
    var l = vec3<f32>(0.0);
    var tr = 1.0;
    let hit = box_intersect(P.cam_origin, d);
    if (hit.x <= hit.y) {
        let offset = f32(pcg_hash(gid.y * P.width + gid.x) >> 8u) * (1.0 / 16777216.0);
        var t = hit.x + offset * P.step;
        let mu = dot(d, P.sun_dir);
        let sigma_s_scale = P.albedo * P.density_scale;
        loop {
            if (t >= hit.y || tr < P.early_exit) { break; }
            let dt = min(P.step, hit.y - t);
            let x = P.cam_origin + d * (t + 0.5 * dt);
            let dens = density_at(x);
            let sigma_t = P.density_scale * dens;
            if (sigma_t > 0.0) {
                let jv = j_at(x);
                let ls = sigma_s_scale * dens * (P.sun_irradiance * (jv.x * hg_eval(P.g * jv.z, mu))
                    + P.sky_radiance * (jv.y / (4.0 * PI)));
                let ts = exp(-sigma_t * dt);
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    if (tr >= P.early_exit) {
        var bg = P.sky_radiance;
        if (P.sun_disc_radiance > 0.0 && dot(d, P.sun_dir) >= P.sun_cos_max) {
            bg += P.sun_irradiance * P.sun_disc_radiance;
        }
        l += tr * bg;
    }
    image[gid.y * P.width + gid.x] = vec4<f32>(l, 1.0);
}
