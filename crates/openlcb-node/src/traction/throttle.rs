//! The throttle side of Traction Control: commands to trains, their replies read, heartbeat
//! requests answered, and a controller taken over reported.

use alloc::vec::Vec;

use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Message, Mti, NodeId};

use super::wire::{self, Speed, TractionCommand};
use crate::node::Outputs;

/// A node's throttle role ([`NodeConfig::throttle`](crate::NodeConfig::throttle)).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ThrottleConfig {
    /// Trains this node controls at once; an assign past it is refused here, not sent.
    pub max_trains: usize,
    /// Answer a controlled train's heartbeat request with a No-op at once.
    pub answer_heartbeats: bool,
}

impl Default for ThrottleConfig {
    fn default() -> Self {
        ThrottleConfig { max_trains: 8, answer_heartbeats: true }
    }
}

/// What a train answered or told this throttle ([`NodeEvent::Throttle`](crate::NodeEvent::Throttle)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ThrottleEvent {
    /// An Assign Controller was accepted: this node controls `train`.
    Assigned {
        /// The train.
        train: NodeId,
    },
    /// An Assign Controller was refused (the reply's result byte).
    AssignRefused {
        /// The train.
        train: NodeId,
        /// Bit 0: the controller refused; bit 1: the train refused.
        result: u8,
    },
    /// A Query Speeds reply.
    Speeds {
        /// The train.
        train: NodeId,
        /// Its Set Speed.
        set: Speed,
        /// In Emergency Stop.
        emergency_stop: bool,
        /// Its commanded speed (NaN: not given).
        commanded: Speed,
        /// Its actual speed (NaN: not known).
        actual: Speed,
    },
    /// A Query Function reply.
    Function {
        /// The train.
        train: NodeId,
        /// The function.
        address: u32,
        /// Its value.
        value: u16,
    },
    /// A Query Controller reply.
    Controller {
        /// The train.
        train: NodeId,
        /// Its controller.
        controller: Option<NodeId>,
    },
    /// An Attach or Detach Listener reply.
    ListenerChanged {
        /// The train.
        train: NodeId,
        /// The listener.
        listener: NodeId,
        /// Attached (else detached).
        attached: bool,
        /// 0: done; else the error code (0x1030 not found, 0x2020 table full, ...).
        code: u16,
    },
    /// A Query Nodes reply: the count, and the listener asked for if there is one.
    Listener {
        /// The train.
        train: NodeId,
        /// How many listeners it has.
        count: u8,
        /// Index, flags and Node ID of the one asked for.
        entry: Option<(u8, u8, NodeId)>,
    },
    /// A Reserve reply.
    Reserved {
        /// The train.
        train: NodeId,
        /// The reservation is this node's.
        ok: bool,
    },
    /// A controlled train asked for a heartbeat (answered already when
    /// [`ThrottleConfig::answer_heartbeats`]).
    HeartbeatRequested {
        /// The train.
        train: NodeId,
        /// Seconds it gives.
        deadline_secs: u32,
    },
    /// Another node took the train over (Controller Changing Notify): this node no longer
    /// controls it.
    ControllerLost {
        /// The train.
        train: NodeId,
        /// The new controller.
        to: NodeId,
    },
    /// A train this node controls is gone: its node left the network (on CAN its alias was
    /// released, or a Verify Node ID found it missing), or this node's own link was lost. It
    /// is no longer controlled here; a train that comes back must be assigned again.
    TrainLost {
        /// The train.
        train: NodeId,
    },
    /// The train rejected a command (Optional Interaction Rejected or Terminate Due To Error).
    Rejected {
        /// The train.
        train: NodeId,
        /// The error code.
        code: ErrorCode,
    },
}

/// Why a throttle command was not sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ThrottleError {
    /// The node has no [`NodeConfig::throttle`](crate::NodeConfig::throttle).
    #[error("this node is no throttle")]
    NotAThrottle,
    /// [`ThrottleConfig::max_trains`] are controlled already.
    #[error("this throttle controls as many trains as it may")]
    TooManyTrains,
    /// The transmit queue is full.
    #[error("the transmit queue is full")]
    QueueFull,
}

#[derive(Debug)]
pub(crate) struct Throttle {
    config: ThrottleConfig,
    /// The trains this node controls (or asked to), in order.
    trains: Vec<NodeId>,
}

impl Throttle {
    pub(crate) fn new(config: ThrottleConfig) -> Self {
        Throttle { config, trains: Vec::new() }
    }

    pub(crate) fn controls(&self, train: NodeId) -> bool {
        self.trains.contains(&train)
    }

    pub(crate) fn controlled(&self) -> &[NodeId] {
        &self.trains
    }

    /// A lost train is no longer controlled, and is told to the application
    /// ([`ThrottleEvent::TrainLost`]; false if a notice was dropped); a renamed one keeps its
    /// place.
    pub(crate) fn peer_changed(&mut self, out: &mut Outputs, change: crate::service::ServiceChange) -> bool {
        let mut told = true;
        for train in self.trains.iter().filter(|t| change.loses(**t)) {
            told &= out.notify(crate::NodeEvent::Throttle(ThrottleEvent::TrainLost { train: *train }));
        }
        self.trains.retain(|t| !change.loses(*t));
        for train in &mut self.trains {
            change.rename(train);
        }
        told
    }

