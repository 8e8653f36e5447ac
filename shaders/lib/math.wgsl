// Constants and frames shared by the shaders.

const PI: f32 = 3.14159265358979;

// A unit vector at cosine `mu` and azimuth `phi` around `axis` (Duff et al. 2017 frame).
fn around(axis: vec3<f32>, mu: f32, phi: f32) -> vec3<f32> {
    let sign = select(-1.0, 1.0, axis.z >= 0.0);
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    let t = vec3<f32>(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x);
    let bb = vec3<f32>(b, sign + axis.y * axis.y * a, -axis.y);
    let st = sqrt(max(0.0, 1.0 - mu * mu));
    return normalize(t * (st * cos(phi)) + bb * (st * sin(phi)) + axis * mu);
}
