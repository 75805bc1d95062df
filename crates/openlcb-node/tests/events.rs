//! Event Transport: the answers to Identify Producer, Identify Consumer and Identify Events,
//! the announcements after Initialization Complete, reports and Learn Event in and out, the
//! PIP bit, and a flood of Identify Events.

use openlcb_node::{
    DeclaredEvents, EventConfig, EventError, EventNotice, EventRange, EventRole, EventState, Listen, Node, NodeConfig,
    NodeEvent, Protocols,
};
use openlcb_stream::{EventId, Instant, Message, MessageRef, Mti, NodeId};

const LOCAL: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x40, 0x02]);
const PEER: NodeId = NodeId::from_bytes([0x05, 0x01, 0x01, 0x01, 0x40, 0x01]);

const BUTTON: EventId = EventId(0x0501_0101_4002_0001);
const LAMP: EventId = EventId(0x0501_0101_4002_0101);

/// Produces BUTTON (valid) and a block of 256 from 0x..0200; consumes LAMP (unknown) and a
/// block of 2 from 0x..0010.
fn events() -> EventConfig {
    let mut events = EventConfig::default();
    events.produced = vec![
        DeclaredEvents::single(BUTTON, EventState::Valid),
        DeclaredEvents {
            range: EventRange::covering(EventId(0x0501_0101_4002_0200), 256).unwrap(),
            state: EventState::Invalid,
        },
    ];
    events.consumed = vec![
        DeclaredEvents::single(LAMP, EventState::Unknown),
        DeclaredEvents {
            range: EventRange::covering(EventId(0x0501_0101_4002_0010), 2).unwrap(),
            state: EventState::Unknown,
        },
    ];
    events
}

fn node_with(events: EventConfig, announce: bool) -> Node {
    let mut config = NodeConfig::default();
    config.events = events;
    config.send_initialization_complete = announce;
    Node::new(LOCAL, config)
}

fn feed(node: &mut Node, source: NodeId, mti: Mti, payload: &[u8]) {
    let destination = mti.is_addressed().then_some(LOCAL);
    node.handle_message(Instant::ZERO, MessageRef { mti, source, destination, payload });
}

fn sent(node: &mut Node) -> Vec<(Mti, Vec<u8>)> {
    std::iter::from_fn(|| node.poll_transmit())
        .map(|m| {
            assert_eq!(m.destination, None, "event answers are global");
            (m.mti, m.payload)
        })
        .collect()
}

fn notices(node: &mut Node) -> Vec<EventNotice> {
    std::iter::from_fn(|| node.poll_event())
        .filter_map(|e| match e {
            NodeEvent::Events(notice) => Some(notice),
            _ => None,
        })
        .collect()
}

/// Every declaration, in the order announced.
fn everything() -> Vec<(Mti, Vec<u8>)> {
    vec![
        (Mti::PRODUCER_IDENTIFIED_VALID, BUTTON.to_bytes().to_vec()),
        // 256 from 0x..0200: bit 8 is 0, so the low 8 bits are sent as ones.
        (Mti::PRODUCER_RANGE_IDENTIFIED, EventId(0x0501_0101_4002_02FF).to_bytes().to_vec()),
        (Mti::CONSUMER_IDENTIFIED_UNKNOWN, LAMP.to_bytes().to_vec()),
        (Mti::CONSUMER_RANGE_IDENTIFIED, EventId(0x0501_0101_4002_0011).to_bytes().to_vec()),
    ]
}

#[test]
fn initialization_complete_is_followed_by_every_declaration() {
    let mut node = node_with(events(), true);
    let mut expected = vec![
        (Mti::INITIALIZATION_COMPLETE, LOCAL.to_bytes().to_vec()),
        (Mti::VERIFY_NODE_ID_GLOBAL, LOCAL.to_bytes().to_vec()),
    ];
    expected.extend(everything());
    assert_eq!(sent(&mut node), expected);
}

#[test]
fn identify_events_global_and_addressed_answer_every_declaration() {
    let mut node = node_with(events(), false);
    assert_eq!(sent(&mut node), []);
    feed(&mut node, PEER, Mti::IDENTIFY_EVENTS_GLOBAL, &[]);
    assert_eq!(sent(&mut node), everything());
    feed(&mut node, PEER, Mti::IDENTIFY_EVENTS_ADDRESSED, &[]);
    assert_eq!(sent(&mut node), everything());
    // Addressed to another node: nothing.
    let other = NodeId::from_bytes([5, 1, 1, 1, 0x40, 9]);
    let msg = MessageRef { mti: Mti::IDENTIFY_EVENTS_ADDRESSED, source: PEER, destination: Some(other), payload: &[] };
    node.handle_message(Instant::ZERO, msg);
    assert_eq!(sent(&mut node), []);
}

