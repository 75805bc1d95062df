//! One vocabulary of results for every command: each [`Outcome`] has an exit status, the word
//! `--json` prints as `result`, and a line of help. A command lists the outcomes it can end
//! with ([`exit_help`]) and turns what stopped it ([`Failure`]) into one of them, with a
//! message for a person that says what went wrong and, where it helps, what to do.
//!
//! A new command: take its `--json` report's `result` and `error` fields from
//! [`Failure::outcome`] and [`Failure`]'s `Display`, and give its `after_help`
//! `net::network_help(&[...])` (a command that joins the network: the outcomes every such
//! command has, and its own) or `exit_help(&[...])`.

use std::fmt;
use std::path::{Path, PathBuf};

use openlcb_stream::NodeId;
use openlcb_stream::wire::ErrorCode;
use openlcb_tokio::openlcb_node::MemoryError;
use openlcb_tokio::{Error, Protocols};

use crate::cdi::CdiFault;

/// How a command ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Outcome {
    Ok,
    Error,
    Usage,
    UnreachableHub,
    Rejected,
    TimedOut,
    NotFound,
    ConnectionLost,
    Terminated,
    FileError,
    VerifyFailed,
    DuplicateNodeId,
    BadAnswer,
    Interrupted,
}

impl Outcome {
    /// Every outcome, in the order of their exit statuses.
    pub(crate) const ALL: [Outcome; 14] = [
        Outcome::Ok,
        Outcome::Error,
        Outcome::Usage,
        Outcome::UnreachableHub,
        Outcome::Rejected,
        Outcome::TimedOut,
        Outcome::NotFound,
        Outcome::ConnectionLost,
        Outcome::Terminated,
        Outcome::FileError,
        Outcome::VerifyFailed,
        Outcome::DuplicateNodeId,
        Outcome::BadAnswer,
        Outcome::Interrupted,
    ];

    /// The process's exit status.
    pub(crate) const fn status(self) -> u8 {
        match self {
            Outcome::Ok => 0,
            Outcome::Error => 1,
            Outcome::Usage => 2,
            Outcome::UnreachableHub => 3,
            Outcome::Rejected => 4,
            Outcome::TimedOut | Outcome::NotFound => 5,
            Outcome::ConnectionLost => 6,
            Outcome::Terminated => 7,
            Outcome::FileError => 8,
            Outcome::VerifyFailed => 9,
            Outcome::DuplicateNodeId => 10,
            Outcome::BadAnswer => 11,
            Outcome::Interrupted => 130,
        }
    }

    /// The `result` of `--json`.
    pub(crate) const fn word(self) -> &'static str {
        match self {
            Outcome::Ok => "ok",
            Outcome::Error => "error",
            Outcome::Usage => "usage",
            Outcome::UnreachableHub => "unreachable_hub",
            Outcome::Rejected => "rejected",
            Outcome::TimedOut => "timed_out",
            Outcome::NotFound => "not_found",
            Outcome::ConnectionLost => "connection_lost",
            Outcome::Terminated => "terminated",
            Outcome::FileError => "file_error",
            Outcome::VerifyFailed => "verify_failed",
            Outcome::DuplicateNodeId => "duplicate_node_id",
            Outcome::BadAnswer => "bad_answer",
            Outcome::Interrupted => "interrupted",
        }
    }

    const fn meaning(self) -> &'static str {
        match self {
            Outcome::Ok => "success",
            Outcome::Error => "another failure",
            Outcome::Usage => {
                "bad arguments (also a read of a space larger than one read takes, without --length), or a \
                 listener that cannot be opened"
            }
            Outcome::UnreachableHub => {
                "the hub, serial port or CAN interface cannot be reached, or it speaks another protocol"
            }
            Outcome::Rejected => "the other node refused",
            Outcome::TimedOut => "the other node stopped answering, or moved the bytes slower than --min-rate",
            Outcome::NotFound => "no node with that Node ID answered",
            Outcome::ConnectionLost => {
                "the connection to the hub was lost (one-shot commands at once; serve, recv, events watch and \
                 monitor join again unless --no-reconnect, and exit so once --reconnect-for runs out)"
            }
            Outcome::Terminated => "the transfer ended early or incomplete",
            Outcome::FileError => "a file cannot be read or written (named in the message)",
            Outcome::VerifyFailed => "the data did not verify",
            Outcome::DuplicateNodeId => "another node on the network has this Node ID (see --node-id)",
            Outcome::BadAnswer => {
                "the other node answered against the protocol (more data than asked for, another space, an \
                 empty CDI or one larger than a CDI may be; named in the message)"
            }
            Outcome::Interrupted => "Ctrl-C, SIGTERM or SIGHUP (open streams are terminated, partial files kept)",
        }
    }
}

/// The help's list of `outcomes`: exit status, `--json` word, meaning.
pub(crate) fn exit_help(outcomes: &[Outcome]) -> String {
    let mut text = String::from("Exit status (and the `result` of --json):");
    for outcome in outcomes {
        text.push_str(&format!("\n  {:>3}  {:<18} {}", outcome.status(), outcome.word(), outcome.meaning()));
    }
    text
}

