//! The `prism` command line: parses arguments and calls the library crates.

mod commands;

use clap::{Parser, Subcommand};

/// prism: real-time single-image human frontal view synthesis (PrismMirror) on Burn.
#[derive(Parser, Debug)]
#[command(name = "prism", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The subcommands; each variant's arguments and `run` live in `commands/`.
#[derive(Subcommand, Debug)]
enum Command {
    /// 3D Gaussian splatting: render standard 3DGS PLY files.
    #[command(subcommand)]
    Splat(commands::splat::SplatCommand),
}

fn main() {
    let cli = Cli::parse();
    let result: anyhow::Result<()> = match cli.command {
        Command::Splat(cmd) => cmd.run(),
    };
    if let Err(err) = result {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}
