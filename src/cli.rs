//! Command-line interface.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

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

/// Output of `replay`, `status` and `bench`: a table for people, JSON for programs.
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    Table,
    Json,
}

/// Output of `simulate paper-grid`.
#[cfg(feature = "sim")]
#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum GridFormat {
    Table,
    Json,
    /// Pooled over the settings of each bias or noise value.
    Summary,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Shell {
    Bash,
    Zsh,
    Fish,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the pipeline on a candump log (`-` reads standard input).
    Replay {
        input: PathBuf,
        /// Config file (default: /etc/leveld/leveld.toml, else the built-in one).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Write the LEVELING frames here in `candump -L` format, stamped with the log clock.
        #[arg(long, short)]
        output: Option<PathBuf>,
        /// Only frames from this interface (default: every interface in the log).
        #[arg(long)]
        interface: Option<String>,
        #[arg(long, value_enum, default_value_t = Format::Table)]
        format: Format,
        /// Stop at the first malformed line.
        #[arg(long)]
        strict: bool,
        /// Replay with this calibration file, as the daemon would read it (default:
        /// none: the config's reference pitch, flagged uncalibrated).
        #[arg(long)]
        calibration: Option<PathBuf>,
    },
    /// Run the daemon on SocketCAN (systemd: Type=notify).
    Run {
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// End-of-line calibration: on a level floor at standstill, store the reference pitch.
    Calibrate {
        #[arg(long)]
        config: Option<PathBuf>,
        /// Calibrate from a candump log instead of the live bus.
        #[arg(long)]
        log: Option<PathBuf>,
        /// With --log: only frames from this interface.
        #[arg(long)]
        interface: Option<String>,
        /// Seconds of settled standstill to average.
        #[arg(long, default_value_t = 5.0)]
        duration: f64,
        /// State file to seed (default: the config's state.path).
        #[arg(long)]
        state: Option<PathBuf>,
        /// Calibration file to write (default: the config's state.calibration_path).
        #[arg(long)]
        calibration: Option<PathBuf>,
        /// Measure and print, store nothing.
        #[arg(long)]
        dry_run: bool,
    },
    /// Validate the config and its DBC, and print what will be decoded.
    CheckConfig {
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// What the running daemon reports (status, estimate, inputs, last save); when it
    /// is not running, says so and shows the saved state.
    Status {
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = Format::Table)]
        format: Format,
    },
    /// Print a shell completion script.
    Completions {
        #[arg(value_enum)]
        shell: Shell,
    },
    /// Print the man page (roff); with a directory, write leveld.1 and one page per
    /// subcommand (leveld-status.1, ...) there.
    #[command(hide = true)]
    Man { dir: Option<PathBuf> },
    /// Benchmarks.
    #[cfg(feature = "sim")]
    Bench {
        #[command(subcommand)]
        what: BenchCmd,
    },
    /// Run the simulator.
    #[cfg(feature = "sim")]
    Simulate {
        #[command(subcommand)]
        what: SimulateCmd,
    },
}

