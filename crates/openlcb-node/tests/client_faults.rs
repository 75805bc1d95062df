//! The Memory Configuration client against a server scripted message by message, when what
//! arrives is not what was asked: the client reports it and never hands over a short result.

use openlcb_node::memconfig::wire::{Command, Reply};
use openlcb_node::{MemoryError, MemoryEvent, Node, NodeConfig, NodeEvent, TransferPath};
use openlcb_stream::{Duration, Instant, Message, Mti, NodeId};

const CLIENT: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]);
const SERVER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
const SID: u8 = 0x11;

/// Runs a whole-space read by stream against a server that sends `data` and then a
/// Complete stating `stated` bytes; returns the client's final event.
fn read_against(data: &[u8], stated: u32) -> MemoryEvent {
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let _ = std::iter::from_fn(|| client.poll_transmit()).count();
    client.read_memory(Instant::ZERO, SERVER, 0xFD, 0, None, TransferPath::Stream).unwrap();
    let mut now = Instant::ZERO;
    let mut did = 0;
    for _ in 0..1_000 {
        let mut answers = Vec::new();
        let send = |answers: &mut Vec<Message>, mti, payload: Vec<u8>| {
            answers.push(Message::addressed(mti, SERVER, CLIENT, payload));
        };
        while let Some(m) = client.poll_transmit() {
            match m.mti {
                Mti::DATAGRAM => {
                    if let Ok(Command::ReadStream { destination_stream, .. }) = Command::parse(&m.payload) {
                        did = destination_stream;
                        send(&mut answers, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
                        send(&mut answers, Mti::STREAM_INITIATE_REQUEST, vec![0x08, 0x00, 0, 0, SID, did]);
                    }
                }
                Mti::STREAM_INITIATE_REPLY => {
                    let reply = Reply::ReadStreamOk {
                        space: Some(0xFD),
                        address: 0,
                        source_stream: SID,
                        destination_stream: did,
                        count: Some(u32::MAX),
                    };
                    send(&mut answers, Mti::DATAGRAM, reply.to_bytes());
                    for chunk in data.chunks(256) {
                        let mut payload = vec![did];
                        payload.extend_from_slice(chunk);
                        send(&mut answers, Mti::STREAM_DATA_SEND, payload);
                    }
                    let n = stated.to_be_bytes();
                    send(&mut answers, Mti::STREAM_DATA_COMPLETE, vec![SID, did, n[0], n[1], n[2], n[3]]);
                }
                _ => {}
            }
        }
        for a in &answers {
            client.handle_message(now, a.as_ref());
        }
        for event in std::iter::from_fn(|| client.poll_event()) {
            if let NodeEvent::Memory(e) = event {
                return e;
            }
        }
        if answers.is_empty() {
            now = client.poll_timeout().expect("nothing to wait for: a hang").max(now);
            assert!(now < Instant::ZERO + Duration::from_secs(600), "no end: a hang");
            client.handle_timeout(now);
        }
    }
    panic!("no end")
}

#[test]
fn a_whole_space_read_by_stream_that_lost_bytes_fails() {
    let space: Vec<u8> = (0..1_024u32).map(|i| (i * 7) as u8).collect();
    // 21 bytes lost after byte 500; the Complete states 1024.
    let lossy: Vec<u8> = space[..500].iter().chain(&space[521..]).copied().collect();
    let end = read_against(&lossy, 1_024);
    assert!(
        matches!(end, MemoryEvent::Failed { error: MemoryError::WrongLength { expected: 1_024, received: 1_003 }, .. }),
        "{end:?}"
    );
    // All 1024 bytes, and a Complete that states 50.
    let end = read_against(&space, 50);
    assert!(matches!(end, MemoryEvent::Failed { error: MemoryError::WrongLength { .. }, .. }), "{end:?}");
    // The honest stream is read.
    let end = read_against(&space, 1_024);
    assert!(matches!(&end, MemoryEvent::ReadDone { data, .. } if *data == space), "{end:?}");
}
