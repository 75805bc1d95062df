//! The driver against in-memory peripherals: alias login, a verified transfer through a
//! memory bus that pushes back, `WouldBlock` and displaced frames never losing a frame,
//! peripheral errors, and frames of a foreign frame type.

use std::cell::Cell;
use std::collections::VecDeque;

use embedded_can::nb::Can;
use embedded_can::{ErrorKind, ExtendedId, Frame, Id};
use openlcb_can::{CanConfig, CanFrame, CanLink};
use openlcb_embedded::memory_bus::MemoryBus;
use openlcb_embedded::{Driver, Error, Poll, Upper};
use openlcb_node::{MemoryEvent, MemoryServer, Node, NodeConfig, NodeEvent, RamSpace, SnipInfo, TransferPath};
use openlcb_stream::{
    Config, Event, Instant, NodeId, OpenOptions, PeerChange, PeerChanges, Receiver, StreamEndpoint, StreamHandle,
};

const A: u64 = 0x05_01_01_01_22_00;
const B: u64 = 0x05_01_01_01_22_01;

fn node(raw: u64) -> NodeId {
    NodeId::new(raw).unwrap()
}

/// The byte at `offset` of the test pattern (not periodic in any window size).
fn pattern(offset: u64) -> u8 {
    let x = offset.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    (x >> 56) as u8 ^ offset as u8
}

/// Jumps virtual time to the earliest deadline of the polls.
fn advance(time: &Cell<Instant>, polls: &[Poll]) {
    let next = polls.iter().filter_map(|p| p.deadline).min().expect("a timer is armed while idle");
    assert!(next <= time.get() + openlcb_stream::Duration::from_secs(60), "nothing left to wait for");
    time.set(next.max(time.get()));
}

// ----- login -----

#[test]
fn login_on_memory_bus_reserves_aliases_after_the_reserve_wait() {
    let bus: MemoryBus<CanFrame, 2, 8> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let clock = || time.get();
    let mut a = Driver::new(bus.port(0).unwrap(), clock, CanLink::new(time.get(), node(A), CanConfig::default()));
    let mut b = Driver::new(bus.port(1).unwrap(), clock, CanLink::new(time.get(), node(B), CanConfig::default()));
    let mut ea = StreamEndpoint::new(node(A), Config::default());
    let mut eb = StreamEndpoint::new(node(B), Config::default());

    let pa = a.poll(&mut ea).unwrap();
    let pb = b.poll(&mut eb).unwrap();
    assert_eq!((pa.transmitted, pb.transmitted), (4, 4), "CID 7..4 from each");
    assert_eq!(pa.deadline, Some(Instant::from_millis(200)));
    assert_eq!(a.link().alias(), None);

    // Before the reserve wait ends, nothing is permitted.
    time.set(Instant::from_millis(199));
    a.poll(&mut ea).unwrap();
    b.poll(&mut eb).unwrap();
    assert_eq!((a.link().alias(), b.link().alias()), (None, None));

    time.set(Instant::from_millis(200));
    for _ in 0..4 {
        a.poll(&mut ea).unwrap();
        b.poll(&mut eb).unwrap();
    }
    let (alias_a, alias_b) = (a.link().alias().unwrap(), b.link().alias().unwrap());
    assert_ne!(alias_a, alias_b);
    // Each learned the other's mapping from its AMD.
    assert_eq!(a.link().node_of(alias_b), Some(node(B)));
    assert_eq!(b.link().node_of(alias_a), Some(node(A)));
    // 4 CID + RID + AMD each; a bare endpoint sends no Initialization Complete (the node
    // layer does).
    assert_eq!(bus.stats().frames, 12);
    assert_eq!(a.stats().frames_transmitted, 6);
    assert_eq!(a.stats().frames_received, 6);
    assert_eq!(bus.queued(), 0);
}

