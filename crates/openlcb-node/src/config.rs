//! [`NodeConfig`] and [`Protocols`], the Protocol Support Reply bits.

#[cfg(feature = "broadcast-time")]
use alloc::vec::Vec;
use core::fmt;
use core::ops::BitOr;

#[cfg(feature = "streams")]
use openlcb_stream::Config;
#[cfg(feature = "snip-client")]
use openlcb_stream::Duration;

#[cfg(feature = "broadcast-time")]
use crate::broadcast_time::ClockConfig;
use crate::datagram::DatagramConfig;
use crate::events::EventConfig;
use crate::memconfig::MemoryConfigOptions;
use crate::snip::SnipInfo;
#[cfg(feature = "traction")]
use crate::traction::{ThrottleConfig, TrainConfig};

/// Bounds, timers and identity of a [`Node`](crate::Node). Every table and buffer it keeps
/// is sized from here (the stream endpoint's from [`NodeConfig::stream`]).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct NodeConfig {
    /// The stream endpoint's bounds and timers (with the `streams` feature: without it the
    /// node has no endpoint to bound).
    #[cfg(feature = "streams")]
    pub stream: Config,
    /// Take part in Stream Transport. When off, the PIP Stream bit is clear and stream
    /// messages are answered with OIR 0x1043, as from a node without streams (with the
    /// `streams` feature: without it the node never does).
    #[cfg(feature = "streams")]
    pub streams_enabled: bool,
    /// The datagram service's bounds and timers, and the content IDs the application takes.
    pub datagrams: DatagramConfig,
    /// What this node answers to Simple Node Information Request.
    pub snip: SnipInfo,
    /// Memory Configuration's bounds and timers, server and client. (The spaces themselves
    /// are given with [`Node::set_memory_server`](crate::Node::set_memory_server).)
    pub memory: MemoryConfigOptions,
    /// The events this node produces and consumes, and which event messages the application
    /// gets (Event Transport; the PIP announces Event Exchange when any are declared).
    pub events: EventConfig,
    /// The Broadcast Time clocks this node generates or follows (the PIP announces Event
    /// Exchange when there are any).
    #[cfg(feature = "broadcast-time")]
    pub clocks: Vec<ClockConfig>,
    /// This node is a train (Traction Control, Train Search; the PIP announces Train
    /// Control and Event Exchange).
    #[cfg(feature = "traction")]
    pub train: Option<TrainConfig>,
    /// This node drives trains (Traction Control's throttle side).
    #[cfg(feature = "traction")]
    pub throttle: Option<ThrottleConfig>,
    /// How long a SNIP request of this node waits for the reply.
    #[cfg(feature = "snip-client")]
    pub snip_timeout: Duration,
    /// SNIP requests of this node waiting at once.
    #[cfg(feature = "snip-client")]
    pub max_snip_requests: usize,
    /// Protocol bits announced besides the ones the node implements itself (Datagram, SNIP,
    /// and Stream when enabled): for protocols the application implements on top.
    pub extra_protocols: Protocols,
    /// Answers to queries (Verified Node ID, PIP, SNIP, OIR, datagram OK/Rejected) are dropped
    /// and counted once this many messages wait to be transmitted. Stream traffic is bounded
    /// by credit instead.
    pub transmit_queue_limit: usize,
    /// Queue Initialization Complete as the first message (MN §3.2). Turn off when the
    /// transport announces the node itself.
    pub send_initialization_complete: bool,
}

impl Default for NodeConfig {
    fn default() -> Self {
        NodeConfig {
            #[cfg(feature = "streams")]
            stream: Config::default(),
            #[cfg(feature = "streams")]
            streams_enabled: true,
            datagrams: DatagramConfig::default(),
            snip: SnipInfo::default(),
            memory: MemoryConfigOptions::default(),
            events: EventConfig::default(),
            #[cfg(feature = "broadcast-time")]
            clocks: Vec::new(),
            #[cfg(feature = "traction")]
            train: None,
            #[cfg(feature = "traction")]
            throttle: None,
            #[cfg(feature = "snip-client")]
            snip_timeout: Duration::from_secs(3),
            #[cfg(feature = "snip-client")]
            max_snip_requests: 8,
            extra_protocols: Protocols::NONE,
            transmit_queue_limit: 256,
            send_initialization_complete: true,
        }
    }
}

/// The 48 bits of a Protocol Support Reply (MN §3.3.7, node-protocols.md §6), bit 47 being
/// the most significant bit of the first byte.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Protocols(pub u64);

