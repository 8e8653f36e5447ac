//! `nimbus generate`: a procedural cloud written as .vol or .npy.

use std::path::PathBuf;

use anyhow::{Result, bail};
use nimbus_scene::{CloudKind, generate, io};

#[derive(clap::Args)]
pub(crate) struct GenerateArgs {
    /// cumulus, congestus, stratus or cirrus
    kind: String,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Resolution X,Y,Z (default: the kind's proportions at 128 along x).
    #[arg(long, value_delimiter = ',')]
    res: Option<Vec<i64>>,
    #[arg(long, short)]
    out: PathBuf,
}

pub(crate) fn run(a: GenerateArgs) -> Result<()> {
    let GenerateArgs {
        kind,
        seed,
        res,
        out,
    } = a;
    let kind: CloudKind = kind.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
    // The output is checked before the (possibly long) generation.
    io::check_grid_output(&out)?;
    let res = match res {
        Some(r) if r.len() != 3 => bail!("--res needs three values X,Y,Z, got {r:?}"),
        // The generator's own limits, said for --res before the output file is opened
        // (a .vol is streamed: sparse).
        Some(r) => generate::check_generator_resolution(
            [r[0], r[1], r[2]],
            out.extension().is_some_and(|e| e == "vol"),
            "--res",
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?,
        None => kind.default_resolution(128),
    };
    let bounds = generate::default_aabb(res);
    let st = if out.extension().is_some_and(|e| e == "vol") {
        // Streamed into the file while it is generated (no grid in memory).
        let mut st = None;
        io::write_atomically(&out, |t| {
            st = Some(generate::generate_vol(kind, seed, res, t, bounds)?);
            Ok(())
        })?;
        st.expect("written")
    } else {
        let grid = generate::generate(kind, seed, res).map_err(|e| anyhow::anyhow!("{e}"))?;
        io::write_grid(&out, &grid, bounds)?;
        grid.stats()
    };
    say!(
        "{} seed {seed}: {}x{}x{}, mean {:.4}, non-zero {:.1} % -> {}",
        kind.name(),
        res[0],
        res[1],
        res[2],
        st.mean,
        100.0 * st.nonzero_fraction,
        out.display()
    );
    Ok(())
}
