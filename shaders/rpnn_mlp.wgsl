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
// renderer's compacted queries, `nimbus_rpnn::gpu_sample`) is bound for L.rows (the whole
// batch) and dispatched indirectly for the count its shading pass wrote; workgroups past the
// count return at once. Other callers bind a limit of 0xffffffff.
//
// Storage: every buffer is read as u32 words, per layer in f32 (bitcast) or in f16 pairs
// (unpack2x16float: core WGSL, no SHADER_F16 needed) as `flags` says: bit 0 the weights,
// bit 1 a, bit 2 b, bit 3 res, bit 4 out. The products accumulate in f32 either way; an f16
// output is written as the pairs (j, j + 1) a thread owns (out_stride and out_offset even).
//
// Two kernels, chosen per network (`nimbus_rpnn::gpu_mlp::Tiles`), both with k-slices of 16
// inputs in workgroup memory and accumulators in named vec4 variables (private arrays indexed
// in loops are far slower on some drivers):
// - `dense_wide` (the default): MLP_TILE_ROWS = 64 queries × MLP_WIDE_TILE_OUTPUTS = 128
//   outputs per workgroup of 16 × 8 threads, each 8 queries × 8 outputs (queries 8 ty …,
//   outputs 4 tx … and 64 + 4 tx …): 4 vec4 workgroup reads per 64 products, half as many per
//   product as `dense`. A slice is loaded with consecutive threads on consecutive inputs of the
//   same rows (the rows of the batch and of the weight matrices are contiguous in k: coalesced
//   on a GPU).
// - `dense`: 64 queries × MLP_TILE_OUTPUTS = 64 outputs per 16 × 16 threads, each a 4 × 4
//   block: 2 vec4 reads per 16 products; consecutive threads load consecutive row groups at
//   one input of the slice.
// The dispatches count in these units (crates/gpu/src/consts.rs).
//
// On lavapipe `dense_wide` takes 25–33 % less time than `dense` for the network alone (`cargo
// bench -p nimbus-rpnn --bench network`) and 25–31 % less for a whole sample at 320×180
// (BENCHMARKS.md). Dropped there: 4 × 8 per thread on 16 × 16 threads (15–20 % slower than
// 8 × 8), and `dense` with separate load paths, free of per-element tests, for slices wholly
// inside `a` or `b` (slower than `dense`). Which is faster on a GPU is `bench/device.sh`
// step 2's.

#import constants

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
    flags: u32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
};

@group(0) @binding(0) var<uniform> L: Layer;
@group(0) @binding(1) var<storage, read> weights: array<u32>;
@group(0) @binding(2) var<storage, read> a_buf: array<u32>;
@group(0) @binding(3) var<storage, read> b_buf: array<u32>;
@group(0) @binding(4) var<storage, read> res_buf: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_buf: array<u32>;
@group(0) @binding(6) var<storage, read> row_limit: array<u32>;

const NO_GAMMA: u32 = 0xffffffffu;
const F16_W: u32 = 1u;
const F16_A: u32 = 2u;
const F16_B: u32 = 4u;
const F16_RES: u32 = 8u;
const F16_OUT: u32 = 16u;

// Element e of a buffer of f32 words, or of f16 pairs.
fn half_of(word: u32, e: u32) -> f32 {
    return unpack2x16float(word)[e & 1u];
}
fn w_at(e: u32) -> f32 {
    if ((L.flags & F16_W) != 0u) { return half_of(weights[e >> 1u], e); }
    return bitcast<f32>(weights[e]);
}
fn a_at(e: u32) -> f32 {
    if ((L.flags & F16_A) != 0u) { return half_of(a_buf[e >> 1u], e); }
    return bitcast<f32>(a_buf[e]);
}
fn b_at(e: u32) -> f32 {
    if ((L.flags & F16_B) != 0u) { return half_of(b_buf[e >> 1u], e); }
    return bitcast<f32>(b_buf[e]);
}
fn res_at(e: u32) -> f32 {
    if ((L.flags & F16_RES) != 0u) { return half_of(res_buf[e >> 1u], e); }
    return bitcast<f32>(res_buf[e]);
}

var<workgroup> a_tile: array<vec4<f32>, 256>; // [k 16][row group 16] × 4 rows
var<workgroup> w_tile: array<vec4<f32>, 256>; // [k 16][output group 16] × 4 outputs
var<workgroup> wg_rows: u32;