#[test]
fn identify_producer_and_consumer_answer_declared_events_only() {
    let mut node = node_with(events(), false);
    feed(&mut node, PEER, Mti::IDENTIFY_PRODUCER, &BUTTON.to_bytes());
    assert_eq!(sent(&mut node), [(Mti::PRODUCER_IDENTIFIED_VALID, BUTTON.to_bytes().to_vec())]);
    // An event inside the produced range: Identified for that event, with the range's state.
    let inside = EventId(0x0501_0101_4002_02A7);
    feed(&mut node, PEER, Mti::IDENTIFY_PRODUCER, &inside.to_bytes());
    assert_eq!(sent(&mut node), [(Mti::PRODUCER_IDENTIFIED_INVALID, inside.to_bytes().to_vec())]);
    feed(&mut node, PEER, Mti::IDENTIFY_CONSUMER, &EventId(0x0501_0101_4002_0011).to_bytes());
    assert_eq!(
        sent(&mut node),
        [(Mti::CONSUMER_IDENTIFIED_UNKNOWN, EventId(0x0501_0101_4002_0011).to_bytes().to_vec())]
    );
    // Not declared in that role, or outside every range, or too short: nothing.
    feed(&mut node, PEER, Mti::IDENTIFY_CONSUMER, &BUTTON.to_bytes());
    feed(&mut node, PEER, Mti::IDENTIFY_PRODUCER, &EventId(0x0501_0101_4002_0300).to_bytes());
    feed(&mut node, PEER, Mti::IDENTIFY_PRODUCER, &[5, 1, 1]);
    assert_eq!(sent(&mut node), []);
    assert_eq!(node.event_stats().malformed, 1);
}

#[test]
fn reports_reach_the_application_filtered_by_what_it_consumes() {
    let mut node = node_with(events(), false);
    feed(&mut node, PEER, Mti::PRODUCER_CONSUMER_EVENT_REPORT, &LAMP.to_bytes());
    let mut with_payload = EventId(0x0501_0101_4002_0010).to_bytes().to_vec();
    with_payload.extend([1, 2, 3, 4]);
    feed(&mut node, PEER, Mti::PRODUCER_CONSUMER_EVENT_REPORT, &with_payload);
    feed(&mut node, PEER, Mti::PRODUCER_CONSUMER_EVENT_REPORT, &BUTTON.to_bytes());
    feed(&mut node, PEER, Mti::LEARN_EVENT, &BUTTON.to_bytes());
    assert_eq!(
        notices(&mut node),
        [
            EventNotice::Report { from: PEER, event: LAMP, payload: vec![] },
            EventNotice::Report { from: PEER, event: EventId(0x0501_0101_4002_0010), payload: vec![1, 2, 3, 4] },
            EventNotice::Learn { from: PEER, event: BUTTON },
        ]
    );
    assert_eq!(node.event_stats().reports_ignored, 1);
}

#[test]
fn listening_to_everything_delivers_every_report_and_identified() {
    let mut config = EventConfig::default();
    config.listen = Listen::Everything;
    let mut node = node_with(config, false);
    feed(&mut node, PEER, Mti::PRODUCER_CONSUMER_EVENT_REPORT, &BUTTON.to_bytes());
    feed(&mut node, PEER, Mti::PRODUCER_IDENTIFIED_UNKNOWN, &BUTTON.to_bytes());
    feed(&mut node, PEER, Mti::CONSUMER_RANGE_IDENTIFIED, &EventId(0x0501_0101_4002_02FF).to_bytes());
    assert_eq!(
        notices(&mut node),
        [
            EventNotice::Report { from: PEER, event: BUTTON, payload: vec![] },
            EventNotice::Identified {
                from: PEER,
                role: EventRole::Producer,
                range: EventRange::single(BUTTON),
                state: Some(EventState::Unknown)
            },
            EventNotice::Identified {
                from: PEER,
                role: EventRole::Consumer,
                range: EventRange::covering(EventId(0x0501_0101_4002_0200), 256).unwrap(),
                state: None
            },
        ]
    );
}

#[test]
fn pip_has_event_exchange_only_with_events() {
    assert!(node_with(events(), false).protocols().contains(Protocols::EVENT_EXCHANGE));
    let plain = node_with(EventConfig::default(), false);
    assert!(!plain.protocols().contains(Protocols::EVENT_EXCHANGE));
}

#[test]
fn without_events_addressed_identify_events_is_rejected_as_before() {
    let mut node = node_with(EventConfig::default(), false);
    feed(&mut node, PEER, Mti::IDENTIFY_EVENTS_ADDRESSED, &[]);
    let answers: Vec<Mti> = std::iter::from_fn(|| node.poll_transmit()).map(|m| m.mti).collect();
    assert_eq!(answers, [Mti::OPTIONAL_INTERACTION_REJECTED]);
}

