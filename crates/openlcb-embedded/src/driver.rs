//! [`Driver`]: the drive loop between a CAN peripheral, a [`CanLink`] and the layer above.

use embedded_can::Frame;
use embedded_can::nb::Can;
use openlcb_can::{CanFrame, CanLink, LinkEvent};
use openlcb_stream::Instant;

use crate::upper::{Clock, Upper};

/// Received frames handled in one [`Driver::poll`] by default, so that a busy bus cannot
/// starve transmission (a receive FIFO holds 2-3 frames on most controllers; more wait).
pub const DEFAULT_RECEIVE_BUDGET: usize = 32;

/// What went wrong in the peripheral. The driver's state stays consistent: a frame that
/// could not be transmitted is kept for the next poll.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Error<E> {
    /// `receive` failed (an overrun, a bus error): frames may have been lost on the way in.
    Receive(E),
    /// `transmit` failed; the frame is kept and offered again on the next poll.
    Transmit(E),
}

impl<E: core::fmt::Debug> core::fmt::Display for Error<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Receive(e) => write!(f, "CAN receive error: {e:?}"),
            Error::Transmit(e) => write!(f, "CAN transmit error: {e:?}"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for Error<E> {}

/// Counters of a [`Driver`], 32-bit like the CAN link's (64-bit ones cost a microcontroller
/// flash and RAM); each stops at `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct DriverStats {
    /// Frames taken from the peripheral.
    pub frames_received: u32,
    /// Frames the peripheral accepted.
    pub frames_transmitted: u32,
    /// `transmit` answered `WouldBlock`: the frame was kept for later.
    pub would_block: u32,
    /// `transmit` accepted a frame by giving back a pending lower-priority one, which was
    /// kept and offered again.
    pub displaced: u32,
    /// Frames that have no form in the other frame type (a received frame with more than 8
    /// data bytes); dropped.
    pub unconvertible: u32,
    /// Messages of the upper layer the link refused (no CAN form, or the link stopped after
    /// a duplicate Node ID); dropped.
    pub send_refused: u32,
    /// `receive` errors.
    pub receive_errors: u32,
    /// `transmit` errors.
    pub transmit_errors: u32,
}

/// What one [`Driver::poll`] did and when the next one is due.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct Poll {
    /// The time this poll ran at.
    pub now: Instant,
    /// Frames received.
    pub received: usize,
    /// Frames transmitted.
    pub transmitted: usize,
    /// The peripheral refused a frame (it is kept): poll again once it has room (its
    /// transmit interrupt), or soon.
    pub transmit_blocked: bool,
    /// The receive budget ran out with frames maybe still waiting: poll again at once.
    pub receive_pending: bool,
    /// The earliest deadline of the link and the upper layer: poll again by then.
    pub deadline: Option<Instant>,
}

impl Poll {
    /// Nothing moved and nothing waits: the caller may sleep until [`deadline`](Poll::deadline)
    /// or the next CAN interrupt, after handling the upper layer's events.
    pub fn is_idle(&self) -> bool {
        self.received == 0 && self.transmitted == 0 && !self.transmit_blocked && !self.receive_pending
    }
}