#[test]
fn a_first_poll_that_comes_late_still_waits_200_ms_after_the_cids() {
    let bus: MemoryBus<CanFrame, 1, 8> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let link = CanLink::new(time.get(), node(A), CanConfig::default());
    let mut a = Driver::new(bus.port(0).unwrap(), || time.get(), link);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());
    // The firmware went on with its start-up for 15 ms before its first poll.
    time.set(Instant::from_millis(15));
    let first = a.poll(&mut endpoint).unwrap();
    assert_eq!(first.transmitted, 4, "the CIDs");
    assert_eq!(first.deadline, Some(Instant::from_millis(215)), "200 ms from the CIDs sent");
    time.set(Instant::from_millis(214));
    a.poll(&mut endpoint).unwrap();
    assert_eq!(a.link().alias(), None, "no RID 199 ms after the CIDs");
    time.set(Instant::from_millis(215));
    a.poll(&mut endpoint).unwrap();
    assert!(a.link().alias().is_some());
}

#[test]
fn nodes_on_memory_bus_announce_themselves_and_answer_snip_by_alias() {
    let bus: MemoryBus<CanFrame, 2, 8> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let clock = || time.get();
    let mut a = Driver::new(bus.port(0).unwrap(), clock, CanLink::new(time.get(), node(A), CanConfig::default()));
    let mut b = Driver::new(bus.port(1).unwrap(), clock, CanLink::new(time.get(), node(B), CanConfig::default()));
    let mut na = Node::new(node(A), NodeConfig::default());
    let mut b_config = NodeConfig::default();
    b_config.snip = SnipInfo { model: "Widget".into(), ..SnipInfo::default() };
    let mut nb = Node::new(node(B), b_config);

    let mut snip = None;
    for _ in 0..64 {
        let pa = a.poll(&mut na).unwrap();
        let pb = b.poll(&mut nb).unwrap();
        if a.link().alias().is_some() && b.link().alias().is_some() && bus.stats().frames == 16 {
            // 4 CID + RID + AMD + Initialization Complete and Verify Node ID naming itself
            // (the node's) each.
            assert_eq!(a.stats().frames_transmitted, 8);
            na.request_snip(time.get(), node(B)).unwrap();
        }
        while let Some(event) = na.poll_event() {
            if let NodeEvent::SnipReceived { peer, info } = event {
                snip = Some((peer, info.model));
            }
        }
        if snip.is_some() {
            break;
        }
        if pa.is_idle() && pb.is_idle() {
            advance(&time, &[pa, pb]);
        }
    }
    assert_eq!(snip, Some((node(B), "Widget".into())), "B's node answered through its driver");
}

#[test]
fn memory_configuration_works_through_the_driver_alone() {
    // A firmware drives its node through the driver and may leave its events for later: the
    // server's Read Stream and the client's read of it run all the same.
    let bus: MemoryBus<CanFrame, 2, 8> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let clock = || time.get();
    let mut a = Driver::new(bus.port(0).unwrap(), clock, CanLink::new(time.get(), node(A), CanConfig::default()));
    let mut b = Driver::new(bus.port(1).unwrap(), clock, CanLink::new(time.get(), node(B), CanConfig::default()));
    let contents: Vec<u8> = (0..600).map(pattern).collect();
    let space = RamSpace::from_bytes(contents.clone());
    let mut na = Node::new(node(A), NodeConfig::default());
    let mut nb =
        Node::new(node(B), NodeConfig::default()).with_memory_server(MemoryServer::new().with_space(0xFD, space));

    let mut operation = None;
    for _ in 0..2000 {
        let pa = a.poll(&mut na).unwrap();
        let pb = b.poll(&mut nb).unwrap();
        if operation.is_none() && a.link().alias().is_some() && b.link().alias().is_some() && bus.queued() == 0 {
            operation = Some(na.read_memory(time.get(), node(B), 0xFD, 0, None, TransferPath::Stream).unwrap());
        }
        if operation.is_some_and(|op| na.memory_progress(op).is_none()) {
            break;
        }
        if pa.is_idle() && pb.is_idle() {
            advance(&time, &[pa, pb]);
        }
    }
    let events: Vec<NodeEvent> = std::iter::from_fn(|| na.poll_event()).collect();
    let read = events.iter().find_map(|e| match e {
        NodeEvent::Memory(MemoryEvent::ReadDone { data, .. }) => Some(data),
        _ => None,
    });
    assert_eq!(read, Some(&contents), "{events:?}");
    assert_eq!(nb.memory_server().map(|s| s.stats().streams_done), Some(1));
}

