//! [`Error`]: everything a node, a stream or a hub can fail with, worded for a person.

use std::io;
use std::sync::Arc;

use openlcb_stream::wire::{ReplyClass, ReplyCode};
use openlcb_stream::{NodeId, StreamError, Termination, TimeoutKind};

/// Why a node, a stream or a hub failed. Cheap to clone: the driver hands the same error to
/// every stream that was waiting when the connection went.
#[derive(Debug, Clone, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The hub could not be reached (refused, no route, bad address, or no answer in time).
    #[error("cannot reach the hub at {addr}: {source}")]
    Connect {
        /// The address as given.
        addr: String,
        /// What the operating system said.
        #[source]
        source: Arc<io::Error>,
    },
    /// A serial port or a CAN interface could not be opened.
    #[error("cannot open the {kind} {device}: {}", device_reason(.kind, .source))]
    Device {
        /// What it is meant to be: "serial port" or "CAN interface".
        kind: &'static str,
        /// The device as given (`/dev/ttyACM0`, `can0`).
        device: String,
        /// What the operating system said.
        #[source]
        source: Arc<io::Error>,
    },
    /// A listening socket could not be opened.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address as given.
        addr: String,
        /// What the operating system said.
        #[source]
        source: Arc<io::Error>,
    },
    /// The connection to the hub broke or was closed by the hub.
    #[error("connection to the hub lost: {0}")]
    ConnectionLost(#[source] Arc<io::Error>),
    /// The socket took none of the pending output for this long (the hub stopped reading):
    /// the connection is given up, and every transfer on it ends.
    #[error("the hub took no data for {} s; giving the connection up", .0.as_secs_f64())]
    WriteStalled(std::time::Duration),
    /// The hub refused this connection: it has as many clients as it takes (what it said,
    /// as `lcc-stream hub` says it: "hub full: 64 clients connected; try again later").
    #[error("the hub refused this connection ({0})")]
    HubFull(String),
    /// The hub sent bytes that cannot be framed (an OpenLCB-TCP length that cannot be trusted).
    #[error("the hub sent undecodable data: {0}")]
    Protocol(String),
    /// The CAN alias could not be used: another node has this Node ID, or the login stalled.
    #[error("CAN alias login failed: {0}")]
    Login(&'static str),
    /// Another node on the network already had this node's Node ID when this node joined:
    /// it answered this node's announcements. This node sent the well-known event Duplicate
    /// Node ID Detected, released its alias and left. (A node that was there first and sees
    /// a newcomer with its Node ID keeps running: it sends the event and logs a warning.)
    #[error(
        "another node on the network already has Node ID {node}: this node reported Duplicate Node ID Detected, released its alias and left (give it another Node ID)"
    )]
    DuplicateNodeId {
        /// The Node ID both nodes have.
        node: NodeId,
    },
    /// The destination refused the stream.
    #[error("node {peer} rejected the stream with code {code}{}", if code.class() == ReplyClass::Temporary { "; it may accept later" } else { "" })]
    Rejected {
        /// The destination.
        peer: NodeId,
        /// The raw code; [`ReplyCode::meaning`] explains it.
        code: ReplyCode,
    },
    /// A Simple Node Information request got no usable answer.
    #[error("{}", crate::requests::snip_failure_text(*.peer, *.failure))]
    Snip {
        /// The node asked.
        peer: NodeId,
        /// What happened.
        failure: openlcb_node::SnipFailure,
    },
    /// A node did not answer a question in time.
    #[error("node {peer} did not answer the {what} in time")]
    NoAnswer {
        /// The node asked.
        peer: NodeId,
        /// The question.
        what: &'static str,
    },
    /// Too many questions of this kind wait for answers already.
    #[error("too many requests are waiting for answers; try again")]
    Busy,
    /// A Broadcast Time command this node cannot give (no such clock, a time out of range).
    #[error("{0}")]
    Clock(openlcb_node::broadcast_time::ClockError),
    /// A train command this node cannot give (it is no train, the search is not its).
    #[error("{0}")]
    Train(openlcb_node::traction::TrainError),
    /// A throttle command this node cannot give (it is no throttle, it controls enough).
    #[error("{0}")]
    Throttle(openlcb_node::traction::ThrottleError),
    /// No node with this Node ID answered on the network.
    #[error("node {0} is not on the network (nobody answered for that Node ID)")]
    Unreachable(NodeId),
    /// A wait ran out and the stream ended.
    #[error("{}", timeout_text(*.peer, *.kind))]
    TimedOut {
        /// The other end.
        peer: NodeId,
        /// Which wait.
        kind: TimeoutKind,
    },
    /// The stream ended early.
    #[error("{}", termination_text(*.peer, *.cause))]
    Terminated {
        /// The other end.
        peer: NodeId,
        /// Why.
        cause: Termination,
    },
    /// The source's Complete stated another byte count than the bytes that arrived.
    #[error("the stream ended with {received} bytes but the source said it sent {stated}")]
    CountMismatch {
        /// Bytes received.
        received: u64,
        /// Bytes the source stated.
        stated: u64,
    },
    /// A Memory Configuration operation with `peer` failed.
    #[error("{}", crate::memory::memory_error_text(*.peer, *.error))]
    Memory {
        /// The node read, written or upgraded.
        peer: NodeId,
        /// What happened.
        error: openlcb_node::MemoryError,
    },
    /// A Memory Configuration operation could not start.
    #[error("{}", crate::memory::request_error_text(*.0))]
    MemoryRequest(openlcb_node::MemoryRequestError),
    /// The stream engine refused a command.
    #[error("stream command refused: {0}")]
    Stream(#[from] StreamError),
    /// The node was shut down (every handle to it dropped, or its driver ended).
    #[error("the node has shut down")]
    Closed,
}

