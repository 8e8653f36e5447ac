//! One memory budget for every allocation whose size comes from input: dense grids (volume
//! files, OpenVDB densification, the generators), images (camera resolution, EXR data windows)
//! and the files read whole into memory.
//!
//! Such an allocation is sized first and checked against the budget; over it, the error names
//! the field, the bytes needed and the budget, instead of the process being killed by the
//! allocator ("memory allocation of N bytes failed" is an abort that no error handling can
//! catch). Within the budget the allocation is made fallibly ([`Vec::try_reserve_exact`]), so a
//! machine that has less free memory than the budget still gets an error, not an abort.
//!
//! The budget bounds each such allocation (the largest one of a run dominates: a 1200³ grid is
//! 6.9 GB, the images and buffers beside it are megabytes). Default: 3/4 of the physical memory
//! (or of the cgroup limit, in a container); `NIMBUS_MAX_MEMORY` or the CLI's `--max-memory`
//! (`6G`, `512M`, `1.5GiB`, bytes) set it.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::FieldError;

/// 0: not set (the default applies).
static BUDGET: AtomicU64 = AtomicU64::new(0);

/// The environment variable that sets the budget (overridden by [`set_budget`]).
pub const ENV: &str = "NIMBUS_MAX_MEMORY";

/// Fallback when the physical memory cannot be read.
const FALLBACK: u64 = 8 << 30;

/// Sets the budget for this process (the CLI's `--max-memory`).
pub fn set_budget(bytes: u64) {
    BUDGET.store(bytes.max(1), Ordering::Relaxed);
}

/// The budget in bytes: [`set_budget`], else `NIMBUS_MAX_MEMORY`, else [`default_budget`].
pub fn budget() -> u64 {
    match BUDGET.load(Ordering::Relaxed) {
        0 => std::env::var(ENV)
            .ok()
            .and_then(|v| parse_size(&v).ok())
            .unwrap_or_else(default_budget),
        b => b,
    }
}

/// 3/4 of the physical memory, or of the cgroup (v2) limit when that is lower.
pub fn default_budget() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
                .map(|kb| kb * 1024)
        })
        .unwrap_or(FALLBACK / 3 * 4);
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|t| t.trim().parse::<u64>().ok())
        .unwrap_or(u64::MAX);
    total.min(cgroup) / 4 * 3
}

/// Parses a size: bytes, or a number with K, M, G, T (powers of 1024; `KB`, `KiB`, … alike).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num
        .parse()
        .map_err(|_| format!("`{s}`: expected a size such as 6G, 512M or 1000000"))?;
    let shift = match unit.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 0,
        "K" | "KB" | "KIB" => 10,
        "M" | "MB" | "MIB" => 20,
        "G" | "GB" | "GIB" => 30,
        "T" | "TB" | "TIB" => 40,
        other => return Err(format!("`{s}`: unknown unit `{other}` (K, M, G or T)")),
    };
    let bytes = v * (1u64 << shift) as f64;
    if bytes.is_nan() || bytes < 1.0 {
        return Err(format!("`{s}`: must be at least 1 byte"));
    }
    if !(bytes.is_finite() && bytes < u64::MAX as f64) {
        return Err(format!("`{s}`: too large (at most 16 EiB, 2^64 bytes)"));
    }
    Ok(bytes as u64)
}

/// A size for people in the units `--max-memory` takes: `8.0 GiB`.
pub fn human(bytes: u128) -> String {
    let b = bytes as f64;
    let k = 1024f64;
    match b {
        b if b >= k.powi(4) => format!("{:.1} TiB", b / k.powi(4)),
        b if b >= k.powi(3) => format!("{:.1} GiB", b / k.powi(3)),
        b if b >= k.powi(2) => format!("{:.1} MiB", b / k.powi(2)),
        b if b >= k => format!("{:.1} KiB", b / k),
        b => format!("{b} bytes"),
    }
}

/// Checks that `what` (e.g. "a 1280×1280×1280 dense grid"), needing `bytes`, fits the budget.
pub fn check(bytes: u128, field: &str, what: &str) -> Result<(), FieldError> {
    let budget = budget();
    if bytes > budget as u128 {
        return Err(FieldError::new(
            field,
            format!(
                "{what} needs {}, the memory budget is {} (--max-memory or {ENV})",
                human(bytes),
                human(budget as u128)
            ),
        ));
    }
    Ok(())
}

/// A vector of `n` copies of `value`, checked against the budget and allocated fallibly.
pub fn filled<T: Clone>(n: usize, value: T, field: &str, what: &str) -> Result<Vec<T>, FieldError> {
    let bytes = (n as u128) * (std::mem::size_of::<T>() as u128);
    check(bytes, field, what)?;
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| {
        FieldError::new(
            field,
            format!(
                "{what} needs {}, which this machine could not allocate now (within the budget of {})",
                human(bytes),
                human(budget() as u128)
            ),
        )
    })?;
    v.resize(n, value);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("6G").unwrap(), 6 << 30);
        assert_eq!(parse_size("512m").unwrap(), 512 << 20);
        assert_eq!(parse_size("1.5GiB").unwrap(), 3 << 29);
        assert_eq!(parse_size("1000").unwrap(), 1000);
        for bad in ["", "G", "-1G", "6X", "0", "1e999"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        // Overflow is said as such (was "must be at least 1 byte").
        let e = parse_size("99999999999999999999T").unwrap_err();
        assert!(e.contains("too large"), "{e}");
    }

    #[test]
    fn default_is_a_fraction_of_physical_memory() {
        let d = default_budget();
        // Any machine this runs on has between 256 MB and 1 PB.
        assert!(d > 256 << 20 && d < 1 << 50, "{d}");
    }

    #[test]
    fn over_budget_names_field_and_sizes() {
        // 10^6 × 10^6 pixels × 12 bytes = 12 TB: over any budget this test can meet.
        let e = filled(1usize << 60, 0u8, "dataWindow", "a 10⁶×10⁶ image").unwrap_err();
        assert_eq!(e.field, "dataWindow");
        assert!(
            e.msg.contains("1048576.0 TiB") && e.msg.contains("--max-memory"),
            "{e}"
        );
        let v = filled(1000, 1.5f32, "x", "a small grid").unwrap();
        assert_eq!((v.len(), v[999]), (1000, 1.5));
    }
}
