//! Trains: the train side of Traction Control (Train Control Standard and its Technical
//! Note), Train Search (Train Search Standard) and the Function Description Information
//! (FDI Standard).
//!
//! A node is a train when [`NodeConfig::train`](crate::NodeConfig::train) holds a
//! [`TrainConfig`]. Its traction service then:
//!
//! - takes every Traction Control Command (MTI 0x05EB): Set Speed (float16, [`Speed`], the
//!   sign the direction, so zero has two values), Set Function, Emergency Stop, Query Speeds
//!   and Query Function; Controller Assign, Release and Query; Listener Attach (or update of
//!   the flags), Detach and Query; Management Reserve, Release and No-op. Each is answered as
//!   §4.4 says, and a command too short for its instruction, or an instruction the standard
//!   does not define, gets Optional Interaction Rejected (0x1080 invalid arguments, 0x1041
//!   not implemented) quoting MTI 0x05EB; nothing from the wire panics or grows a table past
//!   its [`TrainConfig`] bound;
//! - forwards Set Speed, Set Function and Emergency Stop to its listeners with the P bit
//!   (§6.5): never back to the sender, speeds reversed for a listener with
//!   [`LISTENER_REVERSE`], F0 only with [`LISTENER_LINK_F0`], other functions only with
//!   [`LISTENER_LINK_FN`]; a forwarded command (P set) is carried out and forwarded the same
//!   way, so a consist of consists works and no message goes straight back. A listener loop
//!   (A listens to B, B to C, C to A) is cut where it closes: a forwarded command that
//!   changes nothing, or a speed this train forwarded in the last two seconds coming back
//!   (the same or reversed, as a loop with a reversed listener returns it), is dropped and
//!   counted ([`TrainStats::loops_cut`]), so no loop circulates, whatever the flags;
//! - asks its controller for a heartbeat (§6.6) while it is set moving: the request goes out
//!   half of [`TrainConfig::heartbeat`] after the controller last sent anything, and when
//!   nothing comes within the deadline the train takes it as Set Speed 0 (forwarded to every
//!   listener, the controller too);
//! - obeys the well-known events Emergency Stop All / Clear and Emergency Off All / Clear
//!   (§4.1): the train stops, its Set Speed stays, and it runs on when all stops are clear;
//! - produces Is Train (01.01.00.00.00.00.03.03), and answers the Train Search queries that
//!   match it ([`SearchQuery`]) with Producer Identified Valid. A command station
//!   ([`TrainConfig::allocate`]) tells the application of an allocate search that matches
//!   none of its trains ([`TrainChange::Allocate`]): the application creates that train as a
//!   node of its own (its own Node ID and alias), bounded as it chooses, and has it answer
//!   with [`Node::answer_train_search`].
//!
//! The application is told what to do ([`NodeEvent::Train`],
//! [`TrainEvent`]): the speed to apply (the commanded speed, zero while any emergency stop
//! holds), the function to switch, the controller that changed; the service answers queries
//! from the state it keeps ([`Node::train`], [`Node::train_function`]).
//!
//! A node is a throttle when [`NodeConfig::throttle`](crate::NodeConfig::throttle) holds a
//! [`ThrottleConfig`]: [`Node::throttle_command`] sends any [`TractionCommand`] to a train
//! (an Assign counts the train as controlled, up to [`ThrottleConfig::max_trains`]), and the
//! train's replies, rejects, heartbeat requests (answered with a No-op at once unless
//! [`ThrottleConfig::answer_heartbeats`] is off) and a Controller Changing Notify (accepted:
//! the train is another's now) come as [`NodeEvent::Throttle`]
//! ([`ThrottleEvent`]). A node may be both.
//!
//! Space 0xFA, the FDI, is a read-only space of the application's memory server
//! ([`fdi_space`] builds it from the function names); a node with it announces FDI in its
//! PIP. Space 0xF9, the functions themselves (Train Control Standard §7.1), the node keeps
//! beside the application's memory server (unless that serves a 0xF9 of its own): a byte
//! per function address, read as the train's state, and a write of it is a Set Function
//! from the writer, carried out and forwarded as one.
//!
//! # Where the standard and real peers differ
//!
//! - **Query Controller's flags.** The standard marks bit 0 reserved; OpenMRN sets it when
//!   it appends the controller's CAN alias (11 bytes); OlcbChecker's `tr090` wants it set
//!   whenever a controller is assigned, with the 9-byte reply. Here bit 0 says a controller
//!   is assigned and the reply is 9 bytes (a full-format node knows no alias).
//! - **A new controller** is accepted at once and the old one told with Controller Changing
//!   Notify; its answer is not waited for (the standard allows either). A node that holds
//!   the Management reservation refuses other nodes' Assign (result bit 1, train refused).
//! - **The Heartbeat Request's deadline** is one byte of seconds (`40 03 SS`), as OpenMRN's
//!   `heartbeat_request_payload` sends it and OpenMRN and OpenLCB_Java (JMRI's throttles) read
//!   it; OpenLcbCLib sends three bytes, which those readers take as 0 s. The throttle here
//!   answers any form at once.
//! - **Heartbeat timeout** is Set Speed 0 as §6.6 says, not an Emergency Stop (OlcbChecker's
//!   `tr110` notes, as a warning, that OpenLcbCLib sets the E-Stop status).
//! - **Functions** are kept for addresses below [`TrainConfig::functions`] (F0-F68 by
//!   default); a Set or Query Function past them is rejected with 0x1080.
//! - **A function's byte in space 0xF9** is its value clamped to 255 (values are 16 bits on
//!   the Traction Control wire); OpenLCB_Java's throttle writes a single byte (`20 00 00 00
//!   00 NN F9 SS`), which is taken as the function's whole value.
//! - **Train Search allocation** in one process: the command station knows its own trains,
//!   so it does not wait the 200 ms of §6.2 for them; trains of other command stations that
//!   answer later make a duplicate the user must resolve, as with any two command stations.

