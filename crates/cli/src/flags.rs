//! Value parsers for the numeric flags: each checks that the value is finite and in its range
//! while the command line is parsed, so clap refuses a bad one before any work, naming the flag
//! (`error: invalid value 'X' for '--flag <FLAG>': must lie in …`, exit status 2). The ranges
//! are the ones that keep what the value feeds finite and meaningful; the combinations of two
//! flags are checked right after parsing (`main::check_flag_combinations`).

use std::fmt::Display;
use std::str::FromStr;

/// Largest sun angular speed, degrees per second (100 turns a second).
pub(crate) const MAX_SUN_SPEED: f64 = 36_000.0;
/// Largest simulated time step of the headless viewer, seconds (an hour a frame).
pub(crate) const MAX_DT: f64 = 3600.0;
/// Largest frame rate of an animation or a density sequence, frames per simulated second.
pub(crate) const MAX_FPS: f64 = 1000.0;
/// Largest turn of the sun in one frame, degrees: beyond a whole turn the sun's positions
/// alias (a sun speed × time step that large is a mistyped flag, not an animation).
pub(crate) const MAX_TURN_PER_FRAME: f64 = 360.0;
/// Largest density scale (σ_t per unit grid value): the estimators compute in f32.
pub(crate) const MAX_DENSITY_SCALE: f64 = 1e30;
/// Largest exposure (a PNG multiplier; the auto exposure of the dimmest image is far below it).
pub(crate) const MAX_EXPOSURE: f64 = 1e30;
/// Largest record count of a data set (a trillion).
pub(crate) const MAX_RECORDS: usize = 1 << 40;

/// A bound in a message: plain for ordinary numbers, in exponent form for huge ones.
fn show(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

fn number(s: &str) -> Result<f64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))
}

/// A finite number in `[lo, hi]`.
pub(crate) fn f64_in(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s| {
        let v = number(s)?;
        if v.is_finite() && (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(format!(
                "must be a finite number in [{}, {}], got {s}",
                show(lo),
                show(hi)
            ))
        }
    }
}

/// A finite number in `(lo, hi]` (a rate, a step or a scale that must be above `lo`).
pub(crate) fn f64_above(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s| {
        let v = number(s)?;
        if v.is_finite() && v > lo && v <= hi {
            Ok(v)
        } else {
            Err(format!(
                "must be a finite number in ({}, {}], got {s}",
                show(lo),
                show(hi)
            ))
        }
    }
}

/// [`f64_in`] for an `f32` flag.
pub(crate) fn f32_in(
    lo: f32,
    hi: f32,
) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    let f = f64_in(lo as f64, hi as f64);
    move |s| f(s).map(|v| v as f32)
}

/// A whole number in `lo..=hi` (a count, a size, a limit).
pub(crate) fn int_in<T>(
    lo: T,
    hi: T,
) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: FromStr + PartialOrd + Copy + Display + Send + Sync + 'static,
{
    move |s| {
        let v: T = s
            .trim()
            .parse()
            .map_err(|_| format!("`{s}` is not a whole number in {lo}..={hi}"))?;
        if (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(format!("must lie in {lo}..={hi}, got {v}"))
        }
    }
}

/// Three comma-separated whole numbers `X,Y,Z`, each in `lo..=hi` (a resolution).
pub(crate) fn u32_triple(
    lo: u32,
    hi: u32,
) -> impl Fn(&str) -> Result<[u32; 3], String> + Clone + Send + Sync + 'static {
    let one = int_in(lo, hi);
    move |s| {
        let v = s.split(',').map(&one).collect::<Result<Vec<_>, _>>()?;
        <[u32; 3]>::try_from(v)
            .map_err(|v| format!("needs three values X,Y,Z, got {} in `{s}`", v.len()))
    }
}

/// Three comma-separated finite numbers `X,Y,Z` (a point), each of magnitude ≤ `max`.
pub(crate) fn f64_triple(
    max: f64,
) -> impl Fn(&str) -> Result<[f64; 3], String> + Clone + Send + Sync + 'static {
    let one = f64_in(-max, max);
    move |s| {
        let v = s.split(',').map(&one).collect::<Result<Vec<_>, _>>()?;
        <[f64; 3]>::try_from(v)
            .map_err(|v| format!("needs three values X,Y,Z, got {} in `{s}`", v.len()))
    }
}

