//! State tests, named `<state>_<event>`, one per row of wire-spec tables 6.2 (source),
//! 6.3 (destination) and 6.4 (unexpected messages), plus error reports. Each drives one
//! endpoint with hand-made messages from a scripted peer and checks what it sends back.

use openlcb_stream::wire::{CompleteCount, DataComplete, Emit, ErrorCode, ReplyClass, ReplyCode};
use openlcb_stream::{
    AcceptOptions, AcceptPolicy, Config, Duration, Event, Instant, Message, MessageRef, Mti, NodeId, OpenOptions,
    PeerChange, StreamEndpoint, StreamHandle, StreamId, Termination, TimeoutKind,
};

const LOCAL: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x00]);
const PEER: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x01]);
const OTHER: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x22, 0x02]);

/// One endpoint under test and the messages it sent, as (MTI, destination, payload).
struct Bench {
    ep: StreamEndpoint,
    now: Instant,
}

fn sid(raw: u8) -> StreamId {
    StreamId::new(raw).unwrap()
}

fn config() -> Config {
    let mut c = Config::default();
    c.max_window = 16;
    c.early_proceed = false;
    c
}

impl Bench {
    fn new(config: Config) -> Self {
        Bench { ep: StreamEndpoint::new(LOCAL, config), now: Instant::ZERO }
    }

    fn from(&mut self, source: NodeId, mti: Mti, payload: &[u8]) {
        let destination = mti.is_addressed().then_some(LOCAL);
        self.ep.handle_message(self.now, MessageRef { mti, source, destination, payload });
    }

    fn peer(&mut self, mti: Mti, payload: &[u8]) {
        self.from(PEER, mti, payload);
    }

    fn sent(&mut self) -> Vec<(Mti, Vec<u8>)> {
        let mut out = Vec::new();
        while let Some(Message { mti, payload, destination, source }) = self.ep.poll_transmit() {
            assert_eq!(source, LOCAL);
            if mti.is_addressed() {
                assert!(destination.is_some());
            }
            out.push((mti, payload.to_vec()));
        }
        out
    }

    fn events(&mut self) -> Vec<Event> {
        std::iter::from_fn(|| self.ep.poll_event()).collect()
    }

    fn advance(&mut self, by: Duration) {
        self.now += by;
        self.ep.handle_timeout(self.now);
    }

    /// A source stream to PEER, SID 4, accepted with `window` and DID 7.
    fn open_source(&mut self, window: u16) -> StreamHandle {
        let h = self.ep.open(self.now, OpenOptions::new(PEER, window).source_stream(sid(4))).unwrap();
        assert_eq!(self.sent(), [(Mti::STREAM_INITIATE_REQUEST, vec![0, window as u8, 0, 0, 4])]);
        self.peer(Mti::STREAM_INITIATE_REPLY, &[0, window as u8, 0x80, 0x00, 4, 7]);
        assert!(matches!(self.events()[..], [Event::Opened { .. }]));
        h
    }

    /// A destination stream from PEER with SID 4, window 16; returns its handle and DID.
    fn open_destination(&mut self) -> (StreamHandle, u8) {
        self.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
        let sent = self.sent();
        assert_eq!(sent.len(), 1);
        assert_eq!(&sent[0].1[..5], &[0, 16, 0x80, 0, 4]);
        let Event::Opened { handle, .. } = self.events()[0] else { panic!("not opened") };
        (handle, sent[0].1[5])
    }
}

fn data(did: u8, bytes: &[u8]) -> Vec<u8> {
    let mut p = vec![did];
    p.extend_from_slice(bytes);
    p
}

fn read_all(b: &mut Bench, h: StreamHandle) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let mut out = Vec::new();
    while let Ok(n @ 1..) = b.ep.read(b.now, h, &mut buf) {
        out.extend_from_slice(&buf[..n]);
    }
    out
}

// ===== 6.2 Source =====

#[test]
fn closed_open_sends_request() {
    let mut b = Bench::new(config());
    let uid = openlcb_stream::ContentUid::new([5, 1, 1, 1, 0x22, 0xFF]).unwrap();
    b.ep.open(b.now, OpenOptions::new(PEER, 16).source_stream(sid(4)).content_uid(uid)).unwrap();
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REQUEST, vec![0, 16, 0, 0, 4, 0xFF, 5, 1, 1, 1, 0x22, 0xFF])]);
    assert_eq!(b.ep.credit(b.ep.handles().next().unwrap()), Some(0), "no credit before the reply");
}

#[test]
fn closed_open_rotates_sids() {
    let mut b = Bench::new(config());
    let mut sids = Vec::new();
    for _ in 0..3 {
        let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
        sids.push(b.sent()[0].1[4]);
        b.ep.abort(b.now, h, ErrorCode::TEMPORARY).unwrap();
        b.sent();
    }
    assert_eq!(sids, [0, 1, 2], "a closed SID is not reused at once");
    assert_eq!(b.ep.open(b.now, OpenOptions::new(PEER, 0)), Err(openlcb_stream::StreamError::ZeroBufferSize));
}