mod fdi;
mod search;
mod throttle;
mod wire;

use alloc::vec::Vec;

use openlcb_stream::wire::{Emit as _, ErrorCode, ErrorReport};
use openlcb_stream::{Duration, EventId, Instant, Message, MessageRef, Mti, NodeId};

pub use fdi::{FunctionKind, FunctionName, fdi_space, fdi_xml};
pub use search::{
    SEARCH_ADDRESS_ONLY, SEARCH_ALLOCATE, SEARCH_EXACT, SEARCH_PREFIX, SearchError, SearchProtocol, SearchQuery,
    TrainIdentity, TrainProtocol,
};
pub use throttle::{ThrottleConfig, ThrottleError, ThrottleEvent};
pub use wire::{
    LISTENER_HIDE, LISTENER_LINK_F0, LISTENER_LINK_FN, LISTENER_RESERVED, LISTENER_REVERSE, Speed, TractionCommand,
};

use crate::memconfig::wire::SPACE_FUNCTIONS;
use crate::memconfig::{FunctionMirror, MemoryServer};
use crate::node::{Outputs, bump};
use crate::service::{Lent, Service, ServiceChange, earliest};
use crate::{Node, NodeEvent};
use throttle::Throttle;
use wire::CommandError;

/// Is Train (Train Control Standard §4.1, §6.4).
pub const IS_TRAIN: EventId = EventId(0x0101_0000_0000_0303);
/// Emergency Off All.
pub const EMERGENCY_OFF: EventId = EventId(0x0100_0000_0000_FFFF);
/// Clear Emergency Off All.
pub const CLEAR_EMERGENCY_OFF: EventId = EventId(0x0100_0000_0000_FFFE);
/// Emergency Stop All.
pub const EMERGENCY_STOP: EventId = EventId(0x0100_0000_0000_FFFD);
/// Clear Emergency Stop All.
pub const CLEAR_EMERGENCY_STOP: EventId = EventId(0x0100_0000_0000_FFFC);

/// Permanent error, not found (Train Control Standard §4.2).
pub const NOT_FOUND: ErrorCode = ErrorCode(0x1030);
/// Permanent error, already exists.
pub const ALREADY_EXISTS: ErrorCode = ErrorCode(0x1032);

/// A train's identity and bounds.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct TrainConfig {
    /// Address, protocol and name, for Train Search.
    pub identity: TrainIdentity,
    /// Listeners attached at once; one more Attach gets 0x2020 (buffer unavailable).
    pub max_listeners: usize,
    /// Function addresses kept, from 0 (69: F0-F68).
    pub functions: u32,
    /// The deadline a heartbeat request gives the controller (`None`: no heartbeat). Whole
    /// seconds on the wire, at least one.
    pub heartbeat: Option<Duration>,
    /// This node is a command station: an allocate search that matches no train of it is
    /// handed to the application ([`TrainChange::Allocate`]).
    pub allocate: bool,
    /// Produce Is Train (Producer Identified Valid) once the node has started. A train a
    /// command station creates for a search answers that search instead: a Producer
    /// Identified of Is Train in between is taken by OlcbChecker's `ts10` as a wrong answer.
    pub announce: bool,
}

impl TrainConfig {
    /// A DCC train at `address` with the default bounds.
    pub fn dcc(address: u32) -> Self {
        TrainConfig {
            identity: TrainIdentity::dcc(address),
            max_listeners: 8,
            functions: 69,
            heartbeat: Some(Duration::from_secs(3)),
            allocate: false,
            announce: true,
        }
    }
}

/// A change of the train, for the application ([`NodeEvent::Train`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrainEvent {
    /// What changed.
    pub change: TrainChange,
    /// The node whose message caused it (`None`: the train's own timer).
    pub from: Option<NodeId>,
}