    /// Sends `command` to `train`.
    pub(crate) fn send(
        &mut self,
        out: &mut Outputs,
        train: NodeId,
        command: TractionCommand,
    ) -> Result<(), ThrottleError> {
        if !out.has_room() {
            return Err(ThrottleError::QueueFull);
        }
        match command {
            TractionCommand::AssignController { .. } if !self.controls(train) => {
                if self.trains.len() >= self.config.max_trains {
                    return Err(ThrottleError::TooManyTrains);
                }
                self.trains.push(train);
            }
            TractionCommand::ReleaseController { .. } => self.trains.retain(|t| *t != train),
            _ => {}
        }
        let node = out.node;
        out.transmit(Message::addressed(Mti::TRACTION_CONTROL_COMMAND, node, train, command.to_bytes()));
        Ok(())
    }

    /// A Traction Control Reply from `train`; `None`: nothing the application needs.
    pub(crate) fn on_reply(&mut self, out: &mut Outputs, train: NodeId, payload: &[u8]) -> Option<ThrottleEvent> {
        let node_at = |at: usize| payload.get(at..at + 6).and_then(NodeId::from_slice);
        let speed_at = |at: usize| match payload.get(at..at + 2) {
            Some([hi, lo]) => Speed::from_bits(u16::from_be_bytes([*hi, *lo])),
            _ => Speed::NAN,
        };
        Some(match (payload.first().copied()?, payload.get(1).copied()) {
            (wire::QUERY_SPEEDS, _) if payload.len() >= 3 => ThrottleEvent::Speeds {
                train,
                set: speed_at(1),
                emergency_stop: payload.get(3).is_some_and(|s| s & 1 != 0),
                commanded: speed_at(4),
                actual: speed_at(6),
            },
            (wire::QUERY_FUNCTION, _) => {
                let address = match payload.get(1..4) {
                    Some([a, b, c]) => u32::from_be_bytes([0, *a, *b, *c]),
                    _ => return None,
                };
                let value = match payload.get(4..6) {
                    Some([hi, lo]) => u16::from_be_bytes([*hi, *lo]),
                    _ => u16::from(*payload.get(4)?),
                };
                ThrottleEvent::Function { train, address, value }
            }
            (wire::CONTROLLER, Some(wire::CONTROLLER_ASSIGN)) => {
                let result = *payload.get(2)?;
                if result == 0 {
                    ThrottleEvent::Assigned { train }
                } else {
                    self.trains.retain(|t| *t != train);
                    ThrottleEvent::AssignRefused { train, result }
                }
            }
            (wire::CONTROLLER, Some(wire::CONTROLLER_QUERY)) => {
                let controller = node_at(3).filter(|n| n.as_raw() != 0);
                ThrottleEvent::Controller { train, controller }
            }
            (wire::LISTENER, Some(sub @ (wire::LISTENER_ATTACH | wire::LISTENER_DETACH))) => {
                let code = match payload.get(8..10) {
                    Some([hi, lo]) => u16::from_be_bytes([*hi, *lo]),
                    _ => u16::from(*payload.get(8)?),
                };
                ThrottleEvent::ListenerChanged {
                    train,
                    listener: node_at(2)?,
                    attached: sub == wire::LISTENER_ATTACH,
                    code,
                }
            }
            (wire::LISTENER, Some(wire::LISTENER_QUERY)) => {
                let entry = match (payload.get(3), payload.get(4), node_at(5)) {
                    (Some(index), Some(flags), Some(node)) => Some((*index, *flags, node)),
                    _ => None,
                };
                ThrottleEvent::Listener { train, count: *payload.get(2)?, entry }
            }
            (wire::MANAGEMENT, Some(wire::MANAGEMENT_RESERVE)) => {
                ThrottleEvent::Reserved { train, ok: payload.get(2) == Some(&0) }
            }
            (wire::MANAGEMENT, Some(wire::MANAGEMENT_NOOP)) if self.controls(train) => {
                let deadline_secs = match payload.get(2..5) {
                    Some([a, b, c]) => u32::from_be_bytes([0, *a, *b, *c]),
                    _ => u32::from(payload.get(2).copied().unwrap_or(0)),
                };
                if self.config.answer_heartbeats {
                    let node = out.node;
                    let noop = TractionCommand::Noop.to_bytes();
                    out.reply(Message::addressed(Mti::TRACTION_CONTROL_COMMAND, node, train, noop));
                }
                ThrottleEvent::HeartbeatRequested { train, deadline_secs }
            }
            _ => return None,
        })
    }

    /// A Traction Control Command to this node: a controlled train's Controller Changing
    /// Notify is accepted (`Some`); anything else is not the throttle's (`None`).
    pub(crate) fn on_command(&mut self, out: &mut Outputs, train: NodeId, payload: &[u8]) -> Option<ThrottleEvent> {
        let Ok(TractionCommand::ControllerChanging { node: to, .. }) = TractionCommand::parse(payload) else {
            return None;
        };
        if !self.controls(train) {
            return None;
        }
        self.trains.retain(|t| *t != train);
        let node = out.node;
        let accept = alloc::vec![wire::CONTROLLER, wire::CONTROLLER_CHANGING, 0];
        out.reply(Message::addressed(Mti::TRACTION_CONTROL_REPLY, node, train, accept));
        Some(ThrottleEvent::ControllerLost { train, to })
    }
}
