//! Twin of `update` in `shaders/photon_update.wgsl`: the ring update of one cache word (Elek
//! 2012 §4.2), I = I − H_old + H_new and H_new replaces H_old in the ring, in exact integer
//! arithmetic.

/// Word `i` of the ring update: `slot_offset` is the first word of the ring slot being
/// replaced. Returns whether the total would exceed 32 bits (the shader's overflow flag).
pub fn update(
    h_new: &[u32],
    ring: &mut [u32],
    total: &mut [u32],
    slot_offset: usize,
    i: usize,
) -> bool {
    let h_old = ring[slot_offset + i];
    let h_nw = h_new[i];
    // total − h_old cannot wrap (total holds h_old); the sum with h_new can.
    let rest = total[i].wrapping_sub(h_old);
    let overflow = rest > u32::MAX - h_nw;
    total[i] = rest.wrapping_add(h_nw);
    ring[slot_offset + i] = h_nw;
    overflow
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Over many frames the total is always the sum of the ring's slots (no drift), and a sum
    /// beyond 32 bits is flagged.
    #[test]
    fn total_is_the_sum_of_the_ring() {
        let (m, n) = (3usize, 5usize);
        let mut ring = vec![0u32; m * n];
        let mut total = vec![0u32; n];
        for frame in 0..20u32 {
            let h: Vec<u32> = (0..n as u32).map(|i| (frame * 7 + i * 13) % 50).collect();
            let slot = (frame as usize % m) * n;
            for i in 0..n {
                assert!(!update(&h, &mut ring, &mut total, slot, i));
            }
            for i in 0..n {
                let sum: u32 = (0..m).map(|s| ring[s * n + i]).sum();
                assert_eq!(total[i], sum, "frame {frame} word {i}");
            }
        }
        let mut ring = vec![0u32, 0];
        let mut total = vec![u32::MAX - 1, 0];
        assert!(update(&[5, 0], &mut ring, &mut total, 0, 0));
    }
}