/// What changed ([`TrainEvent`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum TrainChange {
    /// The speed: `set` as last commanded, `commanded` what the motor is to run at now (zero
    /// in the same direction while an emergency stop holds).
    Speed {
        /// The Set Speed.
        set: Speed,
        /// The speed to apply.
        commanded: Speed,
    },
    /// A function's value.
    Function {
        /// Its address (F0 is 0).
        address: u32,
        /// Its value.
        value: u16,
    },
    /// Emergency Stop: the train is to stop as fast as it can.
    EmergencyStop,
    /// Emergency Stop All began (`true`) or was cleared.
    GlobalStop(bool),
    /// Emergency Off All began (`true`: stop and de-energize every output) or was cleared.
    GlobalOff(bool),
    /// A controller was assigned; `previous` was told with Controller Changing Notify.
    ControllerAssigned {
        /// The new controller.
        controller: NodeId,
        /// The one it replaced.
        previous: Option<NodeId>,
    },
    /// The controller released the train.
    ControllerReleased(NodeId),
    /// The controller did not answer a heartbeat request in time: the train was set to zero.
    HeartbeatTimedOut(NodeId),
    /// A listener was attached, or its flags changed.
    ListenerAttached {
        /// The listener.
        node: NodeId,
        /// Its flags.
        flags: u8,
    },
    /// A listener was detached.
    ListenerDetached(NodeId),
    /// A node took the Management reservation.
    Reserved(NodeId),
    /// The reservation ended.
    ReservationReleased(NodeId),
    /// A command station's allocate search for a train it does not have: create it and have
    /// it answer with [`Node::answer_train_search`]`(event)`.
    Allocate {
        /// The search's Event ID, to answer with.
        event: EventId,
        /// The train asked for.
        address: u32,
        /// Its protocol.
        protocol: TrainProtocol,
    },
}

/// A train's state now ([`Node::train`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct TrainState {
    /// The last Set Speed (±0 after an Emergency Stop).
    pub set_speed: Speed,
    /// What the motor is to run at: zero while an emergency stop holds.
    pub commanded_speed: Speed,
    /// In Emergency Stop (until the next Set Speed).
    pub emergency_stop: bool,
    /// Emergency Stop All holds.
    pub global_stop: bool,
    /// Emergency Off All holds.
    pub global_off: bool,
    /// The controller.
    pub controller: Option<NodeId>,
    /// The holder of the Management reservation.
    pub reserved_by: Option<NodeId>,
    /// Listeners attached.
    pub listeners: usize,
}

/// Counters of the traction service.
///
/// Each counter stops at `u32::MAX` (32 bits: 64-bit counters cost flash on a
/// microcontroller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct TrainStats {
    /// Commands carried out or answered.
    pub commands: u32,
    /// Commands rejected (too short, unknown, out of bounds).
    pub rejected: u32,
    /// Commands forwarded to listeners.
    pub forwarded: u32,
    /// Heartbeat requests sent.
    pub heartbeats_sent: u32,
    /// Heartbeats the controller let pass.
    pub heartbeat_timeouts: u32,
    /// Forwarded commands that came back round a listener loop, dropped.
    pub loops_cut: u32,
    /// Train Search queries answered.
    pub searches_answered: u32,
    /// Train Search queries with reserved values, ignored.
    pub searches_reserved: u32,
    /// Events dropped because the application left too many waiting.
    pub notices_dropped: u32,
}

/// Why a train command could not be given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TrainError {
    /// The node has no [`NodeConfig::train`](crate::NodeConfig::train).
    #[error("this node is no train")]
    NotATrain,
    /// The search does not match this train (or is no search).
    #[error("the search does not match this train")]
    NoMatch,
    /// The transmit queue is full.
    #[error("the transmit queue is full")]
    QueueFull,
}

/// An attached listener.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Listener {
    node: NodeId,
    flags: u8,
}

#[derive(Debug)]
struct Train {
    config: TrainConfig,
    set_speed: Speed,
    estop: bool,
    global_stop: bool,
    global_off: bool,
    functions: Vec<u16>,
    /// `functions` changed since space 0xF9 last took them.
    functions_changed: bool,
    controller: Option<NodeId>,
    reserved_by: Option<NodeId>,
    listeners: Vec<Listener>,
    /// When the next heartbeat request goes out.
    heartbeat_at: Option<Instant>,
    /// When an unanswered request expires.
    heartbeat_deadline: Option<Instant>,
    /// The last speed this train forwarded, and when: its echo round a loop is cut.
    last_forward: Option<(Instant, Speed)>,
}

/// How long a forwarded speed's echo is recognised (see the module docs, listener loops).
const ECHO_WINDOW: Duration = Duration::from_secs(2);

/// The traction service of a node (nothing when the node is no train).
#[derive(Debug)]
pub(crate) struct TrainService {
    train: Option<Train>,
    throttle: Option<Throttle>,
    announce: bool,
    stats: TrainStats,
}

/// What the train's work writes into: the node's queues and the counters.
struct Bus<'a> {
    out: &'a mut Outputs,
    stats: &'a mut TrainStats,
}

impl Bus<'_> {
    fn reply(&mut self, to: NodeId, payload: Vec<u8>) {
        let node = self.out.node;
        self.out.reply(Message::addressed(Mti::TRACTION_CONTROL_REPLY, node, to, payload));
    }

    fn command(&mut self, to: NodeId, command: TractionCommand) {
        let node = self.out.node;
        self.out.reply(Message::addressed(Mti::TRACTION_CONTROL_COMMAND, node, to, command.to_bytes()));
    }

    fn reject(&mut self, to: NodeId, code: ErrorCode) {
        bump(&mut self.stats.rejected);
        let node = self.out.node;
        let report = ErrorReport { code, mti: Some(Mti::TRACTION_CONTROL_COMMAND) };
        self.out.reply(Message::addressed(Mti::OPTIONAL_INTERACTION_REJECTED, node, to, report.to_bytes()));
    }

    fn event(&mut self, mti: Mti, event: EventId) {
        let node = self.out.node;
        self.out.reply(Message::global(mti, node, event.to_bytes()));
    }

    fn tell(&mut self, change: TrainChange, from: Option<NodeId>) {
        if !self.out.notify(NodeEvent::Train(TrainEvent { change, from })) {
            bump(&mut self.stats.notices_dropped);
        }
    }
}