impl Error {
    /// An error from the operating system while talking to the hub.
    pub(crate) fn lost(error: io::Error) -> Self {
        Error::ConnectionLost(Arc::new(error))
    }

    /// The hub closed its end of the connection.
    pub(crate) fn closed_by_hub() -> Self {
        Error::lost(io::Error::new(io::ErrorKind::UnexpectedEof, "the hub closed the connection"))
    }

    /// `true` when retrying the same thing later may help (temporary rejections, lost
    /// connections, timeouts).
    pub fn is_temporary(&self) -> bool {
        match self {
            Error::Rejected { code, .. } => code.class() == ReplyClass::Temporary,
            Error::Connect { .. }
            | Error::HubFull(_)
            | Error::ConnectionLost(_)
            | Error::TimedOut { .. }
            | Error::Terminated { .. } => true,
            _ => false,
        }
    }
}

/// What went wrong opening a device, in words: the common causes named, the rest as the
/// operating system says them.
fn device_reason(kind: &str, error: &io::Error) -> String {
    // Linux's numbers: ENOENT, EACCES, EBUSY, ENODEV, ENOTTY, EAFNOSUPPORT.
    match (error.raw_os_error(), kind) {
        (Some(2), _) => "no such device".into(),
        (Some(13), "serial port") => "permission denied (on Linux, join the `dialout` group)".into(),
        (Some(13), _) => "permission denied".into(),
        (Some(16), _) => "the device is busy (another program has it open)".into(),
        (Some(19), "CAN interface") => "no such CAN interface (`ip link` lists them)".into(),
        (Some(19), _) => "no such device".into(),
        (Some(25), "serial port") => "not a serial port".into(),
        (Some(97), _) => "this kernel has no CAN sockets (the can and can-raw modules)".into(),
        // The serial crate hands ENOTTY on as text only (glibc's and musl's wording).
        _ if kind == "serial port" && ["typewriter", "ioctl"].iter().any(|t| error.to_string().contains(t)) => {
            "not a serial port".into()
        }
        _ => match error.kind() {
            io::ErrorKind::NotFound => "no such device".into(),
            io::ErrorKind::PermissionDenied => "permission denied".into(),
            _ => error.to_string(),
        },
    }
}

fn timeout_text(peer: NodeId, kind: TimeoutKind) -> String {
    match kind {
        TimeoutKind::Reply => format!("node {peer} did not answer the stream request in time"),
        TimeoutKind::Proceed => format!("node {peer} stopped granting credit (no Data Proceed in time)"),
        TimeoutKind::Idle => format!("node {peer} went silent in the middle of the stream"),
        TimeoutKind::FirstData => format!("node {peer} opened a stream and sent no data in time"),
        TimeoutKind::Decision => format!("the request from node {peer} was not decided on in time"),
        _ => format!("a wait for node {peer} ran out"),
    }
}

fn termination_text(peer: NodeId, cause: Termination) -> String {
    match cause {
        Termination::ByPeer(code) => {
            format!("node {peer} terminated the stream with error {code} ({})", code.meaning())
        }
        Termination::WindowOverrun => format!("node {peer} sent more than the window allows"),
        Termination::Superseded => format!("node {peer} started a new stream in place of this one"),
        Termination::PeerLost => format!("node {peer} left the network"),
        Termination::PeerRestarted => format!("node {peer} restarted"),
        Termination::LinkLost => "this node lost its CAN alias".to_string(),
        Termination::SiblingTerminated => {
            format!("this node ended another stream with node {peer}, which ends this one too")
        }
        _ => format!("the stream with node {peer} ended early"),
    }
}
