//! `lcc-stream`: OpenLCB streams from the command line.

// First, so that its macros are seen by every module after it.
#[macro_use]
mod stdout;

mod args;
mod board;
mod cdi;
mod clock;
mod config;
mod control;
mod demo;
mod events;
mod files;
mod firmware;
mod hub;
mod memory;
mod monitor;
mod net;
mod nodes;
mod outcome;
mod pace;
mod peer;
mod printer;
mod progress;
mod read;
mod reconnect;
mod recv;
mod send;
mod serve;
mod settings;
mod sim;
mod throttle;
mod throttle_tty;
mod train;
mod train_config;
mod ui;
mod watch;
mod write;

use std::io::IsTerminal as _;
use std::process::ExitCode;

use clap::{CommandFactory as _, Parser, Subcommand};
use tracing_subscriber::EnvFilter;

/// Move data over OpenLCB (LCC) streams, or simulate it.
#[derive(Debug, Parser)]
#[command(name = "lcc-stream", version, about, after_help = MAIN_HELP)]
struct Cli {
    /// Log to stderr what happens to connections and streams: -v info (clients connecting and
    /// leaving, streams opened and finished), -vv debug, -vvv trace (with `hub --trace`, every
    /// frame). RUST_LOG, if set, takes precedence (e.g. RUST_LOG=openlcb_tokio=debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Print nothing on success but what was asked for (data, --json); errors still go to
    /// stderr. No progress bars.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

/// The main help's epilogue: where the exit statuses are listed.
const MAIN_HELP: &str = "\
Each command's --help lists the exit statuses it can return, with the `result` word of its
--json output. Shell completions: `lcc-stream completions bash` (zsh, fish, elvish,
powershell); the manual page: `lcc-stream man > lcc-stream.1`.";

/// Starts the log output that `--verbose` or `RUST_LOG` asks for (none by default).
fn init_logs(verbose: u8) {
    let level = match verbose {
        0 => "off",
        1 => "info",
        2 => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(level));
    let ansi = std::io::stderr().is_terminal();
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).init();
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run transfers on a simulated network (virtual time, bit-timed CAN bus) and report.
    Sim(sim::SimArgs),
    /// Run a GridConnect TCP hub (and an OpenLCB-TCP one) that relays every frame to every other client.
    Hub(hub::HubArgs),
    /// Join the network as a node and send a file as one stream.
    Send(send::SendArgs),
    /// Join the network as a node and write every incoming stream to a file.
    Recv(recv::RecvArgs),
    /// List the nodes on the network: Node ID, CAN alias, SNIP strings and protocols.
    Nodes(nodes::NodesArgs),
    /// Serve memory spaces (CDI, configuration, ACDI, a firmware target) as a node, until Ctrl-C.
    Serve(serve::ServeArgs),
    /// Back up a memory space of a node into a file.
    Read(read::ReadArgs),
    /// Restore a memory space of a node from a file.
    Write(write::WriteArgs),
    /// Upgrade a node's firmware (Freeze, the image into space 0xEF, Unfreeze).
    Firmware(firmware::FirmwareArgs),
    /// Save a node's CDI (space 0xFF) as clean XML.
    Cdi(cdi::CdiArgs),
    /// Show, get and set a node's settings by their CDI names; back them up and restore them
    /// in JMRI's format.
    Config(config::ConfigArgs),
    /// Reboot a node (Memory Configuration Reset/Reboot), as after a power cycle.
    Reboot(control::RebootArgs),
    /// Put every setting of a node back to its default (Memory Configuration Factory Reset).
    FactoryReset(control::FactoryResetArgs),
    /// Show the bus decoded, live or from a saved trace: one line per message, by name.
    Monitor(monitor::MonitorArgs),
    /// Watch event reports, send one, or ask who produces and consumes what.
    Events(events::EventsArgs),
    /// The layout's fast clock (Broadcast Time): run a generator, follow a clock, or set,
    /// start and stop one on the bus.
    Clock(clock::ClockArgs),
    /// A virtual command station and train (Traction Control, Train Search, FDI): prints
    /// every command its trains get, and creates trains for the addresses throttles allocate.
    Train(train::TrainArgs),
    /// Find a train by its DCC address, take control of it and drive it (speed, direction,
    /// functions, emergency stop), then release it.
    Throttle(throttle::ThrottleArgs),
    /// Serve a web page (on 127.0.0.1:8080 by default) to see the nodes, configure them,
    /// back them up, upgrade them and watch the bus from a browser, until Ctrl-C.
    Ui(ui::UiArgs),
    /// Start a hub and two nodes on 127.0.0.1, move generated data through real sockets, verify it.
    Demo(demo::DemoArgs),
    /// Print a shell completion script on stdout (e.g. `lcc-stream completions bash >
    /// ~/.local/share/bash-completion/completions/lcc-stream`).
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff) on stdout, e.g. `lcc-stream man > lcc-stream.1`; a
    /// subcommand's with its name (`lcc-stream man config restore > lcc-stream-config-restore.1`),
    /// or every page into a folder with --dir.
    Man {
        /// The subcommand whose page to print, e.g. `send` or `config restore`.
        command: Vec<String>,
        /// Write the pages of the tool and of every subcommand into this folder
        /// (lcc-stream.1, lcc-stream-send.1, lcc-stream-config-restore.1, ...).
        #[arg(long, value_name = "DIR", conflicts_with = "command")]
        dir: Option<std::path::PathBuf>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logs(cli.verbose);
    if let Err(error) = settings::load() {
        eprintln!("lcc-stream: {error}");
        return ExitCode::from(outcome::Outcome::Usage.status());
    }
    if cli.quiet {
        net::set_quiet();
    }
    let result = match cli.command {
        Command::Sim(args) => sim::run(&args),
        Command::Hub(args) => hub::run(&args),
        Command::Send(args) => send::run(&args),
        Command::Recv(args) => recv::run(&args),
        Command::Nodes(args) => nodes::run(&args),
        Command::Serve(args) => serve::run(&args),
        Command::Read(args) => read::run(&args),
        Command::Write(args) => write::run(&args),
        Command::Firmware(args) => firmware::run(&args),
        Command::Cdi(args) => cdi::run(&args),
        Command::Config(args) => config::run(&args),
        Command::Events(args) => events::run(&args),
        Command::Clock(args) => clock::run(&args),
        Command::Train(args) => train::run(&args),
        Command::Throttle(args) => throttle::run(&args),
        Command::Reboot(args) => control::reboot(&args),
        Command::FactoryReset(args) => control::factory_reset(&args),
        Command::Monitor(args) => monitor::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Ui(args) => ui::run(&args),
        Command::Completions { shell } => {
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "lcc-stream", &mut script);
            stdout::write_bytes(&script)
                .map(|()| ExitCode::SUCCESS)
                .map_err(|e| format!("cannot write the completion script: {e}"))
        }
        Command::Man { command, dir } => man(&command, dir.as_deref()),
    };
    match result {
        Ok(code) => code,
        Err(error) => {
            eprintln!("lcc-stream: {error}");
            ExitCode::FAILURE
        }
    }
}