/// A function's value as its byte of space 0xF9.
fn function_byte(value: u16) -> u8 {
    u8::try_from(value).unwrap_or(u8::MAX)
}

fn result_code(code: ErrorCode) -> [u8; 2] {
    code.0.to_be_bytes()
}

impl Train {
    fn new(config: TrainConfig) -> Self {
        let functions = alloc::vec![0; config.functions.min(0x4_0000) as usize];
        Train {
            config,
            set_speed: Speed::ZERO_FORWARD,
            estop: false,
            global_stop: false,
            global_off: false,
            functions,
            functions_changed: true,
            controller: None,
            reserved_by: None,
            listeners: Vec::new(),
            heartbeat_at: None,
            heartbeat_deadline: None,
            last_forward: None,
        }
    }

    fn commanded(&self) -> Speed {
        if self.estop || self.global_stop || self.global_off { self.set_speed.stopped() } else { self.set_speed }
    }

    fn state(&self) -> TrainState {
        TrainState {
            set_speed: self.set_speed,
            commanded_speed: self.commanded(),
            emergency_stop: self.estop,
            global_stop: self.global_stop,
            global_off: self.global_off,
            controller: self.controller,
            reserved_by: self.reserved_by,
            listeners: self.listeners.len(),
        }
    }

    fn tell_speed(&self, bus: &mut Bus<'_>, from: Option<NodeId>) {
        bus.tell(TrainChange::Speed { set: self.set_speed, commanded: self.commanded() }, from);
    }

    /// Whether the train asks its controller for heartbeats now (§6.6).
    fn wants_heartbeat(&self) -> bool {
        self.config.heartbeat.is_some() && self.controller.is_some() && !self.set_speed.is_zero() && !self.estop
    }

    fn heartbeat_secs(&self) -> u32 {
        self.config.heartbeat.map_or(0, |d| (d.as_micros() / 1_000_000).clamp(1, 0xFF_FFFF) as u32)
    }

    /// The controller was heard (or the state changed): the next request half the deadline
    /// on, none while the train stands.
    fn rearm(&mut self, now: Instant, heard: bool) {
        if heard {
            self.heartbeat_deadline = None;
        }
        if !self.wants_heartbeat() {
            self.heartbeat_at = None;
            self.heartbeat_deadline = None;
        } else if self.heartbeat_deadline.is_none() && (heard || self.heartbeat_at.is_none()) {
            let half = Duration::from_micros(u64::from(self.heartbeat_secs()) * 500_000);
            self.heartbeat_at = Some(now + half);
        }
    }

    /// Forwards `command` to every listener but `source`, as its flags say (§6.5).
    fn forward(&mut self, bus: &mut Bus<'_>, source: Option<NodeId>, command: TractionCommand) {
        for listener in &self.listeners {
            if Some(listener.node) == source {
                continue;
            }
            let forwarded = match command {
                TractionCommand::SetSpeed { speed, .. } => {
                    let speed = if listener.flags & LISTENER_REVERSE != 0 { speed.reversed() } else { speed };
                    TractionCommand::SetSpeed { speed, forwarded: true }
                }
                TractionCommand::SetFunction { address, value, .. } => {
                    let link = if address == 0 { LISTENER_LINK_F0 } else { LISTENER_LINK_FN };
                    if listener.flags & link == 0 {
                        continue;
                    }
                    TractionCommand::SetFunction { address, value, forwarded: true }
                }
                TractionCommand::EmergencyStop { .. } => TractionCommand::EmergencyStop { forwarded: true },
                _ => continue,
            };
            bump(&mut bus.stats.forwarded);
            bus.command(listener.node, forwarded);
        }
    }

