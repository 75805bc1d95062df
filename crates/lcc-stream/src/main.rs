//! `lcc-stream`: OpenLCB streams from the command line.

mod sim;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Move data over OpenLCB (LCC) streams, or simulate it.
#[derive(Debug, Parser)]
#[command(name = "lcc-stream", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run transfers on a simulated network (virtual time, bit-timed CAN bus) and report.
    Sim(sim::SimArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Sim(args) => sim::run(&args),
    };
    match result {
        Ok(code) => code,
        Err(error) => {
            eprintln!("lcc-stream: {error}");
            ExitCode::FAILURE
        }
    }
}
