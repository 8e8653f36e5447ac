//! `nimbus stress`: stiff and extreme inputs × every method over `nimbus_eval::stress`, each
//! in a child process under a time limit.

use std::path::PathBuf;

use anyhow::{Result, bail};
use nimbus_eval::stress;

/// `nimbus stress`.
#[derive(clap::Args)]
pub(crate) struct StressArgs {
    /// Methods: pt, pt-gpu, pm, pm-march, pm-elek2012 (the paper's photon mapping), rpnn,
    /// rpnn-dirs (comma-separated).
    #[arg(long, default_value = "pt,pt-gpu,pm,rpnn")]
    methods: String,
    /// `all`, `subset` (the one stiffest case per axis that the tests run), or case ids.
    #[arg(long, default_value = "all")]
    cases: String,
    /// Seconds one method may take on one case before it counts as a hang, 1..=86400.
    #[arg(long, default_value_t = 120, value_parser = crate::flags::int_in(1u64, 86_400))]
    time_limit: u64,
    /// Writes OUT/stability.md and the case scenes to OUT/stability/cases/.
    #[arg(long, short, default_value = "docs")]
    out: PathBuf,
}

pub(crate) fn run(args: &StressArgs) -> Result<()> {
    let methods = nimbus_eval::method::parse_methods(&args.methods)?;
    let cases = match args.cases.as_str() {
        "all" => stress::cases(),
        "subset" => stress::subset(),
        list => {
            let all = stress::cases();
            list.split(',')
                .map(|id| {
                    all.iter()
                        .find(|c| c.id == id.trim())
                        .cloned()
                        .ok_or_else(|| anyhow::anyhow!("--cases: no case `{id}`"))
                })
                .collect::<Result<Vec<_>>>()?
        }
    };
    let exe = std::env::current_exe()?;
    let limit = std::time::Duration::from_secs(args.time_limit);
    let dir = args.out.join("stability").join("cases");
    let outcomes = stress::run_matrix(&exe, &cases, &methods, &dir, limit, &mut |o| {
        say!(
            "{:38} {:7} {} {} ({:.1} s) {}",
            o.case,
            o.method.name(),
            if o.pass { "pass" } else { "FAIL" },
            o.verdict,
            o.time_s,
            o.detail.lines().next().unwrap_or("")
        )
    })?;
    let p = stress::write_markdown(&outcomes, &methods, limit, &args.out)?;
    let fails = outcomes.iter().filter(|o| !o.pass).count();
    say!(
        "{} of {} runs pass -> {}",
        outcomes.len() - fails,
        outcomes.len(),
        p.display()
    );
    if fails > 0 {
        bail!("{fails} stress runs failed (see {})", p.display());
    }
    Ok(())
}
