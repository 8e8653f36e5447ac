//! Every floating-point and count flag of every subcommand is checked while the command line is
//! parsed: NaN, ±∞, 1e308, negatives and zeros where they make no sense are refused by clap
//! (exit status 2) naming the flag, before any scene is read; the values in range are accepted.

use std::time::{Duration, Instant};

use crate::common::{nimbus_within, text};

/// One flag: where it is given, its name, the values refused beyond NaN, ±∞ and 1e308 (which
/// every row refuses), and one value accepted.
struct Row {
    cmd: &'static [&'static str],
    flag: &'static str,
    bad: &'static [&'static str],
    good: &'static str,
}

/// Command lines that fail after parsing for a reason of their own (a missing scene or file, an
/// unknown light or method), so a value that parses shows as exit status 1 without the flag.
const RENDER: &[&str] = &["render", "no/such/scene.toml"];
const ANIMATE: &[&str] = &["animate", "no/such/scene.toml"];
const VIEW: &[&str] = &["view", "no/such/scene.toml"];
const COMPARE: &[&str] = &["compare", "no/such/scene.toml"];
const SUITE: &[&str] = &["bench-suite", "--lights", "nope"];
const STRESS: &[&str] = &["stress", "--methods", "nope"];
const DATAGEN: &[&str] = &[
    "datagen",
    "--clouds",
    "gen:0",
    "-o",
    "no/such/set",
    "--records",
    "1",
];
const DATAGEN_NO_RECORDS: &[&str] = &["datagen", "--clouds", "gen:0", "-o", "no/such/set"];
const INFO: &[&str] = &["info", "no/such/cloud.vol"];

const NONFINITE: [&str; 4] = ["nan", "inf", "-inf", "1e308"];
const TRIPLE_BAD: &[&str] = &["0,8,8", "8,8", "8,8,8,8", "8,-1,8", "8,nan,8", "8,8,65537"];

/// The photon map's flags (`render`, `animate`, `view`).
fn pm_rows(cmd: &'static [&'static str]) -> Vec<Row> {
    vec![
        row(cmd, "--beams", &["0", "-1", "67108865"], "1024"),
        row(cmd, "--pm-lobe-split", &["-1", "1025"], "4"),
        row(cmd, "--ring", &["0", "-1", "4097"], "8"),
        row(cmd, "--cache-res", TRIPLE_BAD, "8,8,8"),
        row(cmd, "--light-res", TRIPLE_BAD, "8,8,8"),
        row(cmd, "--detail-noise", &["-0.5", "16.5"], "1.5"),
        row(cmd, "--similarity", &["-0.1", "1"], "0.05"),
        row(cmd, "--max-order", &["-1", "65537"], "0"),
    ]
}

/// The final gathering's flags (`render`, `compare`, `bench-suite`, `view`).
fn gather_rows(cmd: &'static [&'static str]) -> Vec<Row> {
    vec![
        row(cmd, "--gather-bounces", &["-1", "1000001"], "2"),
        row(cmd, "--gather-spread", &["-0.1", "1.1"], "0.5"),
        row(cmd, "--ring-refresh", &["-1", "1000001"], "4"),
    ]
}

/// RPNN's flags (`render`, `compare`, `bench-suite`).
fn rpnn_rows(cmd: &'static [&'static str]) -> Vec<Row> {
    vec![
        row(cmd, "--sky-dirs", &["0", "-1", "1025"], "8"),
        row(cmd, "--sky-degree", &["-1", "5"], "2"),
        row(cmd, "--traced-bounces", &["-1", "1000000"], "1"),
        row(cmd, "--query-every", &["0", "-1", "65"], "2"),
    ]
}

/// The reference's and the runs' flags (`compare`, `bench-suite`).
fn eval_rows(cmd: &'static [&'static str]) -> Vec<Row> {
    vec![
        row(cmd, "--ref-spp", &["0", "-1", "1048577"], "64"),
        row(cmd, "--ref-noise", &["-0.1", "1"], "0.05"),
        row(cmd, "--ref-time-cap", &["-1", "1e10"], "60"),
        row(cmd, "--beams", &["0", "-1", "16777217"], "1024"),
        row(cmd, "--ring", &["0", "-1", "4097"], "8"),
    ]
}

fn row(
    cmd: &'static [&'static str],
    flag: &'static str,
    bad: &'static [&'static str],
    good: &'static str,
) -> Row {
    Row {
        cmd,
        flag,
        bad,
        good,
    }
}