    fn on_command(&mut self, now: Instant, bus: &mut Bus<'_>, from: NodeId, payload: &[u8]) {
        let command = match TractionCommand::parse(payload) {
            Ok(command) => command,
            Err(CommandError::Short) => return bus.reject(from, ErrorCode::INVALID_ARGUMENTS),
            Err(CommandError::Unknown) => return bus.reject(from, ErrorCode::NOT_IMPLEMENTED_SUBCOMMAND),
        };
        bump(&mut bus.stats.commands);
        let heard = self.controller == Some(from);
        if self.is_echo(now, command) {
            bump(&mut bus.stats.loops_cut);
            return self.rearm(now, heard);
        }
        match command {
            TractionCommand::SetSpeed { speed, .. } => {
                self.set_speed = speed;
                self.estop = false;
                self.tell_speed(bus, Some(from));
                self.last_forward = Some((now, speed));
                self.forward(bus, Some(from), command);
            }
            TractionCommand::SetFunction { address, value, .. } => {
                if !self.set_function(bus, from, address, value) {
                    bus.stats.commands -= 1;
                    return bus.reject(from, ErrorCode::INVALID_ARGUMENTS);
                }
            }
            TractionCommand::EmergencyStop { .. } => {
                self.set_speed = self.set_speed.stopped();
                self.estop = true;
                bus.tell(TrainChange::EmergencyStop, Some(from));
                self.tell_speed(bus, Some(from));
                self.forward(bus, Some(from), command);
            }
            TractionCommand::QuerySpeeds => {
                let mut reply = alloc::vec![wire::QUERY_SPEEDS];
                reply.extend_from_slice(&self.set_speed.to_bits().to_be_bytes());
                reply.push(u8::from(self.estop));
                reply.extend_from_slice(&self.commanded().to_bits().to_be_bytes());
                reply.extend_from_slice(&Speed::NAN.to_bits().to_be_bytes());
                bus.reply(from, reply);
            }
            TractionCommand::QueryFunction { address } => {
                let Some(value) = self.functions.get(address as usize) else {
                    bus.stats.commands -= 1;
                    return bus.reject(from, ErrorCode::INVALID_ARGUMENTS);
                };
                let mut reply = TractionCommand::QueryFunction { address }.to_bytes();
                reply.extend_from_slice(&value.to_be_bytes());
                bus.reply(from, reply);
            }
            TractionCommand::AssignController { node, .. } => {
                let refused = self.reserved_by.is_some_and(|r| r != from);
                if refused {
                    bus.reply(from, alloc::vec![wire::CONTROLLER, wire::CONTROLLER_ASSIGN, 0x02]);
                } else {
                    let previous = self.controller.filter(|old| *old != node);
                    if let Some(old) = previous {
                        bus.command(old, TractionCommand::ControllerChanging { flags: 0, node });
                    }
                    let changed = self.controller != Some(node);
                    self.controller = Some(node);
                    bus.reply(from, alloc::vec![wire::CONTROLLER, wire::CONTROLLER_ASSIGN, 0]);
                    if changed {
                        bus.tell(TrainChange::ControllerAssigned { controller: node, previous }, Some(from));
                    }
                    self.heartbeat_deadline = None;
                    self.heartbeat_at = None;
                    return self.rearm(now, true);
                }
            }
            TractionCommand::ReleaseController { node, .. } => {
                if self.controller == Some(node) {
                    self.controller = None;
                    bus.tell(TrainChange::ControllerReleased(node), Some(from));
                }
            }
            TractionCommand::QueryController => {
                let mut reply =
                    alloc::vec![wire::CONTROLLER, wire::CONTROLLER_QUERY, u8::from(self.controller.is_some())];
                reply.extend_from_slice(&self.controller.map_or([0; 6], NodeId::to_bytes));
                bus.reply(from, reply);
            }
            TractionCommand::ControllerChanging { .. } => {
                // A throttle's message: a train has no controller to hand over.
                bus.stats.commands -= 1;
                return bus.reject(from, ErrorCode::NOT_IMPLEMENTED_SUBCOMMAND);
            }
            TractionCommand::AttachListener { flags, node } => {
                let code = if node == bus.out.node {
                    ALREADY_EXISTS
                } else if let Some(listener) = self.listeners.iter_mut().find(|l| l.node == node) {
                    listener.flags = flags;
                    ErrorCode(0)
                } else if self.listeners.len() >= self.config.max_listeners {
                    ErrorCode::BUFFER_UNAVAILABLE
                } else {
                    self.listeners.push(Listener { node, flags });
                    ErrorCode(0)
                };
                if code.0 == 0 {
                    bus.tell(TrainChange::ListenerAttached { node, flags }, Some(from));
                }
                let mut reply = alloc::vec![wire::LISTENER, wire::LISTENER_ATTACH];
                reply.extend_from_slice(&node.to_bytes());
                reply.extend_from_slice(&result_code(code));
                bus.reply(from, reply);
            }
            TractionCommand::DetachListener { node, .. } => {
                let before = self.listeners.len();
                self.listeners.retain(|l| l.node != node);
                let code = if self.listeners.len() < before {
                    bus.tell(TrainChange::ListenerDetached(node), Some(from));
                    ErrorCode(0)
                } else {
                    NOT_FOUND
                };
                let mut reply = alloc::vec![wire::LISTENER, wire::LISTENER_DETACH];
                reply.extend_from_slice(&node.to_bytes());
                reply.extend_from_slice(&result_code(code));
                bus.reply(from, reply);
            }
            TractionCommand::QueryListeners { index } => {
                let count = self.listeners.len().min(255) as u8;
                let mut reply = alloc::vec![wire::LISTENER, wire::LISTENER_QUERY, count];
                if let Some((i, listener)) = index.and_then(|i| Some((i, self.listeners.get(usize::from(i))?))) {
                    reply.extend_from_slice(&[i, listener.flags]);
                    reply.extend_from_slice(&listener.node.to_bytes());
                }
                bus.reply(from, reply);
            }
            TractionCommand::Reserve => {
                let ok = self.reserved_by.is_none_or(|r| r == from);
                if ok && self.reserved_by.is_none() {
                    self.reserved_by = Some(from);
                    bus.tell(TrainChange::Reserved(from), Some(from));
                }
                bus.reply(from, alloc::vec![wire::MANAGEMENT, wire::MANAGEMENT_RESERVE, u8::from(!ok)]);
            }
            TractionCommand::Release => {
                if self.reserved_by == Some(from) {
                    self.reserved_by = None;
                    bus.tell(TrainChange::ReservationReleased(from), Some(from));
                }
            }
            TractionCommand::Noop => {}
        }
        self.rearm(now, heard);
    }