// ----- a transfer -----

struct Outcome {
    received: u64,
    finished: bool,
    would_block: u64,
    bus_would_block: u64,
    bus_frames: u64,
    transmitted: u64,
}

/// Moves `len` bytes from A to B through a memory bus with receive FIFOs of `DEPTH` frames,
/// checking every byte against the pattern as it is read.
fn transfer<const DEPTH: usize>(len: u64, window: u16, read_chunk: usize) -> Outcome {
    let bus: MemoryBus<CanFrame, 2, DEPTH> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let clock = || time.get();
    let mut a = Driver::new(bus.port(0).unwrap(), clock, CanLink::new(time.get(), node(A), CanConfig::default()))
        .with_receive_budget(4);
    let mut b = Driver::new(bus.port(1).unwrap(), clock, CanLink::new(time.get(), node(B), CanConfig::default()))
        .with_receive_budget(4);
    let mut source = StreamEndpoint::new(node(A), Config::default());
    let mut destination = StreamEndpoint::new(node(B), Config::default());

    let mut stream: Option<StreamHandle> = None;
    let (mut sent, mut received, mut finished, mut source_done) = (0u64, 0u64, false, false);
    let mut chunk = [0u8; 512];
    let mut buf = vec![0u8; read_chunk];
    for _round in 0..2_000_000 {
        if finished && source_done {
            break;
        }
        let pa = a.poll(&mut source).unwrap();
        let pb = b.poll(&mut destination).unwrap();
        let mut worked = false;
        if stream.is_none() && a.link().alias().is_some() && b.link().alias().is_some() {
            stream = Some(source.open(time.get(), OpenOptions::new(node(B), window)).unwrap());
            worked = true;
        }
        while let Some(event) = source.poll_event() {
            match event {
                Event::Opened { .. } | Event::Writable { .. } => {}
                Event::Sent { total, .. } => {
                    assert_eq!(total, len, "the source sent a different total");
                    source_done = true;
                }
                other => panic!("source: unexpected {other:?}"),
            }
        }
        if let Some(handle) = stream.filter(|h| sent < len && source.credit(*h).unwrap_or(0) > 0) {
            let n = chunk.len().min((len - sent) as usize);
            for (i, byte) in chunk[..n].iter_mut().enumerate() {
                *byte = pattern(sent + i as u64);
            }
            let taken = source.write(time.get(), handle, &chunk[..n]).unwrap();
            sent += taken as u64;
            if sent == len {
                source.finish(time.get(), handle).unwrap();
            }
            worked |= taken > 0;
        }
        while let Some(event) = destination.poll_event() {
            match event {
                Event::Opened { .. } | Event::Readable { .. } => {}
                Event::Finished { total, matched, .. } => {
                    assert!(matched, "Complete's total does not match");
                    assert_eq!(total, len);
                    finished = true;
                }
                other => panic!("destination: unexpected {other:?}"),
            }
        }
        for handle in destination.handles().collect::<Vec<_>>() {
            while let Ok(n @ 1..) = destination.read(time.get(), handle, &mut buf) {
                for (i, byte) in buf[..n].iter().enumerate() {
                    assert_eq!(*byte, pattern(received + i as u64), "byte {} differs", received + i as u64);
                }
                received += n as u64;
                worked = true;
            }
        }
        if !worked && pa.is_idle() && pb.is_idle() {
            advance(&time, &[pa, pb]);
        }
    }
    Outcome {
        received,
        finished: finished && source_done,
        would_block: u64::from(a.stats().would_block + b.stats().would_block),
        bus_would_block: bus.stats().would_block,
        bus_frames: bus.stats().frames,
        transmitted: u64::from(a.stats().frames_transmitted + b.stats().frames_transmitted),
    }
}

