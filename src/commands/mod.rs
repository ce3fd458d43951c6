//! One module per subcommand group: each holds its clap arguments and a `run` that calls the
//! library.

pub mod splat;