#[cfg(feature = "sim")]
#[derive(Debug, Subcommand)]
pub enum BenchCmd {
    /// leveld against the Kasaba- and Nilsson-style baselines on simulated drives.
    Accuracy {
        /// Scenario files (default: every file in scenarios/).
        #[arg(long, num_args = 1..)]
        scenarios: Vec<PathBuf>,
        #[arg(long, value_enum, default_value_t = Format::Table)]
        format: Format,
        /// Write PNG plots to this folder.
        #[arg(long)]
        plots: Option<PathBuf>,
        #[arg(long)]
        threads: Option<usize>,
        /// Compare leveld with each improvement beyond the paper switched off instead.
        #[arg(long)]
        ablation: bool,
        /// Run every scenario with this many seeds (its own, then the next ones) and
        /// print the pooled results.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=1000))]
        seeds: u64,
        /// Change a scenario setting before running, KEY=VALUE with a dotted key and a
        /// TOML value, for example `sensors.imu_rate_hz=200` or
        /// `realistic.pitch_freq_hz=[1.0,1.1]` (repeatable; applies to every scenario).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
}

#[cfg(feature = "sim")]
#[derive(Debug, Subcommand)]
pub enum SimulateCmd {
    /// Simulate a drive and write it as a candump log through the DBC, with a truth file.
    Drive {
        /// A named drive (multi-stop, load-change).
        #[arg(long, default_value = "multi-stop", conflicts_with = "scenario")]
        preset: String,
        /// A scenario file instead of a preset: a benchmark drive (`scenarios/*.toml`,
        /// `scenarios/realistic/*.toml`) or a simulator scenario (TOML).
        #[arg(long)]
        scenario: Option<std::path::PathBuf>,
        /// Load case of a benchmark drive (its `loads` names; default the first).
        #[arg(long, requires = "scenario")]
        load: Option<String>,
        /// Seed; a benchmark drive's own seed when not given (the `--seeds N` of
        /// `leveld bench accuracy` are its seed, seed + 1, ...).
        #[arg(long)]
        seed: Option<u64>,
        /// candump log to write (`-` for standard output).
        #[arg(long, short)]
        output: std::path::PathBuf,
        /// Truth to write as JSON lines at 10 Hz.
        #[arg(long)]
        truth: Option<std::path::PathBuf>,
        #[arg(long, default_value = "vcan0")]
        interface: String,
        /// Added to simulation time in the log, s.
        #[arg(long, default_value_t = 1000.0)]
        t0: f64,
        #[arg(long, default_value = "dbc/leveld.dbc")]
        dbc: std::path::PathBuf,
    },
    /// Reproduce the simulation study of Kim et al. 2023 (Table 1, Fig. 13-18).
    PaperGrid {
        /// Movements per setting (the paper uses 50); each gives two windows.
        #[arg(long, default_value_t = 50)]
        runs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, value_enum, default_value_t = GridFormat::Table)]
        format: GridFormat,
        /// Worker threads (default: available cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

pub fn run(cli: Cli) -> Result<i32> {
    use crate::commands;
    match cli.command {
        Command::Replay {
            input,
            config,
            output,
            interface,
            format,
            strict,
            calibration,
        } => commands::replay::run(
            &input,
            config.as_deref(),
            output.as_deref(),
            interface,
            format == Format::Json,
            strict,
            calibration.as_deref(),
        ),
        Command::Run { config } => crate::daemon::live::run(config.as_deref()),
        Command::Calibrate {
            config,
            log,
            interface,
            duration,
            state,
            calibration,
            dry_run,
        } => commands::calibrate::run(
            config.as_deref(),
            log.as_deref(),
            interface.as_deref(),
            duration,
            state.as_deref(),
            calibration.as_deref(),
            dry_run,
        ),
        Command::CheckConfig { config } => commands::check_config::run(config.as_deref()),
        Command::Status { config, format } => {
            commands::status::run(config.as_deref(), format == Format::Json)
        }
        Command::Completions { shell } => {
            let shell = match shell {
                Shell::Bash => clap_complete::Shell::Bash,
                Shell::Zsh => clap_complete::Shell::Zsh,
                Shell::Fish => clap_complete::Shell::Fish,
            };
            let mut cmd = <Cli as clap::CommandFactory>::command();
            clap_complete::generate(shell, &mut cmd, "leveld", &mut std::io::stdout());
            Ok(0)
        }
        Command::Man { dir } => {
            let cmd = <Cli as clap::CommandFactory>::command();
            match dir {
                Some(dir) => clap_mangen::generate_to(cmd, &dir)
                    .with_context(|| format!("writing man pages to {}", dir.display()))?,
                None => clap_mangen::Man::new(cmd).render(&mut std::io::stdout())?,
            }
            Ok(0)
        }
        #[cfg(feature = "sim")]
        Command::Bench { what } => match what {
            BenchCmd::Accuracy {
                scenarios,
                format,
                plots,
                threads,
                ablation,
                seeds,
                set,
            } => commands::bench::accuracy(
                &scenarios,
                format == Format::Json,
                plots.as_deref(),
                threads,
                ablation,
                seeds,
                &set,
            ),
        },
        #[cfg(feature = "sim")]
        Command::Simulate { what } => match what {
            SimulateCmd::Drive {
                preset,
                scenario,
                load,
                seed,
                output,
                truth,
                interface,
                t0,
                dbc,
            } => {
                commands::simulate::drive(
                    &preset,
                    scenario.as_deref(),
                    load.as_deref(),
                    seed,
                    &output,
                    truth.as_deref(),
                    &interface,
                    t0,
                    &dbc,
                )?;
                Ok(0)
            }
            SimulateCmd::PaperGrid {
                runs,
                seed,
                format,
                threads,
            } => {
                let format = match format {
                    GridFormat::Table => commands::simulate::GridFormat::Table,
                    GridFormat::Json => commands::simulate::GridFormat::Json,
                    GridFormat::Summary => commands::simulate::GridFormat::Summary,
                };
                commands::simulate::paper_grid(runs, seed, format, threads)?;
                Ok(0)
            }
        },
    }
}