    /// Function `address` set to `value` by `from` (Set Function, or a write to space 0xF9):
    /// the application told, the listeners linked to it told in turn; `false`: no such
    /// function is kept.
    fn set_function(&mut self, bus: &mut Bus<'_>, from: NodeId, address: u32, value: u16) -> bool {
        let Some(slot) = self.functions.get_mut(address as usize) else { return false };
        *slot = value;
        self.functions_changed = true;
        bus.tell(TrainChange::Function { address, value }, Some(from));
        self.forward(bus, Some(from), TractionCommand::SetFunction { address, value, forwarded: false });
        true
    }

    /// A forwarded command that changes nothing, or the echo of a speed this train
    /// forwarded (the same, or reversed by a listener's flag) within [`ECHO_WINDOW`]: a
    /// listener loop brought it back, and it goes no further.
    fn is_echo(&self, now: Instant, command: TractionCommand) -> bool {
        match command {
            TractionCommand::SetSpeed { speed, forwarded: true } => self
                .last_forward
                .is_some_and(|(at, sent)| now < at + ECHO_WINDOW && (speed == sent || speed == sent.reversed())),
            TractionCommand::SetFunction { address, value, forwarded: true } => {
                self.functions.get(address as usize) == Some(&value)
            }
            TractionCommand::EmergencyStop { forwarded: true } => self.estop,
            _ => false,
        }
    }

    fn on_timeout(&mut self, now: Instant, bus: &mut Bus<'_>) {
        if self.heartbeat_deadline.is_some_and(|d| d <= now) {
            self.heartbeat_deadline = None;
            self.heartbeat_at = None;
            bump(&mut bus.stats.heartbeat_timeouts);
            let stop = TractionCommand::SetSpeed { speed: self.set_speed.stopped(), forwarded: true };
            self.set_speed = self.set_speed.stopped();
            self.last_forward = Some((now, self.set_speed));
            if let Some(controller) = self.controller {
                bus.tell(TrainChange::HeartbeatTimedOut(controller), None);
            }
            self.tell_speed(bus, None);
            self.forward(bus, None, stop);
        }
        if let (Some(at), Some(controller)) = (self.heartbeat_at, self.controller)
            && at <= now
        {
            self.heartbeat_at = None;
            // The deadline in one byte, as OpenMRN and OpenLCB_Java (JMRI's throttles) read it.
            let secs = self.heartbeat_secs().min(u32::from(u8::MAX));
            bus.reply(controller, alloc::vec![wire::MANAGEMENT, wire::MANAGEMENT_NOOP, secs as u8]);
            bump(&mut bus.stats.heartbeats_sent);
            self.heartbeat_deadline = Some(now + Duration::from_secs(u64::from(secs)));
        }
    }

    fn deadline(&self) -> Option<Instant> {
        earliest(self.heartbeat_at, self.heartbeat_deadline)
    }

    /// The emergency events and Is Train; `true`: the message was the train's.
    fn on_event(&mut self, bus: &mut Bus<'_>, msg: MessageRef<'_>, event: EventId) -> bool {
        match msg.mti {
            Mti::PRODUCER_CONSUMER_EVENT_REPORT => {
                let (flag, on, change): (&mut bool, bool, fn(bool) -> TrainChange) = match event {
                    EMERGENCY_STOP => (&mut self.global_stop, true, TrainChange::GlobalStop),
                    CLEAR_EMERGENCY_STOP => (&mut self.global_stop, false, TrainChange::GlobalStop),
                    EMERGENCY_OFF => (&mut self.global_off, true, TrainChange::GlobalOff),
                    CLEAR_EMERGENCY_OFF => (&mut self.global_off, false, TrainChange::GlobalOff),
                    _ => return false,
                };
                if *flag != on {
                    *flag = on;
                    bus.tell(change(on), Some(msg.source));
                    self.tell_speed(bus, Some(msg.source));
                }
                true
            }
            Mti::IDENTIFY_PRODUCER if event == IS_TRAIN => {
                bus.event(Mti::PRODUCER_IDENTIFIED_VALID, IS_TRAIN);
                true
            }
            Mti::IDENTIFY_PRODUCER => match SearchQuery::parse(event) {
                Ok(query) => {
                    if query.matches(&self.config.identity) {
                        bump(&mut bus.stats.searches_answered);
                        bus.event(Mti::PRODUCER_IDENTIFIED_VALID, event);
                    } else if query.allocate() && self.config.allocate {
                        allocate(bus, query, event, msg.source);
                    }
                    true
                }
                Err(SearchError::Reserved) => {
                    bump(&mut bus.stats.searches_reserved);
                    true
                }
                Err(SearchError::NotSearch) => false,
            },
            Mti::IDENTIFY_CONSUMER => match self.emergency_state(event) {
                Some(active) => {
                    let mti = if active { Mti::CONSUMER_IDENTIFIED_VALID } else { Mti::CONSUMER_IDENTIFIED_INVALID };
                    bus.event(mti, event);
                    true
                }
                None => false,
            },
            _ => false,
        }
    }