#[test]
fn closed_open_refuses_a_proposed_did_still_in_use_to_that_node() {
    // Data Send names only the DID: a second stream to the same node with the DID of one
    // still sending would mix their data at the destination (found by fuzzing: the old
    // stream's data, queued behind the new request, arrived in the new stream).
    let mut b = Bench::new(config());
    let open = b.open_source(16);
    let reuse = OpenOptions::new(PEER, 16).proposed_destination(sid(7));
    assert_eq!(b.ep.open(b.now, reuse), Err(openlcb_stream::StreamError::DestinationIdInUse));
    assert!(b.sent().is_empty());
    assert!(b.ep.open(b.now, OpenOptions::new(OTHER, 16).proposed_destination(sid(7))).is_ok(), "another node");
    let pending = b.ep.open(b.now, OpenOptions::new(PEER, 16).proposed_destination(sid(9))).unwrap();
    let again = OpenOptions::new(PEER, 16).proposed_destination(sid(9));
    assert_eq!(b.ep.open(b.now, again), Err(openlcb_stream::StreamError::DestinationIdInUse), "while requested too");
    b.events();
    b.ep.abort(b.now, open, ErrorCode::TEMPORARY).unwrap();
    assert!(b.ep.stream_info(pending).is_none(), "the TDE ended its sibling too");
    assert!(b.ep.open(b.now, OpenOptions::new(PEER, 16).proposed_destination(sid(7))).is_ok(), "free again");
}

#[test]
fn initiated_reply_with_the_did_of_another_open_stream_is_stale() {
    // A Reply naming the DID of another open stream to that node answers an earlier request
    // with this SID (found by fuzzing: a request given up on, its SID used again): taking it
    // would send this stream's data into the other one. The real Reply comes after.
    let mut b = Bench::new(config());
    let open = b.open_source(16);
    let waiting = b.ep.open(b.now, OpenOptions::new(PEER, 16).source_stream(sid(5))).unwrap();
    b.sent();
    let strays = b.ep.stats().stray_replies;
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0x00, 5, 7]);
    assert!(b.events().is_empty(), "not opened by the stale Reply");
    assert_eq!(b.ep.stats().stray_replies, strays + 1);
    assert_eq!(b.ep.credit(waiting), Some(0));
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0x00, 5, 8]);
    assert!(matches!(b.events()[..], [Event::Opened { handle, .. }] if handle == waiting));
    assert_eq!(b.ep.stream_info(waiting).and_then(|i| i.destination_stream), Some(sid(8)));
    assert_eq!(b.ep.stream_info(open).and_then(|i| i.destination_stream), Some(sid(7)));
}

#[test]
fn closed_request_after_a_proposed_did_gets_the_next_did_in_the_rotation() {
    // Found by fuzzing: a stream with a proposed DID ended here (no data in time, TDE on its
    // way), and the next request from that source got the same DID from the rotation; the
    // source's data, sent before the TDE reached it, landed in the new stream.
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4, 0]);
    assert_eq!(b.sent()[0].1, [0, 16, 0x80, 0, 4, 0], "the proposed DID 0");
    b.advance(Duration::from_secs(16));
    b.events();
    b.sent();
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 5]);
    assert_eq!(b.sent()[0].1, [0, 16, 0x80, 0, 5, 1], "DID 0 is not given out again at once");
}

#[test]
fn a_tde_sent_for_one_stream_ends_its_siblings_with_that_node() {
    // A TDE names no stream, so the peer ends every stream it has with this node in the
    // matching role (wire-spec Q5); this node ends the same ones.
    let mut b = Bench::new(config());
    let first = b.open_source(16);
    let second = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    let elsewhere = b.ep.open(b.now, OpenOptions::new(OTHER, 16)).unwrap();
    b.sent();
    let (incoming, _) = b.open_destination();
    b.ep.abort(b.now, first, ErrorCode::TEMPORARY).unwrap();
    let tde = (Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x00, 0x08, 0x88]);
    assert_eq!(b.sent(), [tde.clone(), tde], "a TDE for each");
    assert_eq!(
        b.events(),
        [Event::Terminated { handle: second, cause: Termination::SiblingTerminated }],
        "the other source stream to that node"
    );
    assert!(b.ep.stream_info(elsewhere).is_some(), "a stream to another node stays");
    assert!(b.ep.stream_info(incoming).is_some(), "a stream in the other role stays");
    // The same when a timeout sends the TDE: the first-data wait of the older destination
    // stream runs out (15 s) and the younger one from the same source ends with it.
    b.advance(Duration::from_secs(10));
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 5]);
    b.sent();
    let Event::Opened { handle: younger, .. } = b.events()[0] else { panic!("not opened") };
    b.advance(Duration::from_secs(6));
    let tde = (Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x1F, 0x88]);
    assert_eq!(b.sent(), [tde.clone(), tde]);
    assert_eq!(
        b.events(),
        [
            Event::TimedOut { handle: incoming, kind: TimeoutKind::FirstData },
            Event::Terminated { handle: younger, cause: Termination::SiblingTerminated },
        ]
    );
}

#[test]
fn initiated_reply_accepted() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    assert_eq!(b.ep.credit(h), Some(16));
    assert_eq!(b.ep.stream_info(h).unwrap().destination_stream, Some(sid(7)));
}

#[test]
fn initiated_reply_accepted_with_code_zero() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 64)).unwrap();
    b.sent();
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 32, 0x00, 0x00, 0, 9]);
    assert!(matches!(b.events()[..], [Event::Opened { info, .. }] if info.window == 32));
    assert_eq!(b.ep.credit(h), Some(32), "window lowered by the destination");
}

#[test]
fn initiated_reply_rejected_permanent() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.sent();
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 0, 0x10, 0x40, 0, 0]);
    assert_eq!(
        b.events(),
        [Event::Rejected { handle: h, code: ReplyCode::UNIMPLEMENTED, class: ReplyClass::Permanent }]
    );
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn initiated_reply_rejected_temporary() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.sent();
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 0, 0x20, 0x20, 0, 0xFF]);
    assert_eq!(b.events(), [Event::Rejected { handle: h, code: ReplyCode(0x2020), class: ReplyClass::Temporary }]);
}

