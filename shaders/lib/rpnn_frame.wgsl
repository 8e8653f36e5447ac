// The RPNN's local frame of a shading configuration (Kallweit 2017 §4.2): z towards the light,
// x ⟂ the view (a fixed tangent of z when the view is parallel to it), y = z × x. Mirrors
// `nimbus_rpnn::descriptor::frame`. Imported by the descriptor stage and the whole-sample
// renderer's contraction of the sky head (`rpnn_sample_core`).

fn basis_t(n: vec3<f32>) -> vec3<f32> {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    return vec3<f32>(1.0 + sign * n.x * n.x * a, sign * n.x * n.y * a, -sign * n.x);
}

// Columns x, y, z (local → world) for the view direction and the direction to the light.
fn rpnn_frame(view_dir: vec3<f32>, to_light: vec3<f32>) -> mat3x3<f32> {
    let view = normalize(view_dir);
    let z = normalize(to_light);
    let cr = cross(z, view);
    var x: vec3<f32>;
    if (length(cr) < 1.0e-6) { x = normalize(basis_t(z)); } else { x = normalize(cr); }
    return mat3x3<f32>(x, cross(z, x), z);
}