/// Every checked flag of every subcommand.
fn rows() -> Vec<Row> {
    let mut v = vec![
        row(RENDER, "--spp", &["0", "-1", "16777217"], "4"),
        row(RENDER, "--exposure", &["0", "-1", "1e31"], "2.5"),
        row(RENDER, "--threads", &["0", "-1", "1025"], "2"),
        row(ANIMATE, "--frames", &["0", "-1"], "2"),
        row(ANIMATE, "--sun-speed", &["36001", "-36001"], "-30"),
        row(ANIMATE, "--fps", &["0", "-30", "1001"], "24"),
        row(ANIMATE, "--evolve", &["0", "-1"], "10"),
        row(ANIMATE, "--exposure", &["0", "-1", "1e31"], "1"),
        row(VIEW, "--frames", &["0", "-1"], "3"),
        row(
            VIEW,
            "--size",
            &["0x10", "10x0", "10", "10x", "32769x10", "-1x10", "nanx10"],
            "64x32",
        ),
        row(VIEW, "--sun-speed", &["36001", "-36001"], "-30"),
        row(VIEW, "--evolve", &["0", "-1"], "10"),
        row(VIEW, "--density-fps", &["0", "-1", "1001"], "24"),
        row(VIEW, "--dt", &["0", "-0.1", "3601"], "0.5"),
        row(VIEW, "--exposure", &["0", "-1", "1e31"], "1"),
        row(COMPARE, "--range", &["0", "-0.2", "1e7"], "0.5"),
        row(SUITE, "--clouds", &["0", "-1", "9"], "2"),
        row(SUITE, "--size", &["3x3", "4097x72", "128", "0x0"], "64x36"),
        row(STRESS, "--time-limit", &["0", "-1", "86401"], "60"),
        row(
            DATAGEN_NO_RECORDS,
            "--records",
            &["-1", "1099511627777"],
            "0",
        ),
        row(DATAGEN, "--test-records", &["-1", "1099511627777"], "0"),
        row(DATAGEN, "--val-records", &["-1", "1099511627777"], "0"),
        row(DATAGEN, "--samples", &["0", "-1", "16777217"], "16"),
        row(DATAGEN, "--eval-samples", &["0", "-1", "16777217"], "16"),
        row(DATAGEN, "--eval-noise", &["-0.1", "1"], "0.025"),
        row(
            DATAGEN,
            "--density-range",
            &["0,10", "10,5", "5", "-1,10", "5,inf", "nan,5", "5,1e31"],
            "5,50",
        ),
        row(DATAGEN, "--shard-size", &["0", "-1", "1073741825"], "100"),
        row(DATAGEN, "--max-samples", &["0", "-1"], "1000"),
        row(DATAGEN, "--density-scale", &["0", "-1", "1e31"], "10"),
        row(INFO, "--density-scale", &["-1", "1e31"], "0"),
        row(
            INFO,
            "--aabb-min",
            &["0,0", "0,nan,0", "0,0,inf", "1e16,0,0"],
            "-1,-1,-1",
        ),
        row(INFO, "--aabb-max", &["0,0", "0,nan,0", "0,0,inf"], "1,1,1"),
    ];
    for cmd in [RENDER, ANIMATE, VIEW] {
        v.extend(pm_rows(cmd));
    }
    for cmd in [RENDER, COMPARE, SUITE, VIEW] {
        v.extend(gather_rows(cmd));
    }
    for cmd in [RENDER, COMPARE, SUITE] {
        v.extend(rpnn_rows(cmd));
    }
    for cmd in [COMPARE, SUITE] {
        v.extend(eval_rows(cmd));
    }
    v
}

/// Runs `cmd flag=value` (the `=` form, so a negative value is a value), within 10 s.
fn run(cmd: &[&str], flag: &str, value: &str) -> (std::process::Output, Duration) {
    let arg = format!("{flag}={value}");
    let mut args = cmd.to_vec();
    args.push(&arg);
    let start = Instant::now();
    let o = nimbus_within(&args, 10).unwrap_or_else(|| panic!("{args:?} still ran after 10 s"));
    (o, start.elapsed())
}