/// One node on a CAN peripheral: owns the peripheral `C`, the clock `K` and the node's
/// [`CanLink`]; the layer above (a stream endpoint, a node) is lent to each
/// [`poll`](Driver::poll), so that the application keeps using it between polls.
///
/// A poll reads the clock once, runs due timers, takes received frames into the link (which
/// hands the upper layer the peer changes it learns, as it learns them, then the messages: a
/// peer's rename reaches the upper layer before the messages sent under its new name), acts
/// on the link's own events (an alias lost, a duplicate Node ID), moves the upper layer's
/// messages into the link while it has room, and hands frames to the peripheral until it
/// refuses one. A refused frame is kept and offered first on the next poll; a frame the
/// peripheral gives back in exchange for a higher-priority one (`Ok(Some(frame))`) is kept
/// likewise. Nothing is allocated: frames are converted between the peripheral's frame type
/// and [`CanFrame`] on the stack.
///
/// embedded-can asks peripherals to send frames of equal identifier in FIFO order, and to
/// replace only a lower-priority frame. OpenLCB sends the frames of a message, and the data
/// frames of a stream, under one identifier; a peripheral that gives back one of several
/// pending frames of equal identifier other than the newest breaks that order (a bxcan in
/// priority mode with all three mailboxes full of one identifier can: use FIFO mode).
///
/// The link must not hear its own frames: a controller in loopback or echo mode must filter
/// them out (they would read as an alias collision).
#[derive(Debug)]
pub struct Driver<C: Can, K> {
    can: C,
    clock: K,
    link: CanLink,
    /// A frame the peripheral refused or gave back: transmitted before anything else.
    held: Option<C::Frame>,
    receive_budget: usize,
    stats: DriverStats,
}

impl<C: Can, K: Clock> Driver<C, K> {
    /// A driver for `link` on the peripheral `can`, reading the time from `clock`. Create the
    /// link at the clock's current time: its login starts then.
    pub fn new(can: C, clock: K, link: CanLink) -> Self {
        Driver { can, clock, link, held: None, receive_budget: DEFAULT_RECEIVE_BUDGET, stats: DriverStats::default() }
    }

    /// Sets how many received frames one poll takes at most (at least 1).
    pub fn with_receive_budget(mut self, frames: usize) -> Self {
        self.receive_budget = frames.max(1);
        self
    }

    /// The link.
    pub fn link(&self) -> &CanLink {
        &self.link
    }

    /// The link, for its commands.
    pub fn link_mut(&mut self) -> &mut CanLink {
        &mut self.link
    }

    /// The peripheral.
    pub fn can(&self) -> &C {
        &self.can
    }

    /// The peripheral, for its own configuration.
    pub fn can_mut(&mut self) -> &mut C {
        &mut self.can
    }

    /// Counters.
    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    /// A frame is held because the peripheral refused it.
    pub fn is_transmit_blocked(&self) -> bool {
        self.held.is_some()
    }

    /// The current time, from the clock.
    pub fn now(&mut self) -> Instant {
        self.clock.now()
    }

    /// Gives back the peripheral, the clock and the link (a held frame is dropped).
    pub fn into_parts(self) -> (C, K, CanLink) {
        (self.can, self.clock, self.link)
    }

    /// One turn of the drive loop (see the type's documentation). After it, handle the upper
    /// layer's events and commands, then poll again: at once if the result is not
    /// [idle](Poll::is_idle), else by its deadline or on a CAN interrupt.
    ///
    /// A peripheral error stops that half of the turn (receiving or transmitting) and is
    /// returned at the end of it; nothing is lost by the driver, and the next poll goes on.
    pub fn poll<U: Upper + ?Sized>(&mut self, upper: &mut U) -> Result<Poll, Error<C::Error>> {
        let now = self.clock.now();
        if self.deadline(upper).is_some_and(|at| at <= now) {
            self.link.handle_timeout(now, upper);
            upper.handle_timeout(now);
        }
        let (received, receive_error) = self.receive(now, upper);
        self.pump(now, upper);
        let (transmitted, transmit_error) = self.transmit();
        if transmitted > 0 && self.held.is_none() {
            // Everything the link handed out is with the peripheral: the login's reserve
            // wait counts from here (a first poll may come well after the link was made).
            let sent = self.clock.now();
            self.link.frames_sent(sent);
        }
        let poll = Poll {
            now,
            received,
            transmitted,
            transmit_blocked: self.held.is_some(),
            receive_pending: received == self.receive_budget,
            deadline: self.deadline(upper),
        };
        match receive_error.or(transmit_error) {
            Some(error) => Err(error),
            None => Ok(poll),
        }
    }

