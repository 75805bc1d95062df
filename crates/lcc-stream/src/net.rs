//! What `hub`, `send`, `recv` and `demo` share: connection options, exit statuses, number
//! formatting and JSON output.

use std::process::ExitCode;

use clap::{Args, ValueEnum};
use openlcb_tokio::{Error, Node, NodeOptions, Protocol};

/// The GridConnect port of `lcc-stream hub` (the usual port of GridConnect hubs).
pub(crate) const GRIDCONNECT_ADDR: &str = "127.0.0.1:12021";
/// The OpenLCB-TCP port of `lcc-stream hub`.
pub(crate) const TCP_ADDR: &str = "127.0.0.1:12022";

/// The text of [`EXIT_HELP`], for commands that add to it with `concat!`.
macro_rules! exit_help {
    () => {
        "\
Exit status: 0 success; 1 other failure; 2 bad arguments (also a listener that cannot
be opened); 3 hub unreachable; 4 stream rejected; 5 peer timed out or not found;
6 connection to the hub lost; 7 stream terminated or incomplete; 8 file error; 9 data did
not verify (demo); 10 another node on the network has this Node ID; 130 interrupted
(Ctrl-C or SIGTERM: open streams are terminated, partial files kept)."
    };
}
pub(crate) use exit_help;

/// Exit statuses, one per kind of failure a person can act on.
pub(crate) const EXIT_HELP: &str = exit_help!();

/// Another node holds this Node ID (found at login or later).
pub(crate) const EXIT_DUPLICATE_NODE_ID: u8 = 10;
/// Interrupted by SIGINT or SIGTERM.
pub(crate) const EXIT_INTERRUPTED: u8 = 130;
/// Bad arguments, including a listener that cannot be opened (clap's status for usage errors).
pub(crate) const EXIT_USAGE: u8 = 2;

/// The exit status for `error`.
pub(crate) fn exit_status(error: &Error) -> u8 {
    match error {
        Error::Bind { .. } => EXIT_USAGE,
        Error::DuplicateNodeId { .. } => EXIT_DUPLICATE_NODE_ID,
        Error::Connect { .. } | Error::Login(_) => 3,
        Error::Rejected { .. } => 4,
        Error::TimedOut { .. } | Error::Unreachable(_) => 5,
        Error::ConnectionLost(_) | Error::WriteStalled(_) | Error::Protocol(_) | Error::Closed => 6,
        Error::Terminated { .. } | Error::CountMismatch { .. } => 7,
        _ => 1,
    }
}

/// A file could not be read or written.
pub(crate) const EXIT_FILE: u8 = 8;
/// The demo's data did not arrive intact.
pub(crate) const EXIT_VERIFY: u8 = 9;

/// A short word for `error` in JSON reports.
pub(crate) fn result_word(error: &Error) -> &'static str {
    match exit_status(error) {
        3 => "unreachable_hub",
        4 => "rejected",
        5 => "timed_out",
        6 => "connection_lost",
        7 => "terminated",
        EXIT_DUPLICATE_NODE_ID => "duplicate_node_id",
        _ => "error",
    }
}

/// The framing spoken to the hub.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum ProtocolArg {
    /// CAN frames as GridConnect text (JMRI and OpenMRN hubs), with CAN alias login.
    Gridconnect,
    /// Binary OpenLCB-TCP (full-format messages).
    Tcp,
}

impl From<ProtocolArg> for Protocol {
    fn from(p: ProtocolArg) -> Self {
        match p {
            ProtocolArg::Gridconnect => Protocol::GridConnect,
            ProtocolArg::Tcp => Protocol::Tcp,
        }
    }
}

/// `--connect` or `--serial`, and `--protocol`.
#[derive(Debug, Args)]
pub(crate) struct ConnectArgs {
    /// The hub, HOST:PORT [default: 127.0.0.1:12021; 127.0.0.1:12022 with --protocol tcp,
    /// the two listeners of `lcc-stream hub`].
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "serial", value_parser = crate::args::hub_addr)]
    pub(crate) connect: Option<String>,
    /// A serial port instead of a hub: a USB GridConnect adapter on the CAN bus (RR-CirKits
    /// LCC Buffer-USB, SPROG CANISB), e.g. /dev/ttyACM0 or COM3.
    #[arg(long, value_name = "DEVICE")]
    pub(crate) serial: Option<String>,
    /// A SocketCAN interface instead of a hub, e.g. can0 (Linux; built with the `socketcan`
    /// feature).
    #[cfg(feature = "socketcan")]
    #[arg(long, value_name = "IFACE", conflicts_with_all = ["connect", "serial"])]
    pub(crate) can: Option<String>,
    /// The serial port's line rate in bits per second (USB adapters ignore it).
    #[arg(long, value_name = "N", default_value_t = openlcb_tokio::serial::DEFAULT_BAUD, requires = "serial")]
    pub(crate) baud: u32,
    /// The framing spoken to the hub.
    #[arg(long, value_enum, default_value_t = ProtocolArg::Gridconnect)]
    pub(crate) protocol: ProtocolArg,
}