/// Checks one row: every bad value refused by clap naming the flag, the good value accepted.
/// Returns the failures as lines.
fn check(r: &Row) -> Vec<String> {
    let mut fails = Vec::new();
    // clap's words: `invalid value 'X' for '--flag <FLAG>'`.
    let named = format!("for '{} <", r.flag);
    for bad in NONFINITE.iter().chain(r.bad) {
        let (o, t) = run(r.cmd, r.flag, bad);
        let err = String::from_utf8_lossy(&o.stderr);
        if o.status.code() != Some(2) || !err.contains(&named) || !err.contains("invalid value") {
            fails.push(format!(
                "{:?} {}={bad}: exit {:?}, not refused naming the flag: {err}",
                r.cmd,
                r.flag,
                o.status.code()
            ));
        } else if t > Duration::from_secs(5) {
            fails.push(format!("{:?} {}={bad}: refused after {t:?}", r.cmd, r.flag));
        }
    }
    let (o, _) = run(r.cmd, r.flag, r.good);
    let all = text(&o);
    if o.status.code() != Some(1) || all.contains("invalid value") {
        fails.push(format!(
            "{:?} {}={}: the good value was refused or the command did not fail later (exit {:?}): {all}",
            r.cmd,
            r.flag,
            r.good,
            o.status.code()
        ));
    }
    fails
}

#[test]
fn every_numeric_flag_is_checked_at_parse_time() {
    let rows = rows();
    let values: usize = rows.iter().map(|r| NONFINITE.len() + r.bad.len()).sum();
    // Four threads: the runs wait on process start-up more than on the CPU.
    let chunks: Vec<&[Row]> = rows.chunks(rows.len().div_ceil(4)).collect();
    let fails: Vec<String> = std::thread::scope(|s| {
        let hs: Vec<_> = chunks
            .iter()
            .map(|c| s.spawn(move || c.iter().flat_map(check).collect::<Vec<_>>()))
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    assert!(
        fails.is_empty(),
        "{} of {} values (over {} flag rows) misjudged:\n{}",
        fails.len(),
        values + rows.len(),
        rows.len(),
        fails.join("\n")
    );
    eprintln!(
        "{} flag rows ({} distinct flags): {values} bad values refused, {} good accepted",
        rows.len(),
        {
            let mut f: Vec<&str> = rows.iter().map(|r| r.flag).collect();
            f.sort();
            f.dedup();
            f.len()
        },
        rows.len()
    );
}

/// The user's case: a time step of 1e308 s with the sun playing cost 40 s per frame before the
/// NaN image was refused; now it is refused while parsing.
#[test]
fn view_dt_1e308_is_refused_at_once() {
    let start = Instant::now();
    let o = nimbus_within(&["view", "--dt", "1e308", "--play-sun"], 10).expect("no hang");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        start.elapsed() < Duration::from_secs(2),
        "{:?}",
        start.elapsed()
    );
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("'--dt <DT>'") && err.contains("(0, 3600]"),
        "{err}"
    );
}

/// A negative angle or corner written as its own argument is a value, not a flag.
#[test]
fn negative_values_are_values() {
    for args in [
        vec!["view", "no/such.toml", "--sun-speed", "-30"],
        vec!["animate", "no/such.toml", "--sun-speed", "-30"],
        vec![
            "info",
            "no/such.vol",
            "--aabb-min",
            "-1,-1,-1",
            "--aabb-max",
            "1,1,1",
        ],
    ] {
        let o = nimbus_within(&args, 10).expect("no hang");
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        assert!(text(&o).contains("no/such."), "{args:?}: {}", text(&o));
    }
}

/// The sun's turn per frame depends on two flags: refused past a whole turn, naming both.
#[test]
fn sun_turn_per_frame_names_both_flags() {
    for (args, flags) in [
        (
            vec![
                "view",
                "no/such.toml",
                "--headless",
                "--sun-speed",
                "36000",
                "--dt",
                "1",
            ],
            ["--sun-speed", "--dt"],
        ),
        (
            vec![
                "view",
                "no/such.toml",
                "--headless",
                "--sun-speed=-400",
                "--dt",
                "1",
            ],
            ["--sun-speed", "--dt"],
        ),
        (
            vec![
                "animate",
                "no/such.toml",
                "--sun-speed",
                "3601",
                "--fps",
                "10",
            ],
            ["--sun-speed", "--fps"],
        ),
    ] {
        let o = nimbus_within(&args, 10).expect("no hang");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            flags.iter().all(|f| err.contains(f)) && err.contains("per frame"),
            "{args:?}: {err}"
        );
    }
    // A whole turn per frame is allowed; the window's frame time is its own (--dt is
    // headless only); then the missing scene is the error.
    for args in [
        vec![
            "view",
            "no/such.toml",
            "--headless",
            "--sun-speed=-360",
            "--dt",
            "1",
        ],
        vec!["view", "no/such.toml", "--sun-speed", "36000", "--dt", "1"],
        vec![
            "animate",
            "no/such.toml",
            "--sun-speed",
            "3600",
            "--fps",
            "10",
        ],
    ] {
        let o = nimbus_within(&args, 10).expect("no hang");
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        assert!(text(&o).contains("no/such.toml"), "{args:?}: {}", text(&o));
    }
}