    fn deadline<U: Upper + ?Sized>(&self, upper: &U) -> Option<Instant> {
        match (self.link.poll_timeout(), upper.poll_timeout()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn receive<U: Upper + ?Sized>(&mut self, now: Instant, upper: &mut U) -> (usize, Option<Error<C::Error>>) {
        let mut received = 0;
        while received < self.receive_budget {
            let frame = match self.can.receive() {
                Ok(frame) => frame,
                Err(nb::Error::WouldBlock) => break,
                Err(nb::Error::Other(error)) => {
                    bump(&mut self.stats.receive_errors);
                    return (received, Some(Error::Receive(error)));
                }
            };
            received += 1;
            bump(&mut self.stats.frames_received);
            match convert::<_, CanFrame>(&frame) {
                Some(frame) => self.link.handle_frame(now, &frame, upper),
                None => bump(&mut self.stats.unconvertible),
            }
        }
        (received, None)
    }

    /// The link's events acted on, upper-layer messages down while the link has room.
    fn pump<U: Upper + ?Sized>(&mut self, now: Instant, upper: &mut U) {
        self.apply_link_events(now, upper);
        while self.link.can_send() {
            let Some(message) = upper.poll_transmit() else {
                break;
            };
            if self.link.send(now, message).is_err() {
                bump(&mut self.stats.send_refused);
            }
        }
    }

    /// The link's own events: an alias lost ends everything open above; a duplicate Node ID
    /// is reported (the upper layer's Duplicate Node ID Detected), and if another node had
    /// this Node ID first the link leaves after the report and everything open ends.
    fn apply_link_events<U: Upper + ?Sized>(&mut self, now: Instant, upper: &mut U) {
        while let Some(event) = self.link.poll_event() {
            match event {
                LinkEvent::AliasLost { .. } => upper.link_lost(),
                LinkEvent::DuplicateNodeId { newcomer: true, .. } => {
                    self.link.leave(upper.duplicate_node_id_report());
                    upper.link_lost();
                }
                LinkEvent::DuplicateNodeId { newcomer: false, .. } => {
                    if let Some(report) = upper.duplicate_node_id_report()
                        && self.link.send(now, report).is_err()
                    {
                        bump(&mut self.stats.send_refused);
                    }
                }
                _ => {}
            }
        }
    }

    fn transmit(&mut self) -> (usize, Option<Error<C::Error>>) {
        let mut transmitted = 0;
        loop {
            let frame = match self.held.take() {
                Some(frame) => frame,
                None => {
                    let Some(frame) = self.link.poll_transmit() else {
                        return (transmitted, None);
                    };
                    match convert::<_, C::Frame>(&frame) {
                        Some(frame) => frame,
                        None => {
                            bump(&mut self.stats.unconvertible);
                            continue;
                        }
                    }
                }
            };
            match self.can.transmit(&frame) {
                Ok(displaced) => {
                    transmitted += 1;
                    bump(&mut self.stats.frames_transmitted);
                    if displaced.is_some() {
                        bump(&mut self.stats.displaced);
                        self.held = displaced;
                    }
                }
                Err(nb::Error::WouldBlock) => {
                    bump(&mut self.stats.would_block);
                    self.held = Some(frame);
                    return (transmitted, None);
                }
                Err(nb::Error::Other(error)) => {
                    bump(&mut self.stats.transmit_errors);
                    self.held = Some(frame);
                    return (transmitted, Some(Error::Transmit(error)));
                }
            }
        }
    }
}

/// The same frame in another frame type; `None` if it has no form there (more data than the
/// target holds).
pub fn convert<A: Frame, B: Frame>(frame: &A) -> Option<B> {
    if frame.is_remote_frame() { B::new_remote(frame.id(), frame.dlc()) } else { B::new(frame.id(), frame.data()) }
}

/// Counts one more, stopping at `u32::MAX`. Out of line: one copy of the add for every counter.
#[inline(never)]
fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}
