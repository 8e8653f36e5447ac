//! One module per subcommand: its arguments (a clap `Args` struct) and its `run`.

pub(crate) mod animate;
pub(crate) mod bench_suite;
pub(crate) mod compare;
pub(crate) mod datagen;
pub(crate) mod generate;
pub(crate) mod info;
pub(crate) mod render;
pub(crate) mod stress;
pub(crate) mod view;
