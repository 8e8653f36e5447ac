//! One stencil level of the descriptor at a time (Kallweit 2017 §4.2): the 5 × 5 × 9 points of
//! a level lie on one rotated lattice, and all of them read the same pyramid level, so they are
//! looked up together — 16 at a time with AVX-512 gathers where the CPU has them (a point's two
//! cells along x as one 64-bit load), else one at a time with [`LevelSampler::at`]. Both give the same f32 values to the bit: the vector code
//! performs the scalar code's IEEE operations (no fused multiply-add) in the same order, lane
//! by lane (test: `descriptor::stencil_levels_agree_with_point_lookups`).

use glam::Vec3;

use super::{Cells, LevelSampler};

/// Points per stencil level (5 × 5 × 9).
const POINTS: usize = 225;
/// [`POINTS`] rounded up to whole 16-lane vectors.
const PADDED: usize = 240;

/// The stencil's local coordinates per axis (in units of the level's spacing before scaling,
/// as `descriptor::stencil_point`), padded with zeros to [`PADDED`].
const fn stencil_axis(axis: usize) -> [f32; PADDED] {
    let mut a = [0.0f32; PADDED];
    let mut p = 0;
    while p < POINTS {
        let i = match axis {
            0 => p % 5,
            1 => (p / 5) % 5,
            _ => p / 25,
        };
        a[p] = -1.0 + i as f32 * 0.5;
        p += 1;
    }
    a
}

static STENCIL: [[f32; PADDED]; 3] = [stencil_axis(0), stencil_axis(1), stencil_axis(2)];

/// Whether the vector kernel may read a dense level of `res` holding `len` cells: the cells are
/// exactly res[0]·res[1]·res[2] (the level's fields are public), their indices fit an i32, and
/// every axis is below 2²⁴, so that its last index is exact in f32 and a clamped index stays
/// inside. Anything else takes the scalar path, whose indexing is bounds-checked.
fn vector_safe(res: [usize; 3], len: usize) -> bool {
    res.iter().all(|&r| r <= 1 << 24)
        && res.iter().try_fold(1usize, |n, &r| n.checked_mul(r)) == Some(len)
        && len <= i32::MAX as usize
}