#[test]
fn transfer_64k_through_a_memory_bus_verifies_every_byte() {
    let outcome = transfer::<8>(64 * 1024, 2048, 700);
    assert!(outcome.finished);
    assert_eq!(outcome.received, 64 * 1024);
    // 64 KiB in 7-byte frames, at least.
    assert!(outcome.bus_frames > 64 * 1024 / 7, "{} frames", outcome.bus_frames);
    assert_eq!(outcome.transmitted, outcome.bus_frames, "every accepted frame is on the bus once");
}

#[test]
fn transfer_with_shallow_fifos_is_pushed_back_and_loses_nothing() {
    // Receive FIFOs of 2 frames (a real controller's size) against a receive budget of 4 and
    // windows of 2048 bytes: the sender meets WouldBlock all the time.
    let outcome = transfer::<2>(20_000, 2048, 100);
    assert!(outcome.finished);
    assert_eq!(outcome.received, 20_000);
    assert!(outcome.would_block > 100, "only {} WouldBlock", outcome.would_block);
    assert_eq!(outcome.would_block, outcome.bus_would_block);
    assert_eq!(outcome.transmitted, outcome.bus_frames);
}

// ----- WouldBlock, displaced frames, errors -----

/// A peripheral with `mailboxes` transmit mailboxes, emptied only by `drain`; with `replace`,
/// when full it replaces a pending frame of strictly lower priority (the newest such), as the
/// trait allows.
#[derive(Default)]
struct Mailboxes {
    mailboxes: usize,
    replace: bool,
    pending: Vec<CanFrame>,
    wire: Vec<CanFrame>,
    inbox: VecDeque<Result<CanFrame, ErrorKind>>,
    fail_transmit: Option<ErrorKind>,
}

impl Mailboxes {
    fn new(mailboxes: usize) -> Self {
        Mailboxes { mailboxes, ..Default::default() }
    }

    /// Sends every pending frame, in the order they were placed (a FIFO-mode controller).
    fn drain(&mut self) {
        self.wire.append(&mut self.pending);
    }
}

impl Can for Mailboxes {
    type Frame = CanFrame;
    type Error = ErrorKind;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ErrorKind> {
        if let Some(error) = self.fail_transmit {
            return Err(nb::Error::Other(error));
        }
        if self.pending.len() < self.mailboxes {
            self.pending.push(*frame);
            return Ok(None);
        }
        // The lowest-priority pending frame, the newest of equals.
        let (index, lowest) = self.pending.iter().enumerate().max_by_key(|(i, f)| (f.id(), *i)).unwrap();
        if self.replace && lowest.id() > frame.id() {
            let displaced = self.pending.remove(index);
            self.pending.push(*frame);
            return Ok(Some(displaced));
        }
        Err(nb::Error::WouldBlock)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, ErrorKind> {
        match self.inbox.pop_front() {
            Some(Ok(frame)) => Ok(frame),
            Some(Err(error)) => Err(nb::Error::Other(error)),
            None => Err(nb::Error::WouldBlock),
        }
    }
}

/// The frames a link emits with no peripheral in the way: the reference order.
fn reference_frames(link: &mut CanLink) -> Vec<CanFrame> {
    std::iter::from_fn(|| link.poll_transmit()).collect()
}

fn fixed_clock(at: Instant) -> impl FnMut() -> Instant {
    move || at
}

#[test]
fn would_block_keeps_the_frame_and_sends_it_first_next_time() {
    let mut reference = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let expected = reference_frames(&mut reference);
    assert_eq!(expected.len(), 4);

    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut driver = Driver::new(Mailboxes::new(1), fixed_clock(Instant::ZERO), link);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());
    // One mailbox, emptied between polls: one frame a poll, the refused one held meanwhile.
    for round in 0..4 {
        let poll = driver.poll(&mut endpoint).unwrap();
        assert_eq!(poll.transmitted, 1, "round {round}");
        assert_eq!(poll.transmit_blocked, round < 3, "round {round}");
        assert_eq!(driver.is_transmit_blocked(), round < 3);
        driver.can_mut().drain();
    }
    assert_eq!(driver.can().wire, expected, "every frame once, in order");
    assert_eq!(driver.stats().would_block, 3);
    assert!(driver.poll(&mut endpoint).unwrap().is_idle());
}

