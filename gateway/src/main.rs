//! `rove`: the gateway binary. For now it carries the demo; the vehicle and operator roles, the
//! DDS binding, `status` and `check-config` arrive with issue 4 (see DESIGN.md §8).

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("rove: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo { fast } => {
            demo::run(!fast, |line| println!("{line}"))?;
            Ok(())
        }
    }
}
