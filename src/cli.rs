//! Command-line interface.

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Debug, Parser)]
#[command(
    name = "leveld",
    version,
    about = "Automatic static headlamp leveling from wheel speeds and a 6-axis IMU"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    Table,
    Json,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the simulator.
    Simulate {
        #[command(subcommand)]
        what: SimulateCmd,
    },
}

#[derive(Debug, Subcommand)]
pub enum SimulateCmd {
    /// Reproduce the simulation study of Kim et al. 2023 (Table 1, Fig. 13-18).
    PaperGrid {
        /// Movements per setting (the paper uses 50); each gives two windows.
        #[arg(long, default_value_t = 50)]
        runs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, value_enum, default_value_t = Format::Table)]
        format: Format,
        /// Worker threads (default: available cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

pub fn run(cli: Cli) -> Result<i32> {
    match cli.command {
        Command::Simulate { what } => match what {
            SimulateCmd::PaperGrid {
                runs,
                seed,
                format,
                threads,
            } => {
                crate::report::paper_grid(runs, seed, format == Format::Json, threads)?;
                Ok(0)
            }
        },
    }
}
