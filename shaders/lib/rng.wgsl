// ---- PCG32 (O'Neill), one stream per beam / pixel ------------------------------------------
struct Rng { state: u32 };

fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

fn rng_new(a: u32, b: u32, c: u32) -> Rng {
    return Rng(pcg_hash(a ^ pcg_hash(b ^ pcg_hash(c))));
}

// 24 random bits as an integer in 0 .. 2²⁴ (the bits `rand` maps to [0, 1)).
fn rand_u24(r: ptr<function, Rng>) -> u32 {
    (*r).state = (*r).state * 747796405u + 2891336453u;
    let s = (*r).state;
    let word = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    let x = (word >> 22u) ^ word;
    return x >> 8u;
}

fn rand(r: ptr<function, Rng>) -> f32 {
    // 24 random bits -> [0, 1)
    return f32(rand_u24(r)) * (1.0 / 16777216.0);
}