    /// Whether the emergency event `event` is the state now (`None`: no such event).
    fn emergency_state(&self, event: EventId) -> Option<bool> {
        Some(match event {
            EMERGENCY_STOP => self.global_stop,
            CLEAR_EMERGENCY_STOP => !self.global_stop,
            EMERGENCY_OFF => self.global_off,
            CLEAR_EMERGENCY_OFF => !self.global_off,
            _ => return None,
        })
    }

    /// Identify Events: Is Train produced, the emergency events consumed.
    fn identify(&self, bus: &mut Bus<'_>) {
        bus.event(Mti::PRODUCER_IDENTIFIED_VALID, IS_TRAIN);
        for event in [EMERGENCY_OFF, CLEAR_EMERGENCY_OFF, EMERGENCY_STOP, CLEAR_EMERGENCY_STOP] {
            let active = self.emergency_state(event) == Some(true);
            let mti = if active { Mti::CONSUMER_IDENTIFIED_VALID } else { Mti::CONSUMER_IDENTIFIED_INVALID };
            bus.event(mti, event);
        }
    }
}

/// Hands an allocate search this command station can serve to the application.
fn allocate(bus: &mut Bus<'_>, query: SearchQuery, event: EventId, from: NodeId) {
    let Some(address) = query.address() else { return };
    let protocol = match query.protocol() {
        SearchProtocol::Any | SearchProtocol::Dcc { long: false } if (1..128).contains(&address) => {
            TrainProtocol::Dcc { long: false }
        }
        SearchProtocol::Any | SearchProtocol::Dcc { .. } if (1..=10239).contains(&address) => {
            TrainProtocol::Dcc { long: true }
        }
        _ => return,
    };
    bus.tell(TrainChange::Allocate { event, address, protocol }, Some(from));
}

impl TrainService {
    pub(crate) fn new(config: Option<&TrainConfig>, throttle: Option<&ThrottleConfig>, announce: bool) -> Self {
        TrainService {
            train: config.cloned().map(Train::new),
            throttle: throttle.cloned().map(Throttle::new),
            announce: announce && config.is_some_and(|c| c.announce),
            stats: TrainStats::default(),
        }
    }

    pub(crate) fn is_train(&self) -> bool {
        self.train.is_some()
    }

    /// Keeps space 0xF9 of `server` and the train's functions one (Train Control Standard
    /// §7.1): the space is served once the node has a memory server (unless the application
    /// serves a 0xF9 of its own); each byte a tool wrote there that differs from its
    /// function is a Set Function from that tool, and the functions are copied back after
    /// any change, a value past 255 as 255.
    pub(crate) fn sync_memory(&mut self, out: &mut Outputs, server: &mut MemoryServer) {
        let Some(train) = &mut self.train else { return };
        if server.functions.is_none() && server.space(SPACE_FUNCTIONS).is_none() {
            server.functions = Some(FunctionMirror::default());
            train.functions_changed = true;
        }
        let Some(mirror) = &mut server.functions else { return };
        if let Some(writer) = mirror.written_by.take() {
            let mut bus = Bus { out, stats: &mut self.stats };
            for (address, byte) in (0u32..).zip(mirror.values.iter()) {
                if train.functions.get(address as usize).is_some_and(|&value| function_byte(value) != *byte) {
                    train.set_function(&mut bus, writer, address, u16::from(*byte));
                }
            }
        }
        if core::mem::take(&mut train.functions_changed) {
            mirror.values.clear();
            mirror.values.extend(train.functions.iter().map(|&value| function_byte(value)));
        }
    }

    /// Produce Is Train again (after the node's Initialization Complete).
    pub(crate) fn announce(&mut self) {
        self.announce = self.train.as_ref().is_some_and(|t| t.config.announce);
    }
}