// Input i of query r (i < ka: from a, else from b), for a batch of `rows` queries.
fn input(r: u32, i: u32, rows: u32) -> f32 {
    if (r >= rows) {
        return 0.0;
    }
    if (i < L.ka) {
        var col = L.a_offset + i;
        if (L.a_gamma_col != NO_GAMMA && i == L.ka - 1u) {
            col = L.a_gamma_col;
        }
        return a_at(r * L.a_stride + col);
    }
    let k = i - L.ka;
    if (k < L.kb) {
        return b_at(r * L.b_stride + k);
    }
    return 0.0;
}

// Weight of input i for output j.
fn weight(j: u32, i: u32) -> f32 {
    if (j >= L.outputs) {
        return 0.0;
    }
    if (i < L.ka) {
        return w_at(L.wa_offset + j * L.ka + i);
    }
    let k = i - L.ka;
    if (k < L.kb) {
        return w_at(L.wb_offset + j * L.kb + k);
    }
    return 0.0;
}

// Input i of queries r … r + 3 (a row group of a tile).
fn input4(r: u32, i: u32, rows: u32) -> vec4<f32> {
    return vec4<f32>(input(r, i, rows), input(r + 1u, i, rows), input(r + 2u, i, rows),
        input(r + 3u, i, rows));
}

// Weights of input i for outputs j … j + 3 (an output group of a tile).
fn weight4(j: u32, i: u32) -> vec4<f32> {
    return vec4<f32>(weight(j, i), weight(j + 1u, i), weight(j + 2u, i), weight(j + 3u, i));
}

// The layer's output value (bias, residual, ReLU) of query r, output j, from the product v.
fn value(r: u32, j: u32, v: f32) -> f32 {
    var s = v + w_at(L.bias_offset + j);
    if (L.residual != 0u) {
        s += res_at(r * L.res_stride + j);
    }
    if (L.relu != 0u) {
        s = max(s, 0.0);
    }
    return s;
}

// Writes outputs j … j + 3 of query r (j a multiple of 4) of a batch of `rows` queries.
fn finish(r: u32, j: u32, acc: vec4<f32>, rows: u32) {
    if (r >= rows || j >= L.outputs) {
        return;
    }
    var v = vec4<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        if (j + c < L.outputs) {
            v[c] = value(r, j + c, acc[c]);
        }
    }
    let o = r * L.out_stride + L.out_offset + j;
    if ((L.flags & F16_OUT) != 0u) {
        // Pairs (j, j + 1), (j + 2, j + 3); a pair's second half past the outputs is padding.
        // Clamped to the largest half float (ReLU activations are ≥ 0; beyond 65 504 a half
        // would be infinite).
        let h = clamp(v, vec4<f32>(-65504.0), vec4<f32>(65504.0));
        out_buf[o >> 1u] = pack2x16float(h.xy);
        if (j + 2u < L.outputs) {
            out_buf[(o >> 1u) + 1u] = pack2x16float(h.zw);
        }
        return;
    }
    for (var c = 0u; c < 4u; c++) {
        if (j + c < L.outputs) {
            out_buf[o + c] = bitcast<u32>(v[c]);
        }
    }
}

@compute @workgroup_size(16, 16)
fn dense(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let j0 = wg.x * MLP_TILE_OUTPUTS;
    let r0 = wg.y * MLP_TILE_ROWS;
    let tx = lid.x; // output group
    let ty = lid.y; // row group
    let t = ty * 16u + tx;
    if (t == 0u) {
        wg_rows = min(L.rows, row_limit[0]);
    }
    let rows = workgroupUniformLoad(&wg_rows);
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
        a_tile[lk * 16u + lg] = input4(rr, kk, rows);
        let jj = j0 + lg * 4u;
        w_tile[lk * 16u + lg] = weight4(jj, kk);
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
    finish(r, j, acc0, rows);
    finish(r + 1u, j, acc1, rows);
    finish(r + 2u, j, acc2, rows);
    finish(r + 3u, j, acc3, rows);
}

// `dense_wide`'s tiles: [k][row group] × 4 rows and [k][output group] × 4 outputs, each row of
// the tile one vec4 longer than it needs (the slice's stores run down k and then fall in
// different banks). 16 × 8 threads, each 8 rows × 8 outputs in sixteen vec4 accumulators.
const WIDE_A_PITCH: u32 = 17u;
const WIDE_W_PITCH: u32 = 33u;
var<workgroup> wa_tile: array<vec4<f32>, 272>; // 16 × WIDE_A_PITCH
var<workgroup> ww_tile: array<vec4<f32>, 528>; // 16 × WIDE_W_PITCH

