//! The two compressors of OpenVDB and NanoVDB files, bounded: zlib (pure Rust, `flate2` on
//! miniz_oxide) and Blosc 1 (c-blosc through `blosc-src`, after validating the frame).

/// zlib into exactly `nbytes` (never more is written or allocated).
pub fn inflate(src: &[u8], nbytes: usize) -> Result<Vec<u8>, String> {
    let mut out = vec![0u8; nbytes];
    let mut d = flate2::Decompress::new(true);
    match d.decompress(src, &mut out, flate2::FlushDecompress::Finish) {
        Ok(flate2::Status::StreamEnd) if d.total_out() as usize == nbytes => Ok(out),
        Ok(_) => Err(format!(
            "it does not decompress to the {nbytes} bytes expected ({} so far)",
            d.total_out()
        )),
        Err(e) => Err(e.to_string()),
    }
}

/// OpenVDB pads Blosc inputs shorter than 48 bytes to this many (`BLOSC_PAD_BYTES`).
const BLOSC_PAD_BYTES: usize = 128;

/// A Blosc 1 frame into `nbytes`. The frame is validated first (its header's compressed length
/// must equal the block's and its decompressed length the expected one), which c-blosc
/// documents as making decompression safe; c-blosc never writes past `destsize`.
pub fn unblosc(src: &[u8], nbytes: usize) -> Result<Vec<u8>, String> {
    let claimed = validate_blosc(src)?;
    if claimed != nbytes && !(claimed == BLOSC_PAD_BYTES && nbytes < BLOSC_PAD_BYTES) {
        return Err(format!(
            "it claims {claimed} decompressed bytes where {nbytes} are expected"
        ));
    }
    let mut out = decompress_blosc(src, claimed)?;
    out.truncate(nbytes);
    Ok(out)
}

/// One Blosc chunk of at most `max` bytes (NanoVDB splits large grids into chunks).
pub fn unblosc_chunk(src: &[u8], max: usize) -> Result<Vec<u8>, String> {
    let claimed = validate_blosc(src)?;
    if claimed == 0 || claimed > max {
        return Err(format!(
            "it claims {claimed} decompressed bytes where at most {max} remain"
        ));
    }
    decompress_blosc(src, claimed)
}

/// The decompressed size a frame claims, after c-blosc's own validation against its length.
fn validate_blosc(src: &[u8]) -> Result<usize, String> {
    let mut claimed = 0usize;
    // SAFETY: `src` is a valid slice of `src.len()` bytes; `claimed` is a valid out-pointer.
    let ok =
        unsafe { blosc_src::blosc_cbuffer_validate(src.as_ptr().cast(), src.len(), &mut claimed) };
    if ok != 0 {
        return Err("not a Blosc frame of that length".into());
    }
    Ok(claimed)
}

fn decompress_blosc(src: &[u8], claimed: usize) -> Result<Vec<u8>, String> {
    let mut out = vec![0u8; claimed];
    // SAFETY: the frame was validated against its length; `out` has room for `claimed` bytes,
    // which is the destination size passed.
    let got = unsafe {
        blosc_src::blosc_decompress_ctx(src.as_ptr().cast(), out.as_mut_ptr().cast(), claimed, 1)
    };
    if got < 0 || got as usize != claimed {
        return Err(format!("decompression failed (code {got})"));
    }
    Ok(out)
}
