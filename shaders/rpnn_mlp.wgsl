// One fully connected layer of the RPNN (Kallweit 2017 §4.3) for a batch of queries, as a tiled
// matrix product in workgroup memory:
//
//   out[r, j] = act( b[j] + Σ_i Wa[j, i] a(r, i) + Σ_i Wb[j, i] b(r, i) + res[r, j] )
//
// a(r, ·) is the block's stencil level and γ read straight from the descriptor batch (columns
// a_offset … a_offset + ka − 2, then column a_gamma_col) or a previous activation; b(r, ·) is an
// optional second activation (W1 o_{k−1}); res is the optional residual o_{k−1}; act is ReLU.
// The layers of a block: F1 = ReLU(V z_k + b1 + W1 o_{k−1}), o_k = ReLU(W2 F1 + b2 + o_{k−1});
// head layers: ReLU(W x + b); the sky head's (`nimbus_rpnn::sky`) last layer is W x + b (relu 0)
// and writes its columns after the sun head's (out_offset). The CPU reference is
// `nimbus_rpnn::model::Rpnn::forward`.
//
// Rows: min(L.rows, row_limit[0]). A batch whose size only the GPU knows (the whole-sample
// renderer's compacted queries, `nimbus_rpnn::gpu_sample`) is dispatched for L.rows and
// workgroups past the count return at once; other callers bind a limit of 0xffffffff.
//
// Tiles: 64 queries × 64 outputs per workgroup of 16 × 16 threads, k-slices of 16 inputs in
// workgroup memory; each thread accumulates a 4 × 4 block in four vec4 registers (named
// variables: private arrays indexed in loops are far slower on some drivers).

struct Layer {
    rows: u32,
    outputs: u32,
    ka: u32,
    kb: u32,
    a_stride: u32,
    a_offset: u32,
    a_gamma_col: u32,   // 0xffffffff: no γ column (a is a plain activation)
    b_stride: u32,
    wa_offset: u32,
    wb_offset: u32,
    bias_offset: u32,
    out_stride: u32,
    residual: u32,
    res_stride: u32,
    relu: u32,
    out_offset: u32,
};

@group(0) @binding(0) var<uniform> L: Layer;
@group(0) @binding(1) var<storage, read> weights: array<f32>;
@group(0) @binding(2) var<storage, read> a_buf: array<f32>;
@group(0) @binding(3) var<storage, read> b_buf: array<f32>;
@group(0) @binding(4) var<storage, read> res_buf: array<f32>;
@group(0) @binding(5) var<storage, read_write> out_buf: array<f32>;
@group(0) @binding(6) var<storage, read> row_limit: array<u32>;

const NO_GAMMA: u32 = 0xffffffffu;

var<workgroup> a_tile: array<vec4<f32>, 256>; // [k 16][row group 16] × 4 rows
var<workgroup> w_tile: array<vec4<f32>, 256>; // [k 16][output group 16] × 4 outputs
var<workgroup> wg_rows: u32;
var<private> rows: u32;

// Input i of query r (i < ka: from a, else from b).
fn input(r: u32, i: u32) -> f32 {
    if (r >= rows) {
        return 0.0;
    }
    if (i < L.ka) {
        var col = L.a_offset + i;
        if (L.a_gamma_col != NO_GAMMA && i == L.ka - 1u) {
            col = L.a_gamma_col;
        }
        return a_buf[r * L.a_stride + col];
    }
    let k = i - L.ka;
    if (k < L.kb) {
        return b_buf[r * L.b_stride + k];
    }
    return 0.0;
}

// Weight of input i for output j.
fn weight(j: u32, i: u32) -> f32 {
    if (j >= L.outputs) {
        return 0.0;
    }
    if (i < L.ka) {
        return weights[L.wa_offset + j * L.ka + i];
    }
    let k = i - L.ka;
    if (k < L.kb) {
        return weights[L.wb_offset + j * L.kb + k];
    }
    return 0.0;
}

fn finish(r: u32, j: u32, v: f32) {
    if (r >= rows || j >= L.outputs) {
        return;
    }
    var s = v + weights[L.bias_offset + j];
    if (L.residual != 0u) {
        s += res_buf[r * L.res_stride + j];
    }
    if (L.relu != 0u) {
        s = max(s, 0.0);
    }
    out_buf[r * L.out_stride + L.out_offset + j] = s;
}

@compute @workgroup_size(16, 16)
fn dense(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let j0 = wg.x * 64u;
    let r0 = wg.y * 64u;
    let tx = lid.x; // output group
    let ty = lid.y; // row group
    let t = ty * 16u + tx;
    if (t == 0u) {
        wg_rows = min(L.rows, row_limit[0]);
    }
    rows = workgroupUniformLoad(&wg_rows);
    if (r0 >= rows) {
        return;
    }
    let lk = t / 16u;
    let lg = t % 16u;
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    let k_total = L.ka + L.kb;
    for (var k0 = 0u; k0 < k_total; k0 += 16u) {
        let kk = k0 + lk;
        let rr = r0 + lg * 4u;
        a_tile[lk * 16u + lg] = vec4<f32>(
            input(rr, kk), input(rr + 1u, kk), input(rr + 2u, kk), input(rr + 3u, kk));
        let jj = j0 + lg * 4u;
        w_tile[lk * 16u + lg] = vec4<f32>(
            weight(jj, kk), weight(jj + 1u, kk), weight(jj + 2u, kk), weight(jj + 3u, kk));
        workgroupBarrier();
        for (var k = 0u; k < 16u; k++) {
            let a = a_tile[k * 16u + ty];
            let w = w_tile[k * 16u + tx];
            acc0 += a.x * w;
            acc1 += a.y * w;
            acc2 += a.z * w;
            acc3 += a.w * w;
        }
        workgroupBarrier();
    }
    let r = r0 + ty * 4u;
    let j = j0 + tx * 4u;
    finish(r, j, acc0.x);
    finish(r, j + 1u, acc0.y);
    finish(r, j + 2u, acc0.z);
    finish(r, j + 3u, acc0.w);
    finish(r + 1u, j, acc1.x);
    finish(r + 1u, j + 1u, acc1.y);
    finish(r + 1u, j + 2u, acc1.z);
    finish(r + 1u, j + 3u, acc1.w);
    finish(r + 2u, j, acc2.x);
    finish(r + 2u, j + 1u, acc2.y);
    finish(r + 2u, j + 2u, acc2.z);
    finish(r + 2u, j + 3u, acc2.w);
    finish(r + 3u, j, acc3.x);
    finish(r + 3u, j + 1u, acc3.y);
    finish(r + 3u, j + 2u, acc3.z);
    finish(r + 3u, j + 3u, acc3.w);
}