/// `LO,HI` with `lo < LO <= HI <= hi` (a range of scales).
pub(crate) fn f64_pair_above(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<(f64, f64), String> + Clone + Send + Sync + 'static {
    let one = f64_above(lo, hi);
    move |s| {
        let (a, b) = s
            .split_once(',')
            .ok_or_else(|| format!("needs LO,HI, got `{s}`"))?;
        let (a, b) = (one(a)?, one(b)?);
        if a <= b {
            Ok((a, b))
        } else {
            Err(format!("needs LO <= HI, got `{s}`"))
        }
    }
}

/// An image size `WxH`, each side in `lo..=hi` pixels.
pub(crate) fn image_size(
    lo: usize,
    hi: usize,
) -> impl Fn(&str) -> Result<(usize, usize), String> + Clone + Send + Sync + 'static {
    let side = int_in(lo, hi);
    move |s| {
        let (w, h) = s
            .split_once(['x', 'X'])
            .ok_or_else(|| format!("expected WIDTHxHEIGHT, e.g. 128x72, got `{s}`"))?;
        Ok((side(w)?, side(h)?))
    }
}

/// The sun's turn in one frame, `speed` degrees per second over `dt` seconds, refused beyond
/// [`MAX_TURN_PER_FRAME`]; `flags` names the two flags.
pub(crate) fn check_turn_per_frame(speed: f64, dt: f64, flags: &str) -> Result<(), String> {
    let turn = (speed * dt).abs();
    if turn.is_finite() && turn <= MAX_TURN_PER_FRAME {
        Ok(())
    } else {
        Err(format!(
            "{flags}: the sun would turn {}° per frame; at most {MAX_TURN_PER_FRAME}° (a whole turn)",
            show(turn)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_and_messages() {
        let p = f64_in(-1.0, 1.0);
        assert_eq!(p("0.5"), Ok(0.5));
        assert_eq!(p(" -1 "), Ok(-1.0));
        for bad in ["nan", "NaN", "inf", "-inf", "1e308", "1.0001", "x", ""] {
            assert!(p(bad).is_err(), "{bad}");
        }
        assert!(p("2").unwrap_err().contains("[-1, 1]"));
        let q = f64_above(0.0, MAX_DT);
        assert!(q("0").is_err() && q("-0").is_err() && q("3600.5").is_err());
        assert_eq!(q("3600"), Ok(3600.0));
        assert!(q("1e308").unwrap_err().contains("(0, 3600]"));
        assert!(
            f64_above(0.0, MAX_DENSITY_SCALE)("1e31")
                .unwrap_err()
                .contains("1e30")
        );
        assert_eq!(f32_in(0.0, 16.0)("16"), Ok(16.0));
        assert!(f32_in(0.0, 16.0)("1e39").is_err());
        let n = int_in(1u32, 4096);
        assert_eq!(n("4096"), Ok(4096));
        assert!(n("0").unwrap_err().contains("1..=4096"));
        assert!(n("-1").is_err() && n("1.5").is_err() && n("nan").is_err());
        let t = u32_triple(1, 65536);
        assert_eq!(t("1,2,3"), Ok([1, 2, 3]));
        assert!(t("1,2").is_err() && t("1,0,3").is_err() && t("1,2,3,4").is_err());
        let a = f64_triple(1e15);
        assert_eq!(a("-1,0,2.5"), Ok([-1.0, 0.0, 2.5]));
        assert!(a("0,nan,0").is_err() && a("0,0").is_err());
        let r = f64_pair_above(0.0, MAX_DENSITY_SCALE);
        assert_eq!(r("10,80"), Ok((10.0, 80.0)));
        assert!(r("80,10").is_err() && r("0,1").is_err() && r("1,inf").is_err() && r("1").is_err());
        let s = image_size(1, 32768);
        assert_eq!(s("64x32"), Ok((64, 32)));
        assert!(
            s("0x32").is_err() && s("64x").is_err() && s("64").is_err() && s("1x99999").is_err()
        );
        assert!(check_turn_per_frame(10.0, 1.0 / 30.0, "f").is_ok());
        assert!(check_turn_per_frame(-360.0, 1.0, "f").is_ok());
        let e = check_turn_per_frame(MAX_SUN_SPEED, MAX_DT, "--sun-speed × --dt").unwrap_err();
        assert!(
            e.contains("--sun-speed × --dt") && e.contains("1.296e8"),
            "{e}"
        );
    }
}