impl ConnectArgs {
    /// Where the node connects: the serial device, or the hub's address.
    pub(crate) fn addr(&self) -> &str {
        #[cfg(feature = "socketcan")]
        if let Some(interface) = &self.can {
            return interface;
        }
        match (&self.serial, &self.connect, self.protocol) {
            (Some(device), _, _) => device,
            (None, Some(addr), _) => addr,
            (None, None, ProtocolArg::Gridconnect) => GRIDCONNECT_ADDR,
            (None, None, ProtocolArg::Tcp) => TCP_ADDR,
        }
    }

    /// Joins the network as a node with `options`: through the serial port, or the hub.
    pub(crate) async fn node(&self, options: NodeOptions) -> Result<Node, Error> {
        #[cfg(feature = "socketcan")]
        if let Some(interface) = &self.can {
            let bus = openlcb_tokio::can::FrameStream::new(openlcb_tokio::can::open_socketcan(interface)?);
            return Node::over(bus, Protocol::GridConnect, options).await;
        }
        match &self.serial {
            Some(device) => {
                Node::over(openlcb_tokio::serial::open(device, self.baud)?, self.protocol.into(), options).await
            }
            None => Node::connect(self.addr(), self.protocol.into(), options).await,
        }
    }
    /// The GridConnect text of the hub, serial adapter or CAN interface, for a tool that only
    /// listens (nothing joins the network).
    pub(crate) async fn byte_stream(&self) -> Result<Box<dyn openlcb_tokio::ByteStream>, String> {
        if self.protocol != ProtocolArg::Gridconnect {
            return Err("only GridConnect (CAN frames) can be listened to".into());
        }
        #[cfg(feature = "socketcan")]
        if let Some(interface) = &self.can {
            let bus = openlcb_tokio::can::open_socketcan(interface).map_err(|e| e.to_string())?;
            return Ok(Box::new(openlcb_tokio::can::FrameStream::new(bus)));
        }
        match &self.serial {
            Some(device) => Ok(Box::new(openlcb_tokio::serial::open(device, self.baud).map_err(|e| e.to_string())?)),
            None => {
                let addr = self.addr();
                let socket =
                    tokio::net::TcpStream::connect(addr).await.map_err(|e| format!("cannot reach {addr}: {e}"))?;
                Ok(Box::new(socket))
            }
        }
    }
}

/// SIGINT (Ctrl-C) and SIGTERM, listened for from the moment this is made (so that neither
/// kills the process outright while a stream runs).
pub(crate) struct Interrupt {
    #[cfg(unix)]
    signals: [tokio::signal::unix::Signal; 2],
}

impl Interrupt {
    pub(crate) fn new() -> Result<Self, String> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            let listen = |kind| signal(kind).map_err(|e| format!("cannot listen for signals: {e}"));
            Ok(Interrupt { signals: [listen(SignalKind::interrupt())?, listen(SignalKind::terminate())?] })
        }
        #[cfg(not(unix))]
        Ok(Interrupt {})
    }

    /// Waits for the next SIGINT or SIGTERM.
    pub(crate) async fn wait(&mut self) {
        #[cfg(unix)]
        {
            let [int, term] = &mut self.signals;
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// The Simple Node Information of an `lcc-stream` node running `command`, so that tools
/// (`lcc-stream nodes`, JMRI) can tell what it is.
pub(crate) fn snip(command: &str) -> openlcb_tokio::SnipInfo {
    openlcb_tokio::SnipInfo {
        manufacturer: "openlcb-stream".into(),
        model: format!("lcc-stream {command}"),
        hardware_version: std::env::consts::ARCH.into(),
        software_version: env!("CARGO_PKG_VERSION").into(),
        ..openlcb_tokio::SnipInfo::default()
    }
}

/// A multi-threaded runtime for one subcommand.
pub(crate) fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread().enable_all().build().map_err(|e| format!("cannot start tokio: {e}"))
}

/// Prints `error` for a person and returns its exit status.
pub(crate) fn fail(context: &str, error: &Error) -> ExitCode {
    eprintln!("lcc-stream: {context}: {error}");
    ExitCode::from(exit_status(error))
}

/// `12.3 MB/s`, decimal units as transfer rates usually are.
pub(crate) fn rate_text(bytes_per_s: f64) -> String {
    match bytes_per_s {
        r if r >= 1e6 => format!("{:.2} MB/s", r / 1e6),
        r if r >= 1e3 => format!("{:.1} kB/s", r / 1e3),
        r => format!("{r:.0} B/s"),
    }
}

/// Bytes per second, 0 for no time.
pub(crate) fn rate(bytes: u64, seconds: f64) -> f64 {
    if seconds > 0.0 { bytes as f64 / seconds } else { 0.0 }
}

/// Prints `report` as one line of JSON on stdout.
pub(crate) fn print_json(report: &impl serde::Serialize) {
    match serde_json::to_string(report) {
        Ok(line) => println!("{line}"),
        // Only a map with non-string keys fails, and no report has one.
        Err(error) => eprintln!("lcc-stream: cannot write JSON: {error}"),
    }
}
