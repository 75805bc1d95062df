//! What the commands share: connection options, joining with a free Node ID, how results are
//! said (`-q`), number formatting and JSON output.

use std::process::ExitCode;

use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Args, ValueEnum};
use openlcb_stream::NodeId;
use openlcb_tokio::{Error, Framing, Node, NodeOptions};

use crate::outcome::{Failure, Outcome, exit_help};

/// The GridConnect port of `lcc-stream hub` (the usual port of GridConnect hubs).
pub(crate) const GRIDCONNECT_ADDR: &str = "127.0.0.1:12021";
/// The OpenLCB-TCP port of `lcc-stream hub`.
pub(crate) const TCP_ADDR: &str = "127.0.0.1:12022";

/// `-q`: nothing printed for a person on success.
static QUIET: AtomicBool = AtomicBool::new(false);
/// stdout carries data (`read --out -`): what is said for a person goes to stderr.
static DATA_ON_STDOUT: AtomicBool = AtomicBool::new(false);

/// Silences [`say`] (`-q`).
pub(crate) fn set_quiet() {
    QUIET.store(true, Ordering::Relaxed);
}

/// Sends [`say`] to stderr, stdout being taken by data.
pub(crate) fn data_on_stdout() {
    DATA_ON_STDOUT.store(true, Ordering::Relaxed);
}

/// Prints a command's result for a person: on stdout, on stderr when stdout carries data,
/// not at all with `-q`. Errors are printed whatever `-q` says.
pub(crate) fn say(text: &str) {
    if QUIET.load(Ordering::Relaxed) {
        return;
    }
    if DATA_ON_STDOUT.load(Ordering::Relaxed) {
        eprintln!("{text}");
    } else {
        outln!("{text}");
    }
}

/// `true` with `-q`, for progress bars and notices on stderr.
pub(crate) fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// The Node IDs that commands which come and go choose from when not given one: the first
/// free one from a place that depends on the process, so that two started at once rarely try
/// the same one.
pub(crate) const TRANSIENT_FIRST: u64 = 0x0501_0101_2280;
/// The last of the transient Node IDs.
pub(crate) const TRANSIENT_LAST: u64 = 0x0501_0101_22BF;
/// Transient Node IDs tried before giving up (each taken one costs a login, 200 ms).
const TRANSIENT_TRIES: u64 = 8;

/// How long an OpenLCB-TCP connection is watched after joining for a hub that closes it.
const TCP_SETTLE: std::time::Duration = std::time::Duration::from_millis(200);

/// `--node-id` of a command that comes and goes.
#[derive(Debug, Clone, Args)]
pub(crate) struct TransientId {
    /// This node's Node ID [default: a free one of 05.01.01.01.22.80 to 05.01.01.01.22.BF;
    /// over GridConnect, serial and CAN each is checked on the bus before it is claimed].
    #[arg(long = "node-id", value_name = "NODE_ID", value_parser = crate::args::node_id)]
    pub(crate) chosen: Option<NodeId>,
}

/// The outcomes of every command that joins the network.
pub(crate) const NETWORK_OUTCOMES: &[Outcome] = &[
    Outcome::Ok,
    Outcome::Error,
    Outcome::UnreachableHub,
    Outcome::ConnectionLost,
    Outcome::DuplicateNodeId,
    Outcome::Interrupted,
];

/// `NETWORK_OUTCOMES` and `more`, in the order of their statuses, as help.
pub(crate) fn network_help(more: &[Outcome]) -> String {
    let mut outcomes: Vec<Outcome> = NETWORK_OUTCOMES.iter().chain(more).copied().collect();
    outcomes.sort_by_key(|o| Outcome::ALL.iter().position(|a| a == o));
    outcomes.dedup();
    exit_help(&outcomes)
}

/// The framing spoken to the hub.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum ProtocolArg {
    /// CAN frames as GridConnect text (JMRI and OpenMRN hubs), with CAN alias login.
    Gridconnect,
    /// Binary OpenLCB-TCP (full-format messages).
    Tcp,
}

impl From<ProtocolArg> for Framing {
    fn from(p: ProtocolArg) -> Self {
        match p {
            ProtocolArg::Gridconnect => Framing::GridConnect,
            ProtocolArg::Tcp => Framing::Tcp,
        }
    }
}

