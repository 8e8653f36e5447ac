//! `nimbus info`: statistics of a volume file, or the GPU adapters wgpu sees.

use std::path::PathBuf;

use anyhow::{Result, bail};
use glam::DVec3;
use nimbus_scene::io;

use crate::flags;

#[derive(clap::Args)]
pub(crate) struct InfoArgs {
    /// A volume file (.vol, .npy, .vdb, .nvdb).
    #[arg(required_unless_present = "gpu")]
    file: Option<PathBuf>,
    /// List the GPU adapters wgpu sees, best first (the first is the one Nimbus opens).
    #[arg(long)]
    gpu: bool,
    /// σ_t per unit grid value, for the optical depths (finite, in [0, 1e30]).
    #[arg(long, default_value_t = 1.0,
          value_parser = flags::f64_in(0.0, flags::MAX_DENSITY_SCALE))]
    density_scale: f64,
    /// World box min corner X,Y,Z (default: the file's header box, or `[0,1]³`).
    #[arg(long, allow_hyphen_values = true, value_parser = flags::f64_triple(1e15))]
    aabb_min: Option<[f64; 3]>,
    #[arg(long, allow_hyphen_values = true, value_parser = flags::f64_triple(1e15))]
    aabb_max: Option<[f64; 3]>,
    /// The float grid of a .vdb or .nvdb file to read (default: `density`).
    #[arg(long)]
    grid: Option<String>,
}

pub(crate) fn run(a: InfoArgs) -> Result<()> {
    let InfoArgs {
        file,
        gpu,
        density_scale,
        aabb_min,
        aabb_max,
        grid,
    } = a;
    if gpu {
        let adapters = nimbus_gpu::list_adapters();
        if adapters.is_empty() {
            say!(
                "no GPU adapter (install a Vulkan driver; without a GPU: `apt-get install mesa-vulkan-drivers`)"
            );
        }
        for (i, a) in adapters.iter().enumerate() {
            say!("{} {a}", if i == 0 { "used " } else { "     " });
        }
    }
    let Some(file) = file else {
        return Ok(());
    };
    let f = io::read_grid_named(&file, grid.as_deref())?;
    let (lo, hi) = match (aabb_min, aabb_max) {
        (Some(a), Some(b)) => (DVec3::from_array(a), DVec3::from_array(b)),
        (None, None) => f.bounds.unwrap_or((DVec3::ZERO, DVec3::ONE)),
        _ => bail!("give both --aabb-min and --aabb-max, or neither"),
    };
    let aabb = nimbus_scene::Aabb::new(lo, hi).map_err(|e| anyhow::anyhow!("{e}"))?;
    let vol = nimbus_scene::Volume::new(f.grid, aabb, density_scale)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let g = vol.grid();
    let st = g.stats();
    let r = g.res();
    let tau = vol.max_axis_optical_depth();
    say!("file            {}", file.display());
    say!(
        "resolution      {} x {} x {} ({} voxels)",
        r[0],
        r[1],
        r[2],
        r[0] * r[1] * r[2]
    );
    say!(
        "bounds          {lo} .. {hi}{}",
        if f.bounds.is_some() {
            " (from file)"
        } else {
            ""
        }
    );
    match g.as_bricks() {
        Some(b) => {
            let (stored, constant, absent) = b.counts();
            say!(
                "storage         sparse: {stored} stored, {constant} constant, {absent} absent bricks of 8³ ({})",
                nimbus_scene::memory::human(g.bytes() as u128)
            );
        }
        None => say!(
            "storage         dense ({})",
            nimbus_scene::memory::human(g.bytes() as u128)
        ),
    }
    say!("cell size       {}", vol.cell_size());
    say!("min/mean/max    {} / {:.6} / {}", st.min, st.mean, st.max);
    say!("non-zero        {:.3} %", 100.0 * st.nonzero_fraction);
    say!(
        "max optical depth along x/y/z at density scale {density_scale}: {:.4} / {:.4} / {:.4}",
        tau[0],
        tau[1],
        tau[2]
    );
    Ok(())
}