#[test]
fn reports_and_learn_event_go_out() {
    let mut node = node_with(events(), false);
    node.send_event(BUTTON, &[]).unwrap();
    node.send_event(BUTTON, &[9, 8, 7]).unwrap();
    node.teach_event(LAMP).unwrap();
    node.identify(EventRole::Consumer, LAMP).unwrap();
    node.identify_events(None).unwrap();
    let mut with_payload = BUTTON.to_bytes().to_vec();
    with_payload.extend([9, 8, 7]);
    assert_eq!(
        sent(&mut node),
        [
            (Mti::PRODUCER_CONSUMER_EVENT_REPORT, BUTTON.to_bytes().to_vec()),
            (Mti::PRODUCER_CONSUMER_EVENT_REPORT, with_payload),
            (Mti::LEARN_EVENT, LAMP.to_bytes().to_vec()),
            (Mti::IDENTIFY_CONSUMER, LAMP.to_bytes().to_vec()),
            (Mti::IDENTIFY_EVENTS_GLOBAL, vec![]),
        ]
    );
}

#[test]
fn sending_stops_at_the_transmit_queue_limit() {
    let mut config = NodeConfig::default();
    config.events = events();
    config.transmit_queue_limit = 4;
    config.send_initialization_complete = false;
    let mut node = Node::new(LOCAL, config);
    for _ in 0..4 {
        node.send_event(BUTTON, &[]).unwrap();
    }
    assert_eq!(node.send_event(BUTTON, &[]), Err(EventError::QueueFull));
}

#[test]
fn a_flood_of_identify_events_from_1000_nodes_is_answered_by_one_pass() {
    let mut node = node_with(events(), false);
    for n in 0..1000u64 {
        let source = NodeId::new(0x0501_0101_5000 + n).unwrap();
        let mti = if n % 2 == 0 { Mti::IDENTIFY_EVENTS_GLOBAL } else { Mti::IDENTIFY_EVENTS_ADDRESSED };
        feed(&mut node, source, mti, &[]);
    }
    // Nothing was queued per request: one pass of four answers serves them all.
    assert_eq!(sent(&mut node), everything());
    assert_eq!(node.event_stats().identify_events, 1000);
}

#[test]
fn a_request_during_a_pass_is_answered_with_everything_from_then_on() {
    let mut node = node_with(events(), false);
    feed(&mut node, PEER, Mti::IDENTIFY_EVENTS_GLOBAL, &[]);
    let first: Vec<_> = std::iter::from_fn(|| node.poll_transmit()).take(3).map(|m| (m.mti, m.payload)).collect();
    assert_eq!(first, everything()[..3]);
    feed(&mut node, PEER, Mti::IDENTIFY_EVENTS_GLOBAL, &[]);
    // The pass goes on where it stood and comes round once: every declaration after the
    // second request, none twice more than needed.
    let rest = sent(&mut node);
    let mut expected = everything()[3..].to_vec();
    expected.extend(everything()[..3].iter().cloned());
    assert_eq!(rest, expected);
}

/// Events changed while the node runs (a board a tool has just configured): the new ones are
/// identified at once, Identify answers follow them, the old ones are no longer answered, and
/// a node that had no events gains the Event Exchange bit.
#[test]
fn events_set_at_run_time_are_identified_and_answered_at_once() {
    let mut config = NodeConfig::default();
    config.send_initialization_complete = false;
    let mut node = Node::new(NodeId::new(0x05_01_01_01_22_30).unwrap(), config);
    let tool = NodeId::new(0x05_01_01_01_22_31).unwrap();
    assert!(!node.protocols().contains(Protocols::EVENT_EXCHANGE));
    let old = EventId(0x0501_0101_2230_0001);
    let new = EventId(0x0501_0101_2230_0002);
    let mut events = EventConfig::default();
    events.produced = vec![DeclaredEvents::single(old, EventState::Unknown)];
    node.set_events(events.clone());
    while node.poll_transmit().is_some() {}
    events.produced = vec![DeclaredEvents::single(new, EventState::Unknown)];
    events.consumed = vec![DeclaredEvents::single(old, EventState::Unknown)];
    node.set_events(events);
    let sent: Vec<(Mti, Vec<u8>)> = std::iter::from_fn(|| node.poll_transmit()).map(|m| (m.mti, m.payload)).collect();
    assert_eq!(
        sent,
        [
            (Mti::PRODUCER_IDENTIFIED_UNKNOWN, new.to_bytes().to_vec()),
            (Mti::CONSUMER_IDENTIFIED_UNKNOWN, old.to_bytes().to_vec())
        ]
    );
    assert!(node.protocols().contains(Protocols::EVENT_EXCHANGE));
    for (event, answered) in [(old, false), (new, true)] {
        let ask = Message::global(Mti::IDENTIFY_PRODUCER, tool, event.to_bytes());
        node.handle_message(Instant::ZERO, ask.as_ref());
        assert_eq!(node.poll_transmit().is_some(), answered, "{event}");
    }
}