#[test]
fn a_displaced_frame_is_kept_and_sent_again() {
    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut mailboxes = Mailboxes::new(1);
    mailboxes.replace = true;
    // A lower-priority frame of someone else's already waits in the only mailbox.
    let low = CanFrame::extended(0x1FFF_FFFF, &[1, 2, 3]).unwrap();
    mailboxes.pending.push(low);
    let mut driver = Driver::new(mailboxes, fixed_clock(Instant::ZERO), link);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());

    let poll = driver.poll(&mut endpoint).unwrap();
    // CID 7 displaced `low`, which the driver now holds (and cannot place: every CID has a
    // higher priority than it, and the mailbox is full).
    assert_eq!(driver.stats().displaced, 1);
    assert!(poll.transmit_blocked);
    let mut guard = 0;
    while driver.can().wire.len() < 5 {
        driver.can_mut().drain();
        driver.poll(&mut endpoint).unwrap();
        guard += 1;
        assert!(guard < 20, "frames stuck: {:?}", driver.can().wire);
    }
    driver.can_mut().drain();
    let wire = &driver.can().wire;
    assert_eq!(wire.len(), 5, "{wire:?}");
    assert_eq!(wire.iter().filter(|f| **f == low).count(), 1, "the displaced frame went out exactly once");
    let mut reference = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let cids: Vec<CanFrame> = wire.iter().copied().filter(|f| *f != low).collect();
    assert_eq!(cids, reference_frames(&mut reference));
}

#[test]
fn a_transmit_error_keeps_the_frame_and_is_returned() {
    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut mailboxes = Mailboxes::new(8);
    mailboxes.fail_transmit = Some(ErrorKind::Bit);
    let mut driver = Driver::new(mailboxes, fixed_clock(Instant::ZERO), link);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());
    assert_eq!(driver.poll(&mut endpoint), Err(Error::Transmit(ErrorKind::Bit)));
    assert_eq!(driver.stats().transmit_errors, 1);
    assert!(driver.is_transmit_blocked());
    driver.can_mut().fail_transmit = None;
    let poll = driver.poll(&mut endpoint).unwrap();
    assert_eq!(poll.transmitted, 4);
    driver.can_mut().drain();
    let mut reference = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    assert_eq!(driver.can().wire, reference_frames(&mut reference));
}

#[test]
fn a_receive_error_is_returned_and_the_next_poll_goes_on() {
    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut mailboxes = Mailboxes::new(8);
    let standard = <CanFrame as Frame>::new(embedded_can::StandardId::new(0x123).unwrap(), &[1]).unwrap();
    mailboxes.inbox.extend([Ok(standard), Err(ErrorKind::Overrun), Ok(standard)]);
    let mut driver = Driver::new(mailboxes, fixed_clock(Instant::ZERO), link);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());
    assert_eq!(driver.poll(&mut endpoint), Err(Error::Receive(ErrorKind::Overrun)));
    assert_eq!(driver.stats().receive_errors, 1);
    assert_eq!(driver.link().stats().standard_ignored, 1);
    // Transmission still happened in that poll.
    assert_eq!(driver.can().pending.len(), 4);
    let poll = driver.poll(&mut endpoint).unwrap();
    assert_eq!(poll.received, 1);
    assert_eq!(driver.link().stats().standard_ignored, 2);
}

