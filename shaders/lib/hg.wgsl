#import math

// ---- Henyey–Greenstein (propagation convention: cos between travel directions) -------------
fn hg_eval(g: f32, mu: f32) -> f32 {
    let denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - mu);
    return (1.0 - g * g) / (4.0 * PI * denom * sqrt(denom));
}

fn hg_sample_cos(g: f32, u: f32) -> f32 {
    let s = 2.0 * u - 1.0;
    // The Taylor branch below |g| = 1e-3, not 1e-4 as in f64 (`crates/scene/src/phase/hg.rs`):
    // in f32 the closed form loses ≈ 6e-8 / (2|g|) to cancellation (3e-5 at 1e-3, 3e-4 at
    // 1e-4), while the first-order expansion errs by O(g²) = 1e-6 at 1e-3.
    if (abs(g) < 1.0e-3) {
        return clamp(s + 1.5 * g * (1.0 - s * s), -1.0, 1.0);
    }
    let t = (1.0 - g * g) / (1.0 + g * s);
    return clamp((1.0 + g * g - t * t) / (2.0 * g), -1.0, 1.0);
}
