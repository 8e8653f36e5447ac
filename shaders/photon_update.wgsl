// Ring update (Elek 2012 §4.2): I = I − H_old + H_new, and H_new replaces H_old in the ring.
// Integer arithmetic: exact, so I never drifts however many frames run; a sum that would need
// more than 32 bits sets the overflow flag instead of wrapping unnoticed.
// CPU twin: `nimbus_photon::cpu::update`.
#import constants

@group(0) @binding(2) var<storage, read> h_new: array<u32>;
@group(0) @binding(3) var<storage, read_write> ring: array<u32>;
@group(0) @binding(4) var<storage, read_write> total: array<u32>;

struct Slot { offset: u32, count: u32, _a: u32, _b: u32 };
@group(0) @binding(5) var<uniform> slot: Slot;
// Set to 1 when a cell's ring total exceeds 32 bits (photon_trace.wgsl sets it for H_new).
@group(0) @binding(6) var<storage, read_write> overflow: array<atomic<u32>>;

@compute @workgroup_size(WG)
fn update(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= slot.count) { return; }
    let h_old = ring[slot.offset + i];
    let h_nw = h_new[i];
    // total − h_old cannot wrap (total holds h_old); the sum with h_new can.
    let rest = total[i] - h_old;
    if (rest > 0xffffffffu - h_nw) { atomicStore(&overflow[0], 1u); }
    total[i] = rest + h_nw;
    ring[slot.offset + i] = h_nw;
}