#[test]
fn the_receive_budget_bounds_one_poll() {
    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut mailboxes = Mailboxes::new(8);
    let frame = CanFrame::extended(0x1FFF_F123, &[]).unwrap();
    mailboxes.inbox.extend(std::iter::repeat_n(Ok(frame), 5));
    let mut driver = Driver::new(mailboxes, fixed_clock(Instant::ZERO), link).with_receive_budget(3);
    let mut endpoint = StreamEndpoint::new(node(A), Config::default());
    let first = driver.poll(&mut endpoint).unwrap();
    assert_eq!((first.received, first.receive_pending), (3, true));
    let second = driver.poll(&mut endpoint).unwrap();
    assert_eq!((second.received, second.receive_pending), (2, false));
}

// ----- a foreign frame type -----

/// A HAL's own frame type, with room for CAN FD's 64 bytes.
#[derive(Clone, Debug, PartialEq)]
struct HalFrame {
    id: Id,
    remote: bool,
    data: Vec<u8>,
}

impl Frame for HalFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        (data.len() <= 64).then(|| HalFrame { id: id.into(), remote: false, data: data.to_vec() })
    }
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        (dlc <= 8).then(|| HalFrame { id: id.into(), remote: true, data: vec![0; dlc] })
    }
    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }
    fn is_remote_frame(&self) -> bool {
        self.remote
    }
    fn id(&self) -> Id {
        self.id
    }
    fn dlc(&self) -> usize {
        self.data.len()
    }
    fn data(&self) -> &[u8] {
        if self.remote { &[] } else { &self.data }
    }
}

/// Counts what the endpoint is handed.
struct Recorder {
    messages: usize,
}

impl PeerChanges for Recorder {
    fn peer_changed(&mut self, _change: PeerChange) {}
}

impl Receiver for Recorder {
    fn handle_message(&mut self, _now: Instant, _message: openlcb_stream::MessageRef<'_>) {
        self.messages += 1;
    }

    fn medium_busy(&mut self, _now: Instant) {}
}

impl Upper for Recorder {
    fn link_lost(&mut self) {}
    fn duplicate_node_id_report(&self) -> Option<openlcb_stream::Message> {
        None
    }
    fn handle_timeout(&mut self, _now: Instant) {}
    fn poll_transmit(&mut self) -> Option<openlcb_stream::Message> {
        None
    }
    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
}

#[test]
fn foreign_frames_are_converted_both_ways_and_oversized_ones_counted() {
    let bus: MemoryBus<HalFrame, 2, 16> = MemoryBus::new();
    let mut other = bus.port(1).unwrap();
    let link = CanLink::new(Instant::ZERO, node(A), CanConfig::default());
    let mut driver = Driver::new(bus.port(0).unwrap(), fixed_clock(Instant::ZERO), link);
    assert!(bus.port(0).is_none(), "a port is handed out once");
    let mut upper = Recorder { messages: 0 };

    // Verify Node ID global (0x19490), from alias 0x123: one frame that reaches the upper
    // layer once the sender's alias is known from its AMD.
    let id = |raw: u32| Id::Extended(ExtendedId::new(raw).unwrap());
    other.transmit(&HalFrame::new(id(0x1070_1123), &B.to_be_bytes()[2..]).unwrap()).unwrap();
    other.transmit(&HalFrame::new(id(0x1949_0123), &[]).unwrap()).unwrap();
    other.transmit(&HalFrame::new(id(0x1949_0123), &[0; 12]).unwrap()).unwrap();
    other.transmit(&HalFrame::new_remote(id(0x1949_0123), 2).unwrap()).unwrap();
    driver.poll(&mut upper).unwrap();
    assert_eq!(driver.stats().frames_received, 4);
    assert_eq!(driver.stats().unconvertible, 1, "12 data bytes have no classic CAN form");
    assert_eq!(driver.link().stats().remote_ignored, 1);
    assert_eq!(upper.messages, 1);
    // The CID frames went out as HalFrames.
    let cid = other.receive().unwrap();
    assert!(cid.is_extended() && cid.data.is_empty());
    assert_eq!(cid.id, id(openlcb_embedded::convert::<HalFrame, CanFrame>(&cid).unwrap().raw_id()));
}