#[test]
fn initiated_oir_for_request() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.sent();
    b.peer(Mti::OPTIONAL_INTERACTION_REJECTED, &[0x10, 0x43, 0x0C, 0xC8]);
    assert_eq!(b.events(), [Event::Rejected { handle: h, code: ReplyCode(0x1043), class: ReplyClass::Permanent }]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn initiated_no_answer() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.sent();
    assert_eq!(b.ep.poll_timeout(), Some(Instant::ZERO + Duration::from_secs(20)));
    b.advance(Duration::from_secs(19));
    assert!(b.events().is_empty());
    b.advance(Duration::from_secs(1));
    assert_eq!(b.events(), [Event::TimedOut { handle: h, kind: TimeoutKind::Reply }]);
    assert_eq!(b.ep.poll_timeout(), None);
}

#[test]
fn initiated_write_is_refused() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    assert_eq!(b.ep.write(b.now, h, b"x"), Err(openlcb_stream::StreamError::NotOpen));
    assert_eq!(b.ep.finish(b.now, h), Err(openlcb_stream::StreamError::NotOpen));
}

#[test]
fn open_write_within_credit_never_crosses_a_window() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    assert_eq!(b.ep.write(b.now, h, &[1; 10]).unwrap(), 10);
    assert_eq!(b.ep.write(b.now, h, &[2; 10]).unwrap(), 6, "only the credit is taken");
    let sent = b.sent();
    assert_eq!(sent, [(Mti::STREAM_DATA_SEND, data(7, &[1; 10])), (Mti::STREAM_DATA_SEND, data(7, &[2; 6]))]);
    assert_eq!(b.ep.credit(h), Some(0));
    // Two Proceeds at once (one early): 32 credit, but messages split at the window boundary.
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 7]);
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 7, 0, 0]);
    assert_eq!(b.events(), [Event::Writable { handle: h }]);
    assert_eq!(b.ep.write(b.now, h, &[3; 40]).unwrap(), 32);
    let lens: Vec<usize> = b.sent().iter().map(|(_, p)| p.len() - 1).collect();
    assert_eq!(lens, [16, 16]);
}

#[test]
fn open_credit_exhausted_proceed_times_out() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[0; 16]).unwrap();
    b.sent();
    b.advance(Duration::from_secs(30));
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x08, 0x88])]);
    assert_eq!(b.events(), [Event::TimedOut { handle: h, kind: TimeoutKind::Proceed }]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_write_without_credit_keeps_the_proceed_deadline() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[0; 16]).unwrap();
    b.sent();
    // A driver calls `write` on every wake-up; each finds no credit.
    for _ in 0..5 {
        b.advance(Duration::from_secs(5));
        assert_eq!(b.ep.write(b.now, h, &[0; 16]).unwrap(), 0);
    }
    b.advance(Duration::from_secs(5));
    let tde = (Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x08, 0x88]);
    assert_eq!(b.sent().last(), Some(&tde));
    assert_eq!(
        b.events(),
        [Event::TimedOut { handle: h, kind: TimeoutKind::Proceed }],
        "30 s from when credit ran out"
    );
}

#[test]
fn open_proceed_restores_credit() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[0; 16]).unwrap();
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 7]);
    assert_eq!(b.ep.credit(h), Some(16));
    b.advance(Duration::from_secs(30));
    assert!(b.events().iter().all(|e| !matches!(e, Event::TimedOut { .. })), "the Proceed stopped the timer");
}

#[test]
fn open_idle_sends_keepalive() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[0; 4]).unwrap();
    b.sent();
    b.advance(Duration::from_secs(15));
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_SEND, vec![7])]);
    assert_eq!(b.ep.credit(h), Some(12), "a keep-alive uses no credit");
}

#[test]
fn open_flush_sends_did_only() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.flush(b.now, h).unwrap();
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_SEND, vec![7])]);
}

#[test]
fn open_finish_sends_complete_with_count() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[9; 5]).unwrap();
    b.ep.finish(b.now, h).unwrap();
    let sent = b.sent();
    assert_eq!(sent.last().unwrap(), &(Mti::STREAM_DATA_COMPLETE, vec![4, 7, 0, 0, 0, 5]));
    assert_eq!(b.events(), [Event::Sent { handle: h, total: 5 }], "the source is told it is done");
    assert_eq!(b.ep.stream_count(), 0);
    assert_eq!(b.ep.write(b.now, h, b"x"), Err(openlcb_stream::StreamError::UnknownStream));
}

#[test]
fn open_abort_sends_tde_naming_proceed() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.abort(b.now, h, ErrorCode(0x2000)).unwrap();
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x00, 0x08, 0x88])]);
    assert!(b.events().is_empty());
}

#[test]
fn open_tde_from_destination() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x40, 0x1F, 0x88]);
    assert_eq!(b.events(), [Event::Terminated { handle: h, cause: Termination::ByPeer(ErrorCode(0x2040)) }]);
    assert_eq!(b.ep.stream_count(), 0);
}

// ===== 6.3 Destination =====