impl LevelSampler<'_> {
    /// ρ at the 225 points `x + (ex·sx + ey·sy + ez·sz) · scale` of one stencil level (point
    /// p = ix + 5 iy + 25 iz, local coordinates (sx, sy, sz) = (−1 + ix/2, −1 + iy/2, −1 + iz/2)),
    /// into `out` (len 225): [`LevelSampler::at`] of each point, bit for bit.
    pub fn stencil_into(&self, x: Vec3, axes: [Vec3; 3], scale: f32, out: &mut [f32]) {
        assert_eq!(out.len(), POINTS, "one stencil level is {POINTS} points");
        #[cfg(target_arch = "x86_64")]
        if let Cells::Dense(d) = &self.level.cells
            && vector_safe(self.level.res, d.len())
            && std::arch::is_x86_feature_detected!("avx512f")
        {
            // SAFETY: the CPU has AVX-512F (checked just above); `d` holds exactly the
            // res[0]·res[1]·res[2] cells the kernel's clamped indices address, fewer than 2³¹,
            // and every axis is exact in f32 (`vector_safe`).
            unsafe { avx512::stencil(self, d, x, axes, scale, out) };
            return;
        }
        self.stencil_into_scalar(x, axes, scale, out);
    }

    /// [`LevelSampler::stencil_into`] one point at a time (the reference for the vector code,
    /// and the path for sparse levels and CPUs without AVX-512).
    pub fn stencil_into_scalar(&self, x: Vec3, axes: [Vec3; 3], scale: f32, out: &mut [f32]) {
        assert_eq!(out.len(), POINTS, "one stencil level is {POINTS} points");
        let [ex, ey, ez] = axes;
        for (p, o) in out.iter_mut().enumerate() {
            let s = Vec3::new(STENCIL[0][p], STENCIL[1][p], STENCIL[2][p]);
            *o = self.at(x + (ex * s.x + ey * s.y + ez * s.z) * scale);
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use glam::Vec3;

    use super::{LevelSampler, PADDED, POINTS, STENCIL};

    /// The level's 225 lookups, 16 lanes at a time: per lane the operations of
    /// [`LevelSampler::at`] (box test, cell coordinates, floor, clamp, eight corners, three
    /// lerps), with masked gathers so that no lane outside the box reads memory.
    ///
    /// # Safety
    /// The CPU must have AVX-512F, and `d` must be the dense cells of `s`'s level
    /// (res[0]·res[1]·res[2] values, fewer than 2³¹).
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn stencil(
        s: &LevelSampler,
        d: &[f32],
        x: Vec3,
        axes: [Vec3; 3],
        scale: f32,
        out: &mut [f32],
    ) {
        let res = s.level.res;
        debug_assert_eq!(d.len(), res[0] * res[1] * res[2]);
        debug_assert!(d.len() < i32::MAX as usize);
        let set = |v: f32| _mm512_set1_ps(v);
        let (lo, hi, extent, resf, last) = (s.lo, s.hi, s.extent, s.resf, s.last);
        let (nx, ny) = (
            _mm512_set1_epi32(res[0] as i32),
            _mm512_set1_epi32(res[1] as i32),
        );
        let (zero, one, half) = (_mm512_setzero_ps(), set(1.0), set(0.5));
        let scale = set(scale);
        // Lane i of the 32 floats of two 8-pair gathers: cell x0 at 2i, x0 + 1 at 2i + 1.
        let evens = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let odds = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
        let mix = |a: __m512, b: __m512, t: __m512| {
            _mm512_add_ps(_mm512_mul_ps(a, _mm512_sub_ps(one, t)), _mm512_mul_ps(b, t))
        };
        let mut start = 0;
        while start < POINTS {
            let lanes: __mmask16 = if POINTS - start >= 16 {
                0xffff
            } else {
                (1u16 << (POINTS - start)) - 1
            };
            debug_assert!(start + 16 <= PADDED);
            // SAFETY: start + 16 ≤ PADDED, the length of every STENCIL row.
            let (sx, sy, sz) = unsafe {
                (
                    _mm512_loadu_ps(STENCIL[0].as_ptr().add(start)),
                    _mm512_loadu_ps(STENCIL[1].as_ptr().add(start)),
                    _mm512_loadu_ps(STENCIL[2].as_ptr().add(start)),
                )
            };
            let mut inside = lanes;
            let mut u = [zero; 3];
            for a in 0..3 {
                // x + ((ex·sx + ey·sy) + ez·sz) · scale, as glam's Vec3 computes it per axis.
                let t = _mm512_add_ps(
                    _mm512_mul_ps(set(axes[0][a]), sx),
                    _mm512_mul_ps(set(axes[1][a]), sy),
                );
                let t = _mm512_add_ps(t, _mm512_mul_ps(set(axes[2][a]), sz));
                let p = _mm512_add_ps(set(x[a]), _mm512_mul_ps(t, scale));
                inside &= _mm512_cmp_ps_mask::<_CMP_GE_OQ>(p, set(lo[a]))
                    & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(p, set(hi[a]));
                let q = _mm512_div_ps(_mm512_sub_ps(p, set(lo[a])), set(extent[a]));
                u[a] = _mm512_sub_ps(_mm512_mul_ps(q, set(resf[a])), half);
            }
            let mut f = [zero; 3];
            let mut i0 = [_mm512_setzero_si512(); 3];
            let mut i1 = [_mm512_setzero_si512(); 3];
            for a in 0..3 {
                let b = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(u[a]);
                f[a] = _mm512_sub_ps(u[a], b);
                let clamp = |v: __m512| _mm512_min_ps(_mm512_max_ps(v, zero), set(last[a]));
                i0[a] = _mm512_cvttps_epi32(clamp(b));
                i1[a] = _mm512_cvttps_epi32(clamp(_mm512_add_ps(b, one)));
            }
            let row = |y: __m512i, z: __m512i| {
                _mm512_mullo_epi32(_mm512_add_epi32(_mm512_mullo_epi32(z, ny), y), nx)
            };
            let rows = [
                row(i0[1], i0[2]),
                row(i1[1], i0[2]),
                row(i0[1], i1[2]),
                row(i1[1], i1[2]),
            ];
            // A lane whose two x cells differ reads them as one 64-bit pair: its x1 is x0 + 1 in
            // the same row (b in 0 … last − 1; otherwise both indices clamp to one cell), so
            // half as many loads. The few lanes clamped at an x face read their one cell alone.
            let pair = inside & _mm512_cmpneq_epi32_mask(i0[0], i1[0]);
            let single = inside & !pair;
            let mut c = [zero; 8];
            for (r, row) in rows.iter().enumerate() {
                let idx = _mm512_add_epi32(*row, i0[0]);
                // SAFETY: pair lanes read d[idx] and d[idx + 1], both cells of the level (x0 + 1
                // = x1 ≤ last); single lanes read d[idx]; lanes outside the box read nothing.
                let (lo, hi) = unsafe {
                    (
                        _mm512_mask_i32gather_epi64::<4>(
                            _mm512_setzero_si512(),
                            pair as u8,
                            _mm512_castsi512_si256(idx),
                            d.as_ptr().cast(),
                        ),
                        _mm512_mask_i32gather_epi64::<4>(
                            _mm512_setzero_si512(),
                            (pair >> 8) as u8,
                            _mm512_extracti64x4_epi64::<1>(idx),
                            d.as_ptr().cast(),
                        ),
                    )
                };
                let (lo, hi) = (_mm512_castsi512_ps(lo), _mm512_castsi512_ps(hi));
                let mut even = _mm512_permutex2var_ps(lo, evens, hi);
                let mut odd = _mm512_permutex2var_ps(lo, odds, hi);
                if single != 0 {
                    // SAFETY: as above, one cell per lane.
                    let one =
                        unsafe { _mm512_mask_i32gather_ps::<4>(zero, single, idx, d.as_ptr()) };
                    even = _mm512_mask_mov_ps(even, single, one);
                    odd = _mm512_mask_mov_ps(odd, single, one);
                }
                c[2 * r] = even;
                c[2 * r + 1] = odd;
            }
            let c00 = mix(c[0], c[1], f[0]);
            let c10 = mix(c[2], c[3], f[0]);
            let c01 = mix(c[4], c[5], f[0]);
            let c11 = mix(c[6], c[7], f[0]);
            let v = mix(mix(c00, c10, f[1]), mix(c01, c11, f[1]), f[2]);
            let v = _mm512_maskz_mov_ps(inside, v);
            // SAFETY: the lanes stored are those below POINTS − start, within `out`.
            unsafe { _mm512_mask_storeu_ps(out.as_mut_ptr().add(start), lanes, v) };
            start += 16;
        }
    }
}
