//! One module per subcommand group: each holds its clap arguments and a `run` that calls the
//! library.

pub mod ablate;
pub mod args;
pub mod bench;
pub mod body;
pub mod convert;
pub mod data;
pub mod distill;
pub mod evaluate;
pub mod infer;
pub mod info;
pub mod metrics;
pub mod quickstart;
pub mod serve;
pub mod splat;
pub mod train;
pub mod tune;
pub mod view;