#[test]
fn closed_request_malformed_zero_buffer() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 0, 0, 0, 4]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 0, 0x10, 0x80, 4, 0])]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn closed_request_malformed_short() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0]);
    assert_eq!(b.sent(), [(Mti::OPTIONAL_INTERACTION_REJECTED, vec![0x10, 0x80, 0x0C, 0xC8])]);
    assert_eq!(b.ep.stats().malformed, 1);
}

#[test]
fn closed_request_acceptable() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0x01, 0x00, 0, 0, 4]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 16, 0x80, 0, 4, 0])], "window = min(256, 16)");
    // A second stream from the same source gets another DID.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 8, 0, 0, 5]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 8, 0x80, 0, 5, 1])]);
    let opened: Vec<_> = b.events().into_iter().filter(|e| matches!(e, Event::Opened { .. })).collect();
    assert_eq!(opened.len(), 2);
}

#[test]
fn closed_request_with_proposed_did() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0xFF, 0xFF, 0, 0, 2, 0x37]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 16, 0x80, 0, 2, 0x37])]);
    // The same DID proposed again while in use: busy.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0xFF, 0xFF, 0, 0, 3, 0x37]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 0, 0x20, 0x20, 3, 0])]);
}

#[test]
fn closed_request_refused_by_policy() {
    let mut c = config();
    c.accept_policy = AcceptPolicy::RejectAll(ReplyCode::SOURCE_NOT_PERMITTED);
    let mut b = Bench::new(c);
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 0, 0x10, 0x20, 4, 0])]);
}

#[test]
fn closed_request_decided_by_application() {
    let mut c = config();
    c.accept_policy = AcceptPolicy::Ask;
    let mut b = Bench::new(c);
    let uid = [5, 1, 1, 1, 0x22, 0xFF];
    let mut request = vec![0, 64, 0, 0, 4, 0xFF];
    request.extend_from_slice(&uid);
    b.peer(Mti::STREAM_INITIATE_REQUEST, &request);
    assert!(b.sent().is_empty(), "nothing until the application decides");
    let [Event::IncomingRequest { handle, info }] = b.events()[..] else { panic!() };
    assert_eq!((info.window, info.content_uid.map(|u| u.to_bytes())), (64, Some(uid)));
    b.ep.accept(b.now, handle, Some(8)).unwrap();
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 8, 0x80, 0, 4, 0])]);
    // And a second one refused for its content UID (draft §7.2).
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 64, 0, 0, 5]);
    let handle = b
        .events()
        .into_iter()
        .find_map(|e| match e {
            Event::IncomingRequest { handle, .. } => Some(handle),
            _ => None,
        })
        .unwrap();
    b.ep.reject(b.now, handle, ReplyCode::UNIMPLEMENTED).unwrap();
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 0, 0x10, 0x40, 5, 0])]);
}

#[test]
fn closed_request_undecided_times_out() {
    let mut c = config();
    c.accept_policy = AcceptPolicy::Ask;
    let mut b = Bench::new(c);
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    let [Event::IncomingRequest { handle, .. }] = b.events()[..] else { panic!() };
    b.advance(Duration::from_millis(500));
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 0, 0x20, 0x20, 4, 0])]);
    assert_eq!(b.events(), [Event::TimedOut { handle, kind: TimeoutKind::Decision }]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn closed_request_table_full() {
    let mut c = config();
    c.max_streams = 2;
    let mut b = Bench::new(c);
    for s in 0..3 {
        b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, s]);
    }
    let codes: Vec<u8> = b.sent().iter().map(|(_, p)| p[2]).collect();
    assert_eq!(codes, [0x80, 0x80, 0x20], "third gets 0x2020");
    assert_eq!(b.ep.stream_count(), 2);
}

#[test]
fn open_data_then_proceed_after_a_full_window() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 10]));
    assert_eq!(b.events(), [Event::Readable { handle: h }]);
    assert_eq!(read_all(&mut b, h), [1; 10]);
    assert!(b.sent().is_empty(), "no Proceed before the window is in");
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[2; 6]));
    assert!(b.sent().is_empty(), "the window is in, but 6 unread bytes leave no room for another");
    assert_eq!(read_all(&mut b, h), [2; 6]);
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])]);
}

#[test]
fn open_data_with_early_proceed() {
    let mut c = config();
    c.early_proceed = true;
    let mut b = Bench::new(c);
    let (h, did) = b.open_destination();
    assert_eq!(b.ep.buffer_capacity(h), Some(32));
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 3]));
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])], "one Proceed ahead");
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 13]));
    assert!(b.sent().is_empty(), "never two ahead");
    read_all(&mut b, h);
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 1]));
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])]);
}

#[test]
fn open_slow_reader_holds_the_proceed() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 16]));
    assert!(b.sent().is_empty(), "the buffer is full: no room for another window");
    let mut buf = [0u8; 8];
    assert_eq!(b.ep.read(b.now, h, &mut buf), Ok(8));
    assert!(b.sent().is_empty(), "half a window of room is not enough");
    assert_eq!(b.ep.read(b.now, h, &mut buf), Ok(8));
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])]);
}

#[test]
fn open_flush_uses_no_window() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &[did]);
    assert!(b.events().is_empty() && b.sent().is_empty());
    assert_eq!(b.ep.buffered(h), Some(0));
}

#[test]
fn open_complete_with_matching_count() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"hello"));
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 5]);
    let events = b.events();
    assert_eq!(events.last(), Some(&Event::Finished { handle: h, total: 5, stated: Some(5), matched: true }));
    assert_eq!(read_all(&mut b, h), b"hello");
    assert_eq!(b.ep.stream_count(), 0, "released once read empty");
}