/// `--connect` or `--serial`, and `--protocol`.
#[derive(Debug, Clone, Args)]
pub(crate) struct ConnectArgs {
    /// The hub, HOST:PORT, also set once for every command by the environment variable
    /// LCC_HUB or by `hub = "HOST:PORT"` in the settings file (`~/.config/lcc-stream/config.toml`
    /// on Linux, or the file LCC_STREAM_CONFIG names); --serial and --can take precedence
    /// over all three [default: 127.0.0.1:12021; 127.0.0.1:12022 with --protocol tcp, the
    /// two listeners of `lcc-stream hub`].
    #[arg(long, env = "LCC_HUB", value_name = "HOST:PORT", value_parser = crate::args::hub_addr)]
    pub(crate) connect: Option<String>,
    /// A serial port instead of a hub: a USB GridConnect adapter on the CAN bus (RR-CirKits
    /// LCC Buffer-USB, SPROG CANISB), e.g. /dev/ttyACM0 or COM3.
    #[arg(long, value_name = "DEVICE")]
    pub(crate) serial: Option<String>,
    /// A SocketCAN interface instead of a hub, e.g. can0 (Linux).
    #[cfg(target_os = "linux")]
    #[arg(long, value_name = "IFACE", conflicts_with = "serial")]
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
        #[cfg(target_os = "linux")]
        if let Some(interface) = &self.can {
            return interface;
        }
        match (&self.serial, &self.connect, self.protocol) {
            (Some(device), _, _) => device,
            (None, Some(addr), _) => addr,
            (None, None, protocol) => crate::settings::hub().unwrap_or(match protocol {
                ProtocolArg::Gridconnect => GRIDCONNECT_ADDR,
                ProtocolArg::Tcp => TCP_ADDR,
            }),
        }
    }

    /// Joins the network as a node with `options`: through the serial port, or the hub.
    pub(crate) async fn node(&self, options: NodeOptions) -> Result<Node, Error> {
        #[cfg(target_os = "linux")]
        if let Some(interface) = &self.can {
            let bus = openlcb_tokio::can::FrameStream::new(openlcb_tokio::can::open_socketcan(interface)?);
            return Node::over(bus, Framing::GridConnect, options).await;
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
        #[cfg(target_os = "linux")]
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

impl ConnectArgs {
    /// Joins the network as the node `id.chosen`, or as the first free transient Node ID
    /// (see [`TRANSIENT_FIRST`]); `options` makes the node's options for a Node ID. The
    /// answer of a hub that speaks the other protocol is told apart from an empty network.
    pub(crate) async fn join(
        &self,
        id: &TransientId,
        options: impl Fn(NodeId) -> NodeOptions,
    ) -> Result<Node, Failure> {
        if let Some(chosen) = id.chosen {
            return self.checked(options(chosen)).await;
        }
        let count = TRANSIENT_LAST - TRANSIENT_FIRST + 1;
        let start = u64::from(std::process::id()) % count;
        let mut last_taken = None;
        for step in 0..TRANSIENT_TRIES {
            let Some(candidate) = NodeId::new(TRANSIENT_FIRST + (start + step) % count) else { continue };
            match self.checked(options(candidate)).await {
                Err(Failure::Net(error @ Error::DuplicateNodeId { .. })) => {
                    tracing::info!(node_id = %candidate, "this transient Node ID is taken; trying the next");
                    last_taken = Some(error);
                }
                joined => {
                    if let Ok(node) = &joined {
                        tracing::info!(node_id = %node.node_id(), "joined the network");
                    }
                    return joined;
                }
            }
        }
        Err(Failure::Net(last_taken.unwrap_or(Error::Closed)))
    }

    /// Joins again as `options` says, after the connection was lost (see
    /// [`crate::reconnect`]): a fresh login with the same Node ID; the failure in brief.
    pub(crate) async fn join_again(&self, options: NodeOptions) -> Result<Node, String> {
        self.checked(options).await.map_err(|failure| failure.brief())
    }

    /// Joins as `options` says, then looks at what the hub sent: bytes that never made a
    /// message mean that it speaks the other protocol.
    async fn checked(&self, options: NodeOptions) -> Result<Node, Failure> {
        let mut node = match self.node(options).await {
            Ok(node) => node,
            // An unexpected end of the connection is a lost connection (a hub that closed it
            // as soon as it heard us).
            Err(Error::Connect { source, .. }) if source.kind() == std::io::ErrorKind::UnexpectedEof => {
                return Err(self.ended(Error::ConnectionLost(source)));
            }
            Err(error) => return Err(self.ended(error)),
        };
        if self.protocol == ProtocolArg::Tcp && self.serial.is_none() {
            // OpenLCB-TCP has no login to wait for: a hub of the other protocol shows itself
            // by closing the connection once it has read our first message.
            if let Ok(error) = tokio::time::timeout(TCP_SETTLE, node.closed()).await {
                return Err(self.ended(error));
            }
        }
        match self.heard_the_other_protocol(&node).await {
            Some(failure) => {
                node.close().await;
                Err(failure)
            }
            None => Ok(node),
        }
    }

    /// A failure if the hub has sent only bytes that never made a message (it speaks the
    /// other protocol), or if the node has already ended (see [`ended`](Self::ended)), for
    /// commands to ask when nobody answered.
    pub(crate) async fn heard_the_other_protocol(&self, node: &Node) -> Option<Failure> {
        let stats = match node.stats().await {
            Ok(stats) => stats.wire,
            // The node has ended: the hub closed the connection (as one does on bytes of the
            // other protocol), or another node claimed our Node ID.
            Err(error) => return Some(self.ended(error)),
        };
        if stats.decode_errors == 0 || stats.frames_in > 0 {
            return None;
        }
        self.wrong_protocol(&Error::Protocol(format!("{} undecodable pieces and no message", stats.decode_errors)))
    }

    /// The failure of a node that ended while it joined: a hub that speaks the other protocol
    /// if the end looks like one (the hub closed the connection as soon as it heard us, or
    /// sent what cannot be decoded), else `error` itself (a claim of our Node ID, ...).
    fn ended(&self, error: Error) -> Failure {
        match &error {
            Error::Protocol(_) | Error::ConnectionLost(_) => self.wrong_protocol(&error).unwrap_or(Failure::Net(error)),
            _ => Failure::Net(error),
        }
    }

    /// The failure of a hub that answered in the other protocol, if `error` looks like one.
    fn wrong_protocol(&self, error: &Error) -> Option<Failure> {
        let (spoken, other, flag) = self.protocols()?;
        Some(Failure::WrongProtocol(format!(
            "cannot reach the hub at {}: {error}; it probably does not speak {spoken} (a port for \
             {other}?): try {flag}, or the other port of the hub (lcc-stream hub: GridConnect \
             {GRIDCONNECT_ADDR}, OpenLCB-TCP {TCP_ADDR})",
            self.addr()
        )))
    }

    /// What to say when no node answered over a hub: a hub that speaks the other protocol
    /// and drops what it cannot read (OpenMRN's does) looks like an empty network.
    pub(crate) fn empty_network_hint(&self) -> Option<String> {
        let (_, other, flag) = self.protocols()?;
        Some(format!("if nodes are there, the hub at {} may speak {other}: try {flag}", self.addr()))
    }

    /// The protocol spoken to a hub, the other one, and the option that chooses it; `None`
    /// on a serial port or CAN interface.
    fn protocols(&self) -> Option<(&'static str, &'static str, &'static str)> {
        if self.serial.is_some() || self.can_interface().is_some() {
            return None;
        }
        Some(match self.protocol {
            ProtocolArg::Gridconnect => ("GridConnect", "OpenLCB-TCP", "--protocol tcp"),
            ProtocolArg::Tcp => ("OpenLCB-TCP", "GridConnect", "--protocol gridconnect"),
        })
    }

    /// The SocketCAN interface, if one was given.
    fn can_interface(&self) -> Option<&str> {
        #[cfg(target_os = "linux")]
        return self.can.as_deref();
        #[cfg(not(target_os = "linux"))]
        None
    }
}

/// SIGINT (Ctrl-C), SIGTERM and SIGHUP (a closed terminal, a dropped ssh), listened for from
/// the moment this is made (so that none kills the process outright while a stream runs);
/// or, for an operation that `ui` runs, its Cancel button.
pub(crate) struct Interrupt {
    #[cfg(unix)]
    signals: Option<[tokio::signal::unix::Signal; 3]>,
    /// Set to true to cancel (the Cancel button of `ui`).
    cancel: Option<tokio::sync::watch::Receiver<bool>>,
    /// Where `ui` shows an operation's progress: bytes moved, of how many if known.
    progress: Option<tokio::sync::watch::Sender<(u64, Option<u64>)>>,
}

impl Interrupt {
    pub(crate) fn new() -> Result<Self, String> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            let listen = |kind| signal(kind).map_err(|e| format!("cannot listen for signals: {e}"));
            let signals =
                [listen(SignalKind::interrupt())?, listen(SignalKind::terminate())?, listen(SignalKind::hangup())?];
            Ok(Interrupt { signals: Some(signals), cancel: None, progress: None })
        }
        #[cfg(not(unix))]
        Ok(Interrupt { cancel: None, progress: None })
    }

    /// An interrupt that comes only when `cancel` turns true (no signals: the process that
    /// serves `ui` handles its own); each transfer's progress goes to `progress`.
    pub(crate) fn on(
        cancel: tokio::sync::watch::Receiver<bool>,
        progress: tokio::sync::watch::Sender<(u64, Option<u64>)>,
    ) -> Self {
        Interrupt {
            #[cfg(unix)]
            signals: None,
            cancel: Some(cancel),
            progress: Some(progress),
        }
    }

    /// A transfer has moved `bytes` of `total`.
    pub(crate) fn progress(&self, bytes: u64, total: Option<u64>) {
        if let Some(progress) = &self.progress {
            progress.send_replace((bytes, total));
        }
    }

    /// Waits for the next SIGINT, SIGTERM or SIGHUP, or the cancel.
    pub(crate) async fn wait(&mut self) {
        if let Some(cancel) = &mut self.cancel {
            // A dropped sender never cancels.
            if cancel.wait_for(|c| *c).await.is_err() {
                std::future::pending::<()>().await;
            }
            return;
        }
        #[cfg(unix)]
        {
            let Some([int, term, hup]) = &mut self.signals else { return std::future::pending().await };
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
                _ = hup.recv() => {}
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
    started(tokio::runtime::Builder::new_multi_thread())
}

/// A runtime on this thread alone, for a transfer to one node (`write`, `firmware`): the
/// node's driver and the command's task take turns on it, so no round trip with the target
/// (a datagram and its Datagram Received OK, a window and its Proceed) wakes another thread.
/// Into OpenMRN's Bootloader by datagrams, this cut the turn from a Datagram Received OK to
/// the next datagram from 46 to 38 µs, and the command's CPU time by a third.
pub(crate) fn transfer_runtime() -> Result<tokio::runtime::Runtime, String> {
    started(tokio::runtime::Builder::new_current_thread())
}

/// The runtime `builder` makes, with its timers and I/O.
fn started(mut builder: tokio::runtime::Builder) -> Result<tokio::runtime::Runtime, String> {
    builder.enable_all().build().map_err(|e| format!("cannot start tokio: {e}"))
}

/// Prints `failure` for a person and returns its exit status.
pub(crate) fn fail(context: &str, failure: &Failure) -> ExitCode {
    eprintln!("lcc-stream {context}: {failure}");
    ExitCode::from(failure.outcome().status())
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
    out!("{}", json_line(report));
}

/// `report` as one line of JSON, newline included.
pub(crate) fn json_line(report: &impl serde::Serialize) -> String {
    // Only a map with non-string keys fails, and no report has one.
    let mut line = serde_json::to_string(report)
        .unwrap_or_else(|error| serde_json::json!({ "error": format!("cannot write JSON: {error}") }).to_string());
    line.push('\n');
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hub_args() -> ConnectArgs {
        ConnectArgs {
            connect: Some("127.0.0.1:12021".into()),
            serial: None,
            #[cfg(target_os = "linux")]
            can: None,
            baud: openlcb_tokio::serial::DEFAULT_BAUD,
            protocol: ProtocolArg::Gridconnect,
        }
    }

    #[test]
    fn a_node_that_ends_on_a_claim_of_its_node_id_fails_as_a_duplicate_not_as_the_other_protocol() {
        let node = NodeId::new(0x05_01_01_01_22_77).unwrap();
        let failure = hub_args().ended(Error::DuplicateNodeId { node });
        assert!(matches!(failure, Failure::Net(Error::DuplicateNodeId { .. })), "{failure:?}");
        assert_eq!(failure.outcome(), Outcome::DuplicateNodeId);
    }

    #[test]
    fn a_hub_that_closes_at_once_is_taken_for_one_of_the_other_protocol() {
        let lost = std::io::Error::from(std::io::ErrorKind::UnexpectedEof);
        let failure = hub_args().ended(Error::ConnectionLost(lost.into()));
        assert!(matches!(&failure, Failure::WrongProtocol(words) if words.contains("--protocol tcp")), "{failure:?}");
    }
}