// ----- link events inside a burst -----

/// Frame types (bits 12..27 of the identifier) of the frames that name a sender: AMD,
/// Initialization Complete, Verified Node ID.
fn names_its_sender(frame: &CanFrame) -> bool {
    matches!(frame.raw_id() >> 12, 0x10701 | 0x19100 | 0x19101 | 0x19170 | 0x19171)
}

#[test]
fn a_rename_in_a_burst_reaches_the_endpoint_before_the_data_behind_it() {
    // B runs on the driver; A is a bare link whose frames naming it are held back, so that B
    // serves A under its provisional name until a Verified Node ID arrives.
    let time = Cell::new(Instant::ZERO);
    let b_link = CanLink::new(time.get(), node(B), CanConfig::default());
    let mut driver = Driver::new(Mailboxes::new(usize::MAX), || time.get(), b_link);
    let mut destination = StreamEndpoint::new(node(B), Config::default());
    let mut a_link = CanLink::new(time.get(), node(A), CanConfig::default());
    let mut source = StreamEndpoint::new(node(A), Config::default());
    let exchange = |driver: &mut Driver<Mailboxes, _>,
                    destination: &mut StreamEndpoint,
                    a_link: &mut CanLink,
                    source: &mut StreamEndpoint| {
        let now = time.get();
        driver.poll(destination).unwrap();
        driver.can_mut().drain();
        for frame in std::mem::take(&mut driver.can_mut().wire) {
            a_link.handle_frame(now, &frame, source);
        }
        while a_link.poll_event().is_some() {}
        a_link.handle_timeout(now, source);
        source.handle_timeout(now);
        while let Some(message) = source.poll_transmit() {
            a_link.send(now, message).unwrap();
        }
        std::iter::from_fn(|| a_link.poll_transmit()).filter(|frame| !names_its_sender(frame)).collect::<Vec<_>>()
    };
    for _ in 0..3 {
        time.set(time.get() + openlcb_stream::Duration::from_millis(150));
        for frame in exchange(&mut driver, &mut destination, &mut a_link, &mut source) {
            driver.can_mut().inbox.push_back(Ok(frame));
        }
    }
    let a_alias = a_link.alias().expect("A logged in");
    assert!(driver.link().alias().is_some(), "B logged in");

    let handle = source.open(time.get(), OpenOptions::new(node(B), 256)).unwrap();
    let mut opened = false;
    for _ in 0..4 {
        for frame in exchange(&mut driver, &mut destination, &mut a_link, &mut source) {
            driver.can_mut().inbox.push_back(Ok(frame));
        }
        while let Some(event) = source.poll_event() {
            opened |= matches!(event, Event::Opened { .. });
        }
    }
    assert!(opened, "the stream opened under A's provisional name");

    // One burst: A's Verified Node ID, then stream data.
    let data: Vec<u8> = (0..64).map(pattern).collect();
    assert_eq!(source.write(time.get(), handle, &data).unwrap(), data.len());
    let verified = CanFrame::extended(0x1917_0000 | u32::from(a_alias.as_raw()), &A.to_be_bytes()[2..]).unwrap();
    let data_frames = exchange(&mut driver, &mut destination, &mut a_link, &mut source);
    assert!(data_frames.len() > 1, "the data takes several frames");
    driver.can_mut().inbox.push_back(Ok(verified));
    driver.can_mut().inbox.extend(data_frames.into_iter().map(Ok));
    driver.poll(&mut destination).unwrap();

    let mut received = Vec::new();
    let mut buf = [0u8; 64];
    while let Some(event) = destination.poll_event() {
        if let Event::Readable { handle } = event {
            while let Ok(n @ 1..) = destination.read(time.get(), handle, &mut buf) {
                received.extend_from_slice(&buf[..n]);
            }
        }
    }
    assert_eq!(received, data, "the data arrived under A's new name, after the rename");
}