#[test]
fn open_complete_without_count() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did]);
    assert_eq!(b.events(), [Event::Finished { handle: h, total: 0, stated: None, matched: true }]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_complete_before_data_in_flight() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 7]));
    // On CAN the Complete out-arbitrates the last data frame.
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 10]);
    assert_eq!(b.events(), [Event::Readable { handle: h }], "waits for 3 more bytes");
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[2; 3]));
    assert_eq!(b.events(), [Event::Finished { handle: h, total: 10, stated: Some(10), matched: true }]);
}

#[test]
fn open_complete_count_mismatch() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 7]));
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 5]);
    assert_eq!(b.events().last(), Some(&Event::Finished { handle: h, total: 7, stated: Some(5), matched: false }));
    read_all(&mut b, h);
    // A count beyond any credit granted cannot still be in flight.
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 1, 0]);
    assert_eq!(b.events(), [Event::Finished { handle: h, total: 0, stated: Some(256), matched: false }]);
}

#[test]
fn open_complete_form_d_count() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 4]));
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 0, 4]);
    assert_eq!(b.events().last(), Some(&Event::Finished { handle: h, total: 4, stated: Some(4), matched: true }));
}

#[test]
fn open_last_full_window_still_gets_its_proceed() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 16]));
    read_all(&mut b, h);
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])], "OpenMRN's sender waits for it");
}

#[test]
fn open_abort_sends_tde_naming_data_send() {
    let mut b = Bench::new(config());
    let (h, _) = b.open_destination();
    b.ep.abort(b.now, h, ErrorCode(0x2040)).unwrap();
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x40, 0x1F, 0x88])]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_tde_from_source_keeps_received_data() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"abc"));
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x00, 0x08, 0x88]);
    assert_eq!(
        b.events().last(),
        Some(&Event::Terminated { handle: h, cause: Termination::ByPeer(ErrorCode(0x2000)) })
    );
    assert_eq!(read_all(&mut b, h), b"abc", "what arrived stays readable");
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_source_silent_times_out() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"a"));
    assert_eq!(read_all(&mut b, h), b"a");
    b.events();
    b.advance(Duration::from_secs(59));
    b.peer(Mti::STREAM_DATA_SEND, &[did]); // a keep-alive restarts the wait
    b.advance(Duration::from_secs(59));
    assert!(b.events().is_empty());
    b.advance(Duration::from_secs(1));
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x1F, 0x88])]);
    assert_eq!(b.events(), [Event::TimedOut { handle: h, kind: TimeoutKind::Idle }]);
}

#[test]
fn open_no_first_data_times_out_early() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.advance(Duration::from_secs(14));
    b.peer(Mti::STREAM_DATA_SEND, &[did]); // a keep-alive is not data
    assert!(b.events().is_empty());
    b.advance(Duration::from_secs(1));
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x1F, 0x88])]);
    assert_eq!(b.events(), [Event::TimedOut { handle: h, kind: TimeoutKind::FirstData }]);
    assert_eq!(b.ep.stream_count(), 0, "the slot is free again");
}

#[test]
fn draining_count_not_made_up_is_a_mismatch_after_the_grace() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 7]));
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 10]);
    assert_eq!(b.events(), [Event::Readable { handle: h }], "3 bytes may still be in flight");
    b.advance(Duration::from_secs(2));
    assert_eq!(b.events(), [Event::Finished { handle: h, total: 7, stated: Some(10), matched: false }]);
    assert!(b.sent().is_empty(), "the source has already finished: nothing to terminate");
    assert_eq!(read_all(&mut b, h), [1; 7], "what arrived stays readable");
}

#[test]
fn open_slow_reader_is_not_idle() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[0; 16]));
    b.advance(Duration::from_secs(600));
    assert!(b.events().iter().all(|e| !matches!(e, Event::TimedOut { .. })), "the source is waiting for us");
    assert_eq!(b.ep.buffered(h), Some(16));
}

// ===== 6.4 Unexpected messages =====

#[test]
fn any_data_for_unknown_did() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_DATA_SEND, &[9, 1, 2, 3]);
    assert!(b.sent().is_empty() && b.events().is_empty());
    assert_eq!(b.ep.stats().unknown_stream_data, 1);
}

#[test]
fn any_reserved_stream_id() {
    let mut b = Bench::new(config());
    let (_, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &[0xFF, 1]);
    b.peer(Mti::STREAM_DATA_PROCEED, &[0xFF, did]);
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, 0xFF]);
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 0xFF]);
    assert!(b.sent().is_empty() && b.events().is_empty(), "0xFF is ignored on receipt");
    assert_eq!(b.ep.stats().malformed, 4);
}

#[test]
fn closed_proceed_for_unknown_stream() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 7]);
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16).source_stream(sid(4))).unwrap();
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 7]); // not open yet
    assert_eq!(b.ep.stats().stray_proceeds, 2);
    assert_eq!(b.ep.credit(h), Some(0));
}

#[test]
fn open_proceed_with_wrong_did() {
    let mut b = Bench::new(config());
    let h = b.open_source(16);
    b.ep.write(b.now, h, &[0; 16]).unwrap();
    b.peer(Mti::STREAM_DATA_PROCEED, &[4, 8]);
    assert_eq!(b.ep.credit(h), Some(0));
    assert_eq!(b.ep.stats().stray_proceeds, 1);
}

