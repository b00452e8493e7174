//! `rove`: the gateway binary. For now it carries the demo; the vehicle and operator roles, the
//! DDS binding, `status` and `check-config` arrive with issue 4 (see DESIGN.md §8).

mod config;
mod demo;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// rove — share control of robots between operators, safely.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a simulated vehicle and three scripted operators and print every handover
    /// (join, preempt, quit, request/accept/finish, crash → failsafe).
    Demo {
        /// Do not pace the story in real time; print it at once.
        #[arg(long)]
        fast: bool,
    },
    /// Validate a vehicle or operator config; print the effective config with `--print`.
    CheckConfig {
        /// The TOML file.
        file: std::path::PathBuf,
        /// Print the effective configuration (defaults filled in).
        #[arg(long)]
        print: bool,
    },
}

/// Exit code for a configuration error, distinct from runtime failures so that systemd's
/// `RestartPreventExitStatus=` stops restart loops on a bad edit.
const EXIT_CONFIG: u8 = 78; // EX_CONFIG from sysexits.h

fn main() -> ExitCode {
    let cli = Cli::parse();
    let is_config = matches!(cli.command, Command::CheckConfig { .. });
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("rove: {err:#}");
            if is_config {
                ExitCode::from(EXIT_CONFIG)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo { fast } => {
            demo::run(!fast, |line| println!("{line}"))?;
            Ok(())
        }
        Command::CheckConfig { file, print } => {
            let loaded = config::load_any(&file)?;
            let role = match &loaded {
                config::AnyConfig::Vehicle(_) => "vehicle",
                config::AnyConfig::Operator(_) => "operator",
            };
            if print {
                let text = match &loaded {
                    config::AnyConfig::Vehicle(c) => format!("{c:#?}"),
                    config::AnyConfig::Operator(c) => format!("{c:#?}"),
                };
                println!("{text}");
            }
            println!("{}: valid {role} config", file.display());
            Ok(())
        }
    }
}
