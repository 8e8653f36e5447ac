//! 4×4 blocks of cloud pixels: the unit of the noise, bias and speed-up figures
//! ([`crate::metrics`]) and of the reference's stopping rule ([`crate::reference`]), which both
//! build on this module (neither on the other for it).

/// Fewest cloud pixels of a 4×4 tile that counts as a block: half of it.
pub const MIN_BLOCK_PIXELS: usize = 8;

/// The 4×4 tiles with at least [`MIN_BLOCK_PIXELS`] pixels inside `mask`, each as the indices
/// of its cloud pixels (block means are taken over those). Tiles only partly in the cloud
/// count: a thin cloud (cirrus at 128×72: 4 tiles lie fully inside it, ≈ 40 at least half)
/// would otherwise be judged on a handful of blocks, whose noise estimate from two halves is
/// itself too uncertain for a bias to be told from noise.
pub fn cloud_blocks(mask: &[bool], w: usize, h: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for by in 0..h / 4 {
        for bx in 0..w / 4 {
            let b: Vec<usize> = (0..16)
                .map(|k| (by * 4 + k / 4) * w + bx * 4 + k % 4)
                .filter(|&i| mask[i])
                .collect();
            if b.len() >= MIN_BLOCK_PIXELS {
                out.push(b);
            }
        }
    }
    out
}

/// Mean over blocks of `v` averaged over each block's pixels, squared: the block MSE of a
/// per-pixel difference.
pub fn block_mean_square(v: impl Fn(usize) -> f64, blocks: &[Vec<usize>]) -> f64 {
    if blocks.is_empty() {
        return 0.0;
    }
    blocks
        .iter()
        .map(|b| {
            let m = b.iter().map(|&i| v(i)).sum::<f64>() / b.len() as f64;
            m * m
        })
        .sum::<f64>()
        / blocks.len() as f64
}