#[test]
fn closed_complete_for_unknown_or_duplicate() {
    let mut b = Bench::new(config());
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, 0]);
    let (_, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_COMPLETE, &[5, did]); // wrong SID
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 0]);
    b.events();
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 0]); // stale duplicate
    assert!(b.events().is_empty());
    assert_eq!(b.ep.stats().stray_completes, 3);
}

#[test]
fn initiated_reply_wrong_sid_or_node() {
    let mut b = Bench::new(config());
    let h = b.ep.open(b.now, OpenOptions::new(PEER, 16).source_stream(sid(4))).unwrap();
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0, 5, 7]);
    b.from(OTHER, Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0, 4, 7]);
    assert!(b.events().is_empty());
    assert_eq!(b.ep.credit(h), Some(0));
    assert_eq!(b.ep.stats().stray_replies, 2);
}

#[test]
fn open_window_overrun_terminates_even_with_room() {
    let mut c = config();
    c.early_proceed = true; // buffer of 32 for a window of 16
    let mut b = Bench::new(c);
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 16]));
    b.sent();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[2; 16])); // credit was 16 more: fine
    b.peer(Mti::STREAM_DATA_SEND, &[did]); // flush: fine
    assert_eq!(b.ep.stats().window_overruns, 0);
    assert_eq!(read_all(&mut b, h), [[1; 16], [2; 16]].concat());
    b.sent();
    // 4 more than the 16 granted, though the buffer has room: TDE, and none of it taken.
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[3; 20]));
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x40, 0x1F, 0x88])]);
    assert_eq!(b.events().last(), Some(&Event::Terminated { handle: h, cause: Termination::WindowOverrun }));
    assert_eq!(b.ep.stats().window_overruns, 1);
    assert_eq!(read_all(&mut b, h), Vec::<u8>::new());
}

#[test]
fn open_window_overrun_without_room_terminates() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[1; 10]));
    b.peer(Mti::STREAM_DATA_SEND, &data(did, &[2; 10]));
    assert_eq!(b.sent(), [(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x40, 0x1F, 0x88])]);
    assert_eq!(b.events().last(), Some(&Event::Terminated { handle: h, cause: Termination::WindowOverrun }));
    assert_eq!(read_all(&mut b, h), [1; 10], "the data that fitted is kept, nothing is half-taken");
}

#[test]
fn open_tde_with_several_streams_ends_that_role() {
    let mut b = Bench::new(config());
    let s1 = b.open_source(16);
    let s2 = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.sent();
    let (d1, _) = b.open_destination();
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x40, 0x1F, 0x88]);
    let ended: Vec<_> = b
        .events()
        .iter()
        .filter_map(|e| match e {
            Event::Terminated { handle, .. } => Some(*handle),
            _ => None,
        })
        .collect();
    assert_eq!(ended, [s1, s2], "TDE naming Data Send ends our source streams (wire-spec Q5)");
    assert!(b.ep.stream_info(d1).is_some(), "the destination stream is untouched");
    // A 2-byte TDE (no MTI) ends everything with that peer.
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x00]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_tde_naming_data_send_from_our_source_ends_that_stream_at_once() {
    // Real sources terminate their own stream naming Data Send (0x1F88), the MTI the draft
    // gives the destination: with no source stream to that peer, it is about our destination.
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"ab"));
    b.events();
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x20, 0x00, 0x1F, 0x88]);
    assert_eq!(b.events(), [Event::Terminated { handle: h, cause: Termination::ByPeer(ErrorCode(0x2000)) }]);
    assert_eq!(read_all(&mut b, h), b"ab");
    assert_eq!(b.ep.stream_count(), 0, "the slot is free at once");
    // The same peer's next request is accepted, not refused with 0x2020.
    let (_, _) = b.open_destination();
}

#[test]
fn open_tde_or_oir_naming_another_protocol_leaves_streams_open() {
    let mut b = Bench::new(config());
    let s = b.open_source(16);
    let (d, _) = b.open_destination();
    b.peer(Mti::TERMINATE_DUE_TO_ERROR, &[0x10, 0x00, 0x0D, 0xE8]); // names the SNIP request
    b.peer(Mti::OPTIONAL_INTERACTION_REJECTED, &[0x10, 0x43, 0x1C, 0x48]); // names Datagram
    assert!(b.events().is_empty());
    assert!(b.ep.stream_info(s).is_some() && b.ep.stream_info(d).is_some());
    assert_eq!(b.ep.stats().stray_error_reports, 2);
}

#[test]
fn awaiting_decision_accept_with_chooses_window_and_early_proceed_per_stream() {
    let mut c = config();
    c.accept_policy = AcceptPolicy::Ask;
    c.max_window = 16;
    let mut b = Bench::new(c);
    // First stream: early Proceed on, on an endpoint configured without it: the window is
    // halved so that two windows fit the per-stream buffer bound.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    let Event::IncomingRequest { handle, .. } = b.events()[0] else { panic!("no request") };
    b.ep.accept_with(b.now, handle, AcceptOptions::new(None, true)).unwrap();
    let reply = b.sent();
    assert_eq!(&reply[0].1[..5], &[0, 8, 0x80, 0, 4]);
    let did = reply[0].1[5];
    assert_eq!(b.ep.buffer_capacity(handle), Some(16));
    b.events();
    // With early Proceed, the first byte of the window already draws a Proceed.
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"a"));
    assert_eq!(b.sent(), [(Mti::STREAM_DATA_PROCEED, vec![4, did, 0, 0])]);
    b.events();
    // Second stream: a window of 4, no early Proceed.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 5]);
    let Event::IncomingRequest { handle: second, .. } = b.events()[0] else { panic!("no request") };
    b.ep.accept_with(b.now, second, AcceptOptions::new(Some(4), false)).unwrap();
    let reply = b.sent();
    assert_eq!(&reply[0].1[..5], &[0, 4, 0x80, 0, 5]);
    let did2 = reply[0].1[5];
    b.peer(Mti::STREAM_DATA_SEND, &data(did2, b"abc"));
    assert!(b.sent().is_empty(), "no Proceed before the window is full");
}