/// Writes the manual page (the tool, its options and its commands) to stdout.
/// The manual page of the subcommand `path` names (the tool's for none) on stdout, or every
/// page into `dir`.
fn man(path: &[String], dir: Option<&std::path::Path>) -> Result<ExitCode, String> {
    let mut cli = Cli::command().disable_help_subcommand(true);
    if let Some(dir) = dir {
        clap_mangen::generate_to(cli, dir)
            .map_err(|e| format!("cannot write the manual pages into {}: {e}", dir.display()))?;
        return Ok(ExitCode::SUCCESS);
    }
    // Built, each subcommand is named as its page is: lcc-stream-config-restore.
    cli.build();
    let mut command = &cli;
    for name in path {
        let Some(sub) = command.find_subcommand(name) else {
            let known: Vec<&str> = command.get_subcommands().map(clap::Command::get_name).collect();
            let parent = command.get_display_name().unwrap_or("lcc-stream");
            eprintln!("lcc-stream man: `{parent}` has no subcommand `{name}` (it has: {})", known.join(", "));
            return Ok(ExitCode::from(outcome::Outcome::Usage.status()));
        };
        command = sub;
    }
    let page = clap_mangen::Man::new(command.clone());
    let mut roff = Vec::new();
    page.render(&mut roff).map_err(|e| format!("cannot render the manual page: {e}"))?;
    stdout::write_bytes(&roff).map_err(|e| format!("cannot write the manual page: {e}"))?;
    Ok(ExitCode::SUCCESS)
}