impl Protocols {
    /// No protocol.
    pub const NONE: Protocols = Protocols(0);
    /// Simple Protocol subset.
    pub const SIMPLE: Protocols = Protocols(0x8000_0000_0000);
    /// Datagram Protocol.
    pub const DATAGRAM: Protocols = Protocols(0x4000_0000_0000);
    /// Stream Protocol.
    pub const STREAM: Protocols = Protocols(0x2000_0000_0000);
    /// Memory Configuration Protocol.
    pub const MEMORY_CONFIGURATION: Protocols = Protocols(0x1000_0000_0000);
    /// Reservation Protocol.
    pub const RESERVATION: Protocols = Protocols(0x0800_0000_0000);
    /// Event Exchange (Producer/Consumer).
    pub const EVENT_EXCHANGE: Protocols = Protocols(0x0400_0000_0000);
    /// Identification Protocol.
    pub const IDENTIFICATION: Protocols = Protocols(0x0200_0000_0000);
    /// Teaching/Learning Configuration.
    pub const TEACHING_LEARNING: Protocols = Protocols(0x0100_0000_0000);
    /// Remote Button.
    pub const REMOTE_BUTTON: Protocols = Protocols(0x0080_0000_0000);
    /// Abbreviated Default CDI.
    pub const ACDI: Protocols = Protocols(0x0040_0000_0000);
    /// Display.
    pub const DISPLAY: Protocols = Protocols(0x0020_0000_0000);
    /// Simple Node Information.
    pub const SIMPLE_NODE_INFORMATION: Protocols = Protocols(0x0010_0000_0000);
    /// Configuration Description Information.
    pub const CDI: Protocols = Protocols(0x0008_0000_0000);
    /// Train Control.
    pub const TRAIN_CONTROL: Protocols = Protocols(0x0004_0000_0000);
    /// Function Description Information.
    pub const FDI: Protocols = Protocols(0x0002_0000_0000);
    /// Function Configuration.
    pub const FUNCTION_CONFIGURATION: Protocols = Protocols(0x0000_4000_0000);
    /// Firmware Upgrade.
    pub const FIRMWARE_UPGRADE: Protocols = Protocols(0x0000_2000_0000);
    /// Firmware Upgrade Active.
    pub const FIRMWARE_UPGRADE_ACTIVE: Protocols = Protocols(0x0000_1000_0000);

    /// Every named bit with its name, in wire order.
    pub const NAMED: [(Protocols, &'static str); 18] = [
        (Protocols::SIMPLE, "Simple"),
        (Protocols::DATAGRAM, "Datagram"),
        (Protocols::STREAM, "Stream"),
        (Protocols::MEMORY_CONFIGURATION, "MemoryConfiguration"),
        (Protocols::RESERVATION, "Reservation"),
        (Protocols::EVENT_EXCHANGE, "EventExchange"),
        (Protocols::IDENTIFICATION, "Identification"),
        (Protocols::TEACHING_LEARNING, "TeachingLearning"),
        (Protocols::REMOTE_BUTTON, "RemoteButton"),
        (Protocols::ACDI, "ACDI"),
        (Protocols::DISPLAY, "Display"),
        (Protocols::SIMPLE_NODE_INFORMATION, "SNIP"),
        (Protocols::CDI, "CDI"),
        (Protocols::TRAIN_CONTROL, "TrainControl"),
        (Protocols::FDI, "FDI"),
        (Protocols::FUNCTION_CONFIGURATION, "FunctionConfiguration"),
        (Protocols::FIRMWARE_UPGRADE, "FirmwareUpgrade"),
        (Protocols::FIRMWARE_UPGRADE_ACTIVE, "FirmwareUpgradeActive"),
    ];

    /// Reads a Protocol Support Reply payload: bits not sent are 0, bytes past the sixth
    /// ignored (MN §3.3.7).
    pub fn from_payload(payload: &[u8]) -> Self {
        let mut bytes = [0u8; 8];
        for (slot, byte) in bytes.iter_mut().skip(2).zip(payload) {
            *slot = *byte;
        }
        Protocols(u64::from_be_bytes(bytes))
    }

    /// The six bytes sent in a Protocol Support Reply.
    pub fn to_bytes(self) -> [u8; 6] {
        let [_, _, a, b, c, d, e, f] = self.0.to_be_bytes();
        [a, b, c, d, e, f]
    }

    /// Every bit of `other` is set here.
    pub const fn contains(self, other: Protocols) -> bool {
        self.0 & other.0 == other.0
    }

    /// The names of the bits set, in wire order (unnamed bits are left out).
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Self::NAMED.into_iter().filter(move |(bit, _)| self.contains(*bit)).map(|(_, name)| name)
    }
}

impl BitOr for Protocols {
    type Output = Protocols;
    fn bitor(self, rhs: Protocols) -> Protocols {
        Protocols(self.0 | rhs.0)
    }
}

impl fmt::Debug for Protocols {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Protocols(0x{:012X}", self.0)?;
        for name in self.names() {
            write!(f, " {name}")?;
        }
        write!(f, ")")
    }
}