#[test]
fn open_request_reusing_a_live_sid_supersedes() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    // The same request again (a duplicated frame) is answered again, nothing else happens.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    assert_eq!(b.sent(), [(Mti::STREAM_INITIATE_REPLY, vec![0, 16, 0x80, 0, 4, did])]);
    assert!(b.events().is_empty());
    // After data, the same SID again means the source reset: the old stream is over.
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"x"));
    b.events();
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    let events = b.events();
    assert_eq!(events[0], Event::Terminated { handle: h, cause: Termination::Superseded });
    assert!(matches!(events[1], Event::Opened { .. }));
}

#[test]
fn closed_stream_with_unread_data_is_not_superseded_by_its_sid_again() {
    let mut b = Bench::new(config());
    let (h, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"xy"));
    b.peer(Mti::STREAM_DATA_COMPLETE, &[4, did, 0, 0, 0, 2]);
    let events = b.events();
    assert!(events.iter().any(|e| matches!(e, Event::Finished { handle, total: 2, .. } if *handle == h)));
    b.sent();
    // The source starts a new stream with the same SID: the finished one is not ended again.
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 4]);
    let events = b.events();
    assert_eq!(events.len(), 1, "{events:?}");
    let Event::Opened { handle: second, info } = events[0] else { panic!("not opened: {events:?}") };
    assert_ne!(second, h);
    assert_ne!(info.destination_stream, Some(sid(did)), "the closed stream keeps its DID");
    // The old data is still there to read.
    assert_eq!(read_all(&mut b, h), b"xy");
}

#[test]
fn any_peer_lost_ends_its_streams() {
    let mut b = Bench::new(config());
    let s = b.open_source(16);
    b.ep.peer_changed(PeerChange::Lost(OTHER));
    assert!(b.events().is_empty());
    b.ep.peer_changed(PeerChange::Lost(PEER));
    assert_eq!(b.events(), [Event::Terminated { handle: s, cause: Termination::PeerLost }]);
    assert!(b.sent().is_empty(), "nothing is sent to a node that is gone");
}

#[test]
fn any_initialization_complete_from_peer_ends_its_streams() {
    let mut b = Bench::new(config());
    let s = b.open_source(16);
    let (d, did) = b.open_destination();
    b.peer(Mti::STREAM_DATA_SEND, &data(did, b"ab"));
    b.events();
    b.peer(Mti::INITIALIZATION_COMPLETE, &PEER.to_bytes());
    assert_eq!(
        b.events(),
        [
            Event::Terminated { handle: s, cause: Termination::PeerRestarted },
            Event::Terminated { handle: d, cause: Termination::PeerRestarted }
        ]
    );
    assert_eq!(read_all(&mut b, d), b"ab");
    b.peer(Mti::INITIALIZATION_COMPLETE, &PEER.to_bytes());
    assert!(b.events().is_empty(), "a node with no streams with us changes nothing");
    // A request that crossed the peer's announcement on the wire is still answered.
    let pending = b.ep.open(b.now, OpenOptions::new(PEER, 16)).unwrap();
    b.peer(Mti::INITIALIZATION_COMPLETE, &PEER.to_bytes());
    assert!(b.events().is_empty());
    assert!(b.ep.stream_info(pending).is_some());
}

#[test]
fn any_message_for_another_node_is_ignored() {
    let mut b = Bench::new(config());
    b.ep.handle_message(
        b.now,
        MessageRef {
            mti: Mti::STREAM_INITIATE_REQUEST,
            source: PEER,
            destination: Some(OTHER),
            payload: &[0, 16, 0, 0, 4],
        },
    );
    assert!(b.sent().is_empty());
    assert_eq!(b.ep.stats().not_for_us, 1);
}

#[test]
fn complete_count_forms_encode_as_documented() {
    let c = DataComplete { source_stream: sid(1), destination_stream: sid(2), count: CompleteCount::Total(3) };
    assert_eq!(c.to_bytes().len(), 6);
}

#[test]
fn open_data_on_a_sibling_keeps_the_first_data_wait_going() {
    let mut b = Bench::new(config());
    let (busy, busy_did) = b.open_destination();
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 5]);
    let waiting_did = b.sent()[0].1[5];
    let Event::Opened { handle: waiting, .. } = b.events()[0] else { panic!("not opened") };
    b.advance(Duration::from_secs(10));
    // A window's worth: progress (a byte alone is not, see min_idle_progress).
    b.peer(Mti::STREAM_DATA_SEND, &data(busy_did, &[b'a'; 16]));
    assert_eq!(read_all(&mut b, busy), [b'a'; 16]);
    b.events();
    b.sent();
    b.advance(Duration::from_secs(5));
    assert!(b.events().is_empty(), "the peer is busy sending on its other stream");
    assert!(b.sent().is_empty());
    b.advance(Duration::from_secs(9));
    b.peer(Mti::STREAM_DATA_SEND, &data(waiting_did, b"b"));
    assert_eq!(read_all(&mut b, waiting), b"b");
    b.events();
    b.advance(Duration::from_secs(60));
    assert_eq!(b.events().len(), 2, "both idle once the peer falls silent");
}