/// Why a command stopped.
#[derive(Debug)]
pub(crate) enum Failure {
    /// The network, the hub or the other node.
    Net(Error),
    /// A file (named) cannot be read or written.
    File { path: PathBuf, error: std::io::Error },
    /// The hub's address answered with bytes of the other protocol.
    WrongProtocol(String),
    /// The transfer fell behind `--min-rate`.
    TooSlow(crate::pace::TooSlow),
    /// SIGINT, SIGTERM or SIGHUP.
    Interrupted,
    /// SIGINT, SIGTERM or SIGHUP during a read into `part`, which is kept and holds the
    /// first `bytes` of the read.
    InterruptedKeeping { part: PathBuf, bytes: u64 },
    /// The node's CDI cannot be taken: empty, or larger than a CDI may be.
    BadCdi { peer: NodeId, fault: CdiFault },
    /// The node lacks a protocol by its own PIP: it does not list it (and, when `code` is
    /// there, it refused with that "not implemented" code).
    Lacks { peer: NodeId, missing: Missing, code: Option<ErrorCode> },
}

/// A protocol a command needs that a node's PIP may not list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Missing {
    /// Memory Configuration: every command that reads or writes a node's spaces.
    Configuration,
    /// Firmware Upgrade (either of its two bits): `firmware`.
    FirmwareUpgrade,
    /// Stream Transport: `send`.
    Streams,
}

impl Missing {
    /// Whether `protocols` has what `self` names.
    pub(crate) fn is_in(self, protocols: Protocols) -> bool {
        match self {
            Missing::Configuration => protocols.contains(Protocols::MEMORY_CONFIGURATION),
            Missing::FirmwareUpgrade => {
                protocols.contains(Protocols::FIRMWARE_UPGRADE)
                    || protocols.contains(Protocols::FIRMWARE_UPGRADE_ACTIVE)
            }
            Missing::Streams => protocols.contains(Protocols::STREAM),
        }
    }

    /// What the node has not, for a person.
    const fn words(self) -> &'static str {
        match self {
            Missing::Configuration => "configuration",
            Missing::FirmwareUpgrade => "firmware upgrade",
            Missing::Streams => "streams",
        }
    }

    /// The protocol's name in a PIP.
    const fn protocol(self) -> &'static str {
        match self {
            Missing::Configuration => "Memory Configuration",
            Missing::FirmwareUpgrade => "Firmware Upgrade",
            Missing::Streams => "Stream",
        }
    }
}

impl Failure {
    /// A file error about `path`.
    pub(crate) fn file(path: &Path, error: std::io::Error) -> Self {
        Failure::File { path: path.to_path_buf(), error }
    }

    pub(crate) fn outcome(&self) -> Outcome {
        match self {
            Failure::Net(error) => net_outcome(error),
            Failure::File { .. } => Outcome::FileError,
            Failure::WrongProtocol(_) => Outcome::UnreachableHub,
            Failure::TooSlow(_) => Outcome::TimedOut,
            Failure::Interrupted | Failure::InterruptedKeeping { .. } => Outcome::Interrupted,
            Failure::BadCdi { .. } => Outcome::BadAnswer,
            Failure::Lacks { .. } => Outcome::Rejected,
        }
    }

    /// What went wrong, without the advice of `Display` (for a line said at every attempt to
    /// reach the hub again).
    pub(crate) fn brief(&self) -> String {
        match self {
            Failure::Net(error) => error.to_string(),
            other => other.to_string(),
        }
    }

    /// The code of a refusal that says "not implemented" (0x1040 to 0x1043, MN §3.5.5):
    /// of a Memory Configuration command, or of a stream's Initiate.
    pub(crate) fn not_implemented_code(&self) -> Option<ErrorCode> {
        let code = match self {
            Failure::Net(Error::Memory {
                error: MemoryError::Rejected(code) | MemoryError::Failed(code) | MemoryError::StreamRejected(code),
                ..
            }) => *code,
            Failure::Net(Error::Rejected { code, .. }) => ErrorCode(code.0),
            _ => return None,
        };
        (0x1040..=0x1043).contains(&code.0).then_some(code)
    }
}

impl From<Error> for Failure {
    fn from(error: Error) -> Self {
        Failure::Net(error)
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Failure::Net(error) => {
                write!(f, "{error}")?;
                match hint(error) {
                    Some(hint) => write!(f, "; {hint}"),
                    None => Ok(()),
                }
            }
            Failure::File { path, error } => write!(f, "{}: {}", path.display(), crate::files::reason(error)),
            Failure::WrongProtocol(text) => write!(f, "{text}"),
            Failure::TooSlow(slow) => write!(f, "{slow}"),
            Failure::Interrupted => write!(f, "interrupted"),
            Failure::InterruptedKeeping { part, bytes } => {
                write!(f, "interrupted: {} holds {bytes} bytes, the first of the read (kept)", part.display())
            }
            Failure::BadCdi { peer, fault } => write!(f, "the CDI of node {peer} {fault}"),
            Failure::Lacks { peer, missing, code } => {
                write!(
                    f,
                    "this node ({peer}) has no {}: its Protocol Support Reply (PIP) lists no {}",
                    missing.words(),
                    missing.protocol()
                )?;
                match code {
                    Some(code) => write!(f, ", and it answered {code} (not implemented)"),
                    None => Ok(()),
                }
            }
        }
    }
}