// ----- duplicate Node ID -----

/// A node on the driver, logged in as alias 0x343 (the generator's first for A) at 200 ms, its
/// login frames and announcements sent.
fn logged_in_node(time: &Cell<Instant>) -> (Driver<Mailboxes, impl FnMut() -> Instant + '_>, Node) {
    let link = CanLink::new(time.get(), node(A), CanConfig::default());
    let mut driver = Driver::new(Mailboxes::new(usize::MAX), || time.get(), link);
    let mut upper = Node::new(node(A), NodeConfig::default());
    driver.poll(&mut upper).unwrap();
    time.set(Instant::from_millis(200));
    driver.poll(&mut upper).unwrap();
    driver.poll(&mut upper).unwrap();
    assert_eq!(driver.link().alias().map(|a| a.as_raw()), Some(0x343));
    driver.can_mut().drain();
    driver.can_mut().wire.clear();
    (driver, upper)
}

/// The identifiers of what the driver sent since the last call.
fn sent_ids(driver: &mut Driver<Mailboxes, impl FnMut() -> Instant>) -> Vec<u32> {
    driver.can_mut().drain();
    std::mem::take(&mut driver.can_mut().wire).iter().map(CanFrame::raw_id).collect()
}

/// Duplicate Node ID Detected (01.01.00.00.00.00.02.01), a Producer/Consumer Event Report.
const DUPLICATE_REPORT: [u8; 8] = [1, 1, 0, 0, 0, 0, 2, 1];

#[test]
fn a_duplicate_node_id_after_the_newcomer_window_is_reported_and_the_node_stays() {
    let time = Cell::new(Instant::ZERO);
    let (mut driver, mut upper) = logged_in_node(&time);
    time.set(Instant::from_millis(2000));
    // Another alias announces A's Node ID.
    let amd = CanFrame::extended(0x1070_1777, &A.to_be_bytes()[2..]).unwrap();
    driver.can_mut().inbox.push_back(Ok(amd));
    driver.poll(&mut upper).unwrap();
    driver.can_mut().drain();
    let wire = std::mem::take(&mut driver.can_mut().wire);
    assert_eq!(wire.iter().map(CanFrame::raw_id).collect::<Vec<_>>(), [0x195B_4343]);
    assert_eq!(wire[0].payload(), DUPLICATE_REPORT);
    assert!(driver.link().can_send(), "the node that was there first stays");
}

#[test]
fn a_duplicate_node_id_in_the_newcomer_window_is_reported_then_the_node_leaves() {
    let time = Cell::new(Instant::ZERO);
    let (mut driver, mut upper) = logged_in_node(&time);
    // The node that was there first answers A's Verify Node ID at once.
    let verified = CanFrame::extended(0x1917_0777, &A.to_be_bytes()[2..]).unwrap();
    driver.can_mut().inbox.push_back(Ok(verified));
    driver.poll(&mut upper).unwrap();
    // The report, then AMR, then nothing.
    assert_eq!(sent_ids(&mut driver), [0x195B_4343, 0x1070_3343]);
    assert!(driver.link().has_left());
    time.set(Instant::from_millis(10_000));
    driver.poll(&mut upper).unwrap();
    assert_eq!(sent_ids(&mut driver), Vec::<u32>::new());
}