impl Service<Lent<'_>> for TrainService {
    fn handle_message(&mut self, cx: &mut Lent<'_>, msg: MessageRef<'_>) -> bool {
        if let Some(throttle) = &mut self.throttle {
            let event = match msg.mti {
                Mti::TRACTION_CONTROL_COMMAND => throttle.on_command(cx.out, msg.source, msg.payload),
                Mti::TRACTION_CONTROL_REPLY => throttle.on_reply(cx.out, msg.source, msg.payload),
                _ => None,
            };
            if let Some(event) = event {
                if !cx.out.notify(NodeEvent::Throttle(event)) {
                    bump(&mut self.stats.notices_dropped);
                }
                return true;
            }
            if msg.mti == Mti::TRACTION_CONTROL_REPLY {
                return true;
            }
        }
        let Some(train) = &mut self.train else { return false };
        let mut bus = Bus { out: &mut *cx.out, stats: &mut self.stats };
        match msg.mti {
            Mti::TRACTION_CONTROL_COMMAND => {
                train.on_command(cx.now, &mut bus, msg.source, msg.payload);
                true
            }
            // Answers to what the train sent (Controller Changing Notify): nothing waits.
            Mti::TRACTION_CONTROL_REPLY => true,
            Mti::IDENTIFY_EVENTS_GLOBAL | Mti::IDENTIFY_EVENTS_ADDRESSED => {
                train.identify(&mut bus);
                true
            }
            Mti::INITIALIZATION_COMPLETE | Mti::INITIALIZATION_COMPLETE_SIMPLE => {
                // A restarted node holds nothing of before: its reservation ends.
                if train.reserved_by == Some(msg.source) {
                    train.reserved_by = None;
                    bus.tell(TrainChange::ReservationReleased(msg.source), Some(msg.source));
                }
                false
            }
            mti if crate::events::is_event_mti(mti) => match EventId::from_slice(msg.payload) {
                Some(event) => train.on_event(&mut bus, msg, event),
                None => false,
            },
            _ => false,
        }
    }

    /// A train's reject of a command of this throttle.
    fn handle_error_report(&mut self, cx: &mut Lent<'_>, peer: NodeId, report: ErrorReport) -> bool {
        let Some(throttle) = &self.throttle else { return false };
        if report.mti != Some(Mti::TRACTION_CONTROL_COMMAND) && !(report.mti.is_none() && throttle.controls(peer)) {
            return false;
        }
        if !cx.out.notify(NodeEvent::Throttle(ThrottleEvent::Rejected { train: peer, code: report.code })) {
            bump(&mut self.stats.notices_dropped);
        }
        true
    }

    fn peer_changed(&mut self, out: &mut Outputs, change: ServiceChange) {
        if let Some(throttle) = &mut self.throttle
            && !throttle.peer_changed(out, change)
        {
            bump(&mut self.stats.notices_dropped);
        }
        let Some(train) = &mut self.train else { return };
        if let Some(holder) = train.reserved_by
            && change.loses(holder)
        {
            train.reserved_by = None;
        }
        for node in train.controller.iter_mut().chain(train.reserved_by.iter_mut()) {
            change.rename(node);
        }
        for listener in &mut train.listeners {
            change.rename(&mut listener.node);
        }
    }

    fn handle_timeout(&mut self, cx: &mut Lent<'_>) {
        let Some(train) = &mut self.train else { return };
        let mut bus = Bus { out: &mut *cx.out, stats: &mut self.stats };
        if core::mem::take(&mut self.announce) {
            bus.event(Mti::PRODUCER_IDENTIFIED_VALID, IS_TRAIN);
        }
        train.on_timeout(cx.now, &mut bus);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        if self.announce {
            return Some(Instant::ZERO);
        }
        self.train.as_ref().and_then(Train::deadline)
    }
}

/// Train commands.
impl Node {
    /// The train's state (`None`: this node is no train).
    pub fn train(&self) -> Option<TrainState> {
        self.services.trains.train.as_ref().map(Train::state)
    }

    /// The value of function `address` (`None`: no train, or past
    /// [`TrainConfig::functions`]).
    pub fn train_function(&self, address: u32) -> Option<u16> {
        self.services.trains.train.as_ref()?.functions.get(address as usize).copied()
    }

    /// Listener `index` of the train, in the order attached, with its flags.
    pub fn train_listener(&self, index: usize) -> Option<(NodeId, u8)> {
        let listener = self.services.trains.train.as_ref()?.listeners.get(index)?;
        Some((listener.node, listener.flags))
    }

    /// The traction service's counters (zero for a node that is no train).
    pub fn train_stats(&self) -> TrainStats {
        self.services.trains.stats
    }

    /// Sends `command` to `train` as this node's throttle; the answers come as
    /// [`NodeEvent::Throttle`](crate::NodeEvent::Throttle). An Assign Controller counts the
    /// train as controlled (until refused, released or taken over).
    pub fn throttle_command(&mut self, train: NodeId, command: TractionCommand) -> Result<(), ThrottleError> {
        let throttle = self.services.trains.throttle.as_mut().ok_or(ThrottleError::NotAThrottle)?;
        throttle.send(&mut self.out, train, command)
    }

    /// The trains this node's throttle controls (or has asked to).
    pub fn controlled_trains(&self) -> &[NodeId] {
        self.services.trains.throttle.as_ref().map_or(&[], |t| t.controlled())
    }

    /// The train's address, protocol and name from now on (its configuration changed): Train
    /// Search queries are matched against them. The train's speed, functions, controller
    /// and listeners stay.
    pub fn set_train_identity(&mut self, identity: TrainIdentity) -> Result<(), TrainError> {
        let train = self.services.trains.train.as_mut().ok_or(TrainError::NotATrain)?;
        train.config.identity = identity;
        Ok(())
    }

    /// Answers the Train Search `event` with Producer Identified Valid, as a train a command
    /// station created for it does (§6.2).
    pub fn answer_train_search(&mut self, event: EventId) -> Result<(), TrainError> {
        let train = self.services.trains.train.as_ref().ok_or(TrainError::NotATrain)?;
        let query = SearchQuery::parse(event).map_err(|_| TrainError::NoMatch)?;
        if !query.matches(&train.config.identity) {
            return Err(TrainError::NoMatch);
        }
        if !self.out.has_room() {
            return Err(TrainError::QueueFull);
        }
        let node = self.out.node;
        self.out.transmit(Message::global(Mti::PRODUCER_IDENTIFIED_VALID, node, event.to_bytes()));
        Ok(())
    }
}