#[test]
fn open_a_proceed_from_the_peer_on_any_stream_keeps_the_proceed_wait_going() {
    let mut b = Bench::new(config());
    let waiting = b.open_source(16);
    b.ep.write(b.now, waiting, &[0; 16]).unwrap();
    // A second stream to the same peer, SID 5, DID 8, that ends after its one window.
    let other = b.ep.open(b.now, OpenOptions::new(PEER, 16).source_stream(sid(5))).unwrap();
    b.peer(Mti::STREAM_INITIATE_REPLY, &[0, 16, 0x80, 0x00, 5, 8]);
    b.ep.write(b.now, other, &[1; 16]).unwrap();
    b.ep.finish(b.now, other).unwrap();
    b.sent();
    b.events();
    // 25 s on, the peer proceeds the stream that has ended here: it is taking this node's
    // data, so the stream still waiting its turn is not given up 30 s after its window.
    b.advance(Duration::from_secs(25));
    b.peer(Mti::STREAM_DATA_PROCEED, &[5, 8]);
    assert_eq!(b.ep.stats().stray_proceeds, 1);
    b.advance(Duration::from_secs(10));
    assert!(b.events().is_empty(), "the peer proceeded 10 s ago");
    assert!(!b.sent().iter().any(|(mti, _)| *mti == Mti::TERMINATE_DUE_TO_ERROR));
    // Once the peer falls silent the wait runs out, 30 s after its last Proceed.
    b.advance(Duration::from_secs(19));
    assert!(b.events().is_empty());
    b.advance(Duration::from_secs(1));
    assert_eq!(b.events(), [Event::TimedOut { handle: waiting, kind: TimeoutKind::Proceed }]);
    assert_eq!(b.sent().last(), Some(&(Mti::TERMINATE_DUE_TO_ERROR, vec![0x20, 0x10, 0x08, 0x88])));
}

#[test]
fn every_wait_for_the_peer_runs_from_the_last_stream_data_on_a_busy_medium() {
    let mut b = Bench::new(config());
    let sending = b.open_source(16);
    b.ep.write(b.now, sending, &[0; 16]).unwrap();
    b.sent();
    let (receiving, _) = b.open_destination();
    let requested = b.ep.open(b.now, OpenOptions::new(OTHER, 16).source_stream(sid(9))).unwrap();
    b.sent();
    b.events();
    // Others' streams keep the bus busy for ten minutes, a frame every second: the peers'
    // frames lose arbitration, so no wait for them (Reply, Proceed, first data) runs out.
    for _ in 0..600 {
        b.advance(Duration::from_secs(1));
        b.ep.medium_busy(b.now);
    }
    assert!(b.events().is_empty(), "a peer waiting for its turn on the bus is not silent");
    assert!(!b.sent().iter().any(|(mti, _)| *mti == Mti::TERMINATE_DUE_TO_ERROR));
    // The bus falls quiet: each wait runs out as configured, from the last frame.
    b.advance(Duration::from_secs(15));
    assert_eq!(b.events(), [Event::TimedOut { handle: receiving, kind: TimeoutKind::FirstData }]);
    b.advance(Duration::from_secs(5));
    assert_eq!(b.events(), [Event::TimedOut { handle: requested, kind: TimeoutKind::Reply }]);
    b.advance(Duration::from_secs(10));
    assert_eq!(b.events(), [Event::TimedOut { handle: sending, kind: TimeoutKind::Proceed }]);
    assert_eq!(b.ep.stream_count(), 0);
}

#[test]
fn open_a_trickle_keeps_a_slot_only_until_someone_else_wants_it() {
    let mut c = config();
    c.max_streams = 2;
    c.max_window = 2048;
    let mut b = Bench::new(c);
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0x08, 0, 0, 0, 4]);
    let did1 = b.sent()[0].1[5];
    b.peer(Mti::STREAM_INITIATE_REQUEST, &[0x08, 0, 0, 0, 5]);
    let did2 = b.sent()[0].1[5];
    let Event::Opened { handle: first, .. } = b.events()[0] else { panic!("not opened") };
    let trickle = |b: &mut Bench| {
        for did in [did1, did2] {
            b.peer(Mti::STREAM_DATA_SEND, &data(did, b"x"));
            // On CAN the link also reports the trickle's frames as stream data on the bus.
            b.ep.medium_busy(b.now);
        }
        for h in b.ep.handles().collect::<Vec<_>>() {
            read_all(b, h);
        }
        b.events();
        b.sent();
    };
    // A byte every 10 s on each stream keeps both open while nobody else asks.
    for _ in 0..12 {
        b.advance(Duration::from_secs(10));
        trickle(&mut b);
    }
    assert_eq!(b.ep.stream_count(), 2);
    // Another node is turned away: from now on the trickle is not progress.
    b.from(OTHER, Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 9]);
    assert_eq!(b.sent()[0].1[2..4], [0x20, 0x20], "refused: every slot is taken");
    for _ in 0..6 {
        b.advance(Duration::from_secs(10));
        trickle(&mut b);
    }
    assert_eq!(b.ep.stream_count(), 0, "both trickling streams gave up their slots within the idle wait");
    assert!(b.ep.stream_info(first).is_none());
    b.from(OTHER, Mti::STREAM_INITIATE_REQUEST, &[0, 16, 0, 0, 9]);
    assert_eq!(b.sent()[0].1[2], 0x80, "the next request is accepted");
}