@compute @workgroup_size(16, 8)
fn dense_wide(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let j0 = wg.x * MLP_WIDE_TILE_OUTPUTS;
    let r0 = wg.y * MLP_TILE_ROWS;
    let tx = lid.x; // outputs j0 + 4 tx … and j0 + 64 + 4 tx …
    let ty = lid.y; // rows r0 + 8 ty …
    let t = ty * 16u + tx;
    if (t == 0u) {
        wg_rows = min(L.rows, row_limit[0]);
    }
    let rows = workgroupUniformLoad(&wg_rows);
    if (r0 >= rows) {
        return;
    }
    var c00 = vec4<f32>(0.0);
    var c01 = vec4<f32>(0.0);
    var c10 = vec4<f32>(0.0);
    var c11 = vec4<f32>(0.0);
    var c20 = vec4<f32>(0.0);
    var c21 = vec4<f32>(0.0);
    var c30 = vec4<f32>(0.0);
    var c31 = vec4<f32>(0.0);
    var c40 = vec4<f32>(0.0);
    var c41 = vec4<f32>(0.0);
    var c50 = vec4<f32>(0.0);
    var c51 = vec4<f32>(0.0);
    var c60 = vec4<f32>(0.0);
    var c61 = vec4<f32>(0.0);
    var c70 = vec4<f32>(0.0);
    var c71 = vec4<f32>(0.0);
    let k_total = L.ka + L.kb;
    for (var k0 = 0u; k0 < k_total; k0 += 16u) {
        // Queries: 16 inputs × 16 row groups of 4, two vec4 per thread; weights: 16 inputs × 32
        // output groups of 4, four per thread. Consecutive threads take consecutive inputs of
        // the same rows, and each stores whole vec4s.
        for (var h = 0u; h < 2u; h++) {
            let s = t + 128u * h;
            let lk = s % 16u;
            let g = s / 16u;
            let kk = k0 + lk;
            let rr = r0 + g * 4u;
            wa_tile[lk * WIDE_A_PITCH + g] = input4(rr, kk, rows);
        }
        for (var h = 0u; h < 4u; h++) {
            let s = t + 128u * h;
            let lk = s % 16u;
            let og = s / 16u;
            let kk = k0 + lk;
            let jj = j0 + og * 4u;
            ww_tile[lk * WIDE_W_PITCH + og] = weight4(jj, kk);
        }
        workgroupBarrier();
        for (var k = 0u; k < 16u; k++) {
            let a0 = wa_tile[k * WIDE_A_PITCH + 2u * ty];
            let a1 = wa_tile[k * WIDE_A_PITCH + 2u * ty + 1u];
            let w0 = ww_tile[k * WIDE_W_PITCH + tx];
            let w1 = ww_tile[k * WIDE_W_PITCH + 16u + tx];
            c00 += a0.x * w0;
            c01 += a0.x * w1;
            c10 += a0.y * w0;
            c11 += a0.y * w1;
            c20 += a0.z * w0;
            c21 += a0.z * w1;
            c30 += a0.w * w0;
            c31 += a0.w * w1;
            c40 += a1.x * w0;
            c41 += a1.x * w1;
            c50 += a1.y * w0;
            c51 += a1.y * w1;
            c60 += a1.z * w0;
            c61 += a1.z * w1;
            c70 += a1.w * w0;
            c71 += a1.w * w1;
        }
        workgroupBarrier();
    }
    let r = r0 + ty * 8u;
    let j = j0 + tx * 4u;
    let j1 = j0 + 64u + tx * 4u;
    finish(r, j, c00, rows);
    finish(r, j1, c01, rows);
    finish(r + 1u, j, c10, rows);
    finish(r + 1u, j1, c11, rows);
    finish(r + 2u, j, c20, rows);
    finish(r + 2u, j1, c21, rows);
    finish(r + 3u, j, c30, rows);
    finish(r + 3u, j1, c31, rows);
    finish(r + 4u, j, c40, rows);
    finish(r + 4u, j1, c41, rows);
    finish(r + 5u, j, c50, rows);
    finish(r + 5u, j1, c51, rows);
    finish(r + 6u, j, c60, rows);
    finish(r + 6u, j1, c61, rows);
    finish(r + 7u, j, c70, rows);
    finish(r + 7u, j1, c71, rows);
}