/// The outcome of a failure of the network or of the other node.
pub(crate) fn net_outcome(error: &Error) -> Outcome {
    match error {
        Error::Bind { .. } => Outcome::Usage,
        Error::DuplicateNodeId { .. } => Outcome::DuplicateNodeId,
        Error::Connect { .. } | Error::Device { .. } | Error::Login(_) | Error::HubFull(_) => Outcome::UnreachableHub,
        Error::Rejected { .. } => Outcome::Rejected,
        Error::Unreachable(_) => Outcome::NotFound,
        Error::TimedOut { .. } | Error::NoAnswer { .. } => Outcome::TimedOut,
        Error::ConnectionLost(_) | Error::WriteStalled(_) | Error::Protocol(_) | Error::Closed => {
            Outcome::ConnectionLost
        }
        Error::Terminated { .. } | Error::CountMismatch { .. } => Outcome::Terminated,
        Error::Memory { error, .. } => match error {
            MemoryError::Rejected(_) | MemoryError::Failed(_) | MemoryError::StreamRejected(_) => Outcome::Rejected,
            MemoryError::NoStreams | MemoryError::Locked { .. } => Outcome::Rejected,
            MemoryError::TimedOut | MemoryError::StreamTimedOut(_) | MemoryError::PeerLost => Outcome::TimedOut,
            MemoryError::StreamEnded(_)
            | MemoryError::WrongLength { .. }
            | MemoryError::CountMismatch { .. }
            | MemoryError::PeerRestarted => Outcome::Terminated,
            MemoryError::Overrun { .. } | MemoryError::WrongSpace { .. } | MemoryError::BadReply => Outcome::BadAnswer,
            MemoryError::SpaceTooLarge { .. } => Outcome::Usage,
            _ => Outcome::Error,
        },
        _ => Outcome::Error,
    }
}

/// What to do about `error`, where the tool knows.
fn hint(error: &Error) -> Option<String> {
    let code = match error {
        Error::DuplicateNodeId { .. } => return Some("give this command another with --node-id NODE_ID".into()),
        Error::Unreachable(peer) => {
            return Some(format!("`lcc-stream nodes` lists the nodes that answer (is {peer} powered and connected?)"));
        }
        Error::Memory { error: MemoryError::Rejected(code) | MemoryError::Failed(code), .. } => code.0,
        Error::Memory { error: MemoryError::NoStreams, .. } => return Some("try --no-stream (datagrams)".into()),
        Error::Memory { error: MemoryError::SpaceTooLarge { limit, .. }, .. } => {
            return Some(format!(
                "read it in parts with --length (at most {limit} bytes each) and --address, e.g. --address 0 \
                 --length {limit}, then --address {limit}"
            ));
        }
        Error::Rejected { code, .. } if code.0 & 0x1000 != 0 => return Some("the node takes no such stream".into()),
        Error::Connect { source, .. } if source.kind() == std::io::ErrorKind::ConnectionRefused => {
            return Some(
                "nothing listens there: start a hub (`lcc-stream hub`), or name the one that runs with \
                 --connect HOST:PORT (JMRI's hub listens on port 12021) or once for every command with \
                 LCC_HUB=HOST:PORT"
                    .into(),
            );
        }
        _ => return None,
    };
    match code {
        0x1081 => {
            Some("the node has no such address space; its CDI (read --space 0xFF) names the spaces it has".into())
        }
        0x1082 => Some("the address or length lies outside the space; try a smaller --length or --address".into()),
        0x1083 => Some("the space is read-only on this node".into()),
        0x1041 => Some("the node does not implement this command".into()),
        0x1040 => Some(
            "the node does not implement this for that space (a firmware space 0xEF cannot be read back; \
             `lcc-stream firmware` writes it)"
                .into(),
        ),
        0x2000..=0x2FFF => Some("a temporary error: trying again later may succeed".into()),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_outcome_has_its_own_word() {
        let mut words: Vec<_> = Outcome::ALL.iter().map(|o| o.word()).collect();
        words.sort_unstable();
        words.dedup();
        assert_eq!(words.len(), Outcome::ALL.len());
    }

    #[test]
    fn the_help_lists_only_the_outcomes_asked_for() {
        let help = exit_help(&[Outcome::Ok, Outcome::FileError]);
        assert!(help.contains("  0  ok") && help.contains("  8  file_error"), "{help}");
        assert!(!help.contains("interrupted"), "{help}");
    }

    #[test]
    fn a_peer_that_is_not_there_is_not_found_everywhere() {
        let peer = "05.01.01.01.22.99".parse().unwrap();
        assert_eq!(net_outcome(&Error::Unreachable(peer)), Outcome::NotFound);
        assert_eq!(net_outcome(&Error::NoAnswer { peer, what: "PIP" }), Outcome::TimedOut);
    }
}
