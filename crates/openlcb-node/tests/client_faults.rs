//! The Memory Configuration client against a server scripted message by message, when what
//! arrives is not what was asked: the client reports it and never hands over a short result.

use openlcb_node::memconfig::wire::{Command, FailedKind, OptionsReply, Reply, SpaceInfoReply};
use openlcb_node::{MemoryError, MemoryEvent, Node, NodeConfig, NodeEvent, TransferPath};
use openlcb_stream::wire::ErrorCode;
use openlcb_stream::{Duration, Instant, Message, Mti, NodeId};

const CLIENT: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 1]);
const SERVER: NodeId = NodeId::from_bytes([5, 1, 1, 1, 0x40, 2]);
const SID: u8 = 0x11;

/// A server scripted for one read by stream: its Get Address Space Information answer, the
/// bytes it streams and the count its Complete states.
struct Script {
    /// The read's length (`None`: to the end of the space).
    len: Option<u32>,
    /// (space named, size) of the Get Address Space Information reply; `None`: the command
    /// is rejected (0x1041), as by a node that does not implement it.
    info: Option<(u8, u64)>,
    data: Vec<u8>,
    stated: u32,
}

impl Script {
    /// A whole-space read of space 0xFD that holds `data` and says so.
    fn honest(data: &[u8]) -> Script {
        Script { len: None, info: Some((0xFD, data.len() as u64)), data: data.to_vec(), stated: data.len() as u32 }
    }

    /// Runs the read against the script; returns the client's final event and the commands
    /// it sent.
    fn run(&self) -> (MemoryEvent, Vec<Command>) {
        let mut client = Node::new(CLIENT, NodeConfig::default());
        let _ = std::iter::from_fn(|| client.poll_transmit()).count();
        client.read_memory(Instant::ZERO, SERVER, 0xFD, 0, self.len, TransferPath::Stream).unwrap();
        let mut now = Instant::ZERO;
        let mut did = 0;
        let mut commands = Vec::new();
        for _ in 0..1_000 {
            let mut answers = Vec::new();
            let send = |answers: &mut Vec<Message>, mti, payload: Vec<u8>| {
                answers.push(Message::addressed(mti, SERVER, CLIENT, payload));
            };
            while let Some(m) = client.poll_transmit() {
                match m.mti {
                    Mti::DATAGRAM => match Command::parse(&m.payload) {
                        Ok(command @ Command::GetSpaceInfo { .. }) => {
                            commands.push(command);
                            let Some((space, size)) = self.info else {
                                send(&mut answers, Mti::DATAGRAM_REJECTED, vec![0x10, 0x41]);
                                continue;
                            };
                            send(&mut answers, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
                            let info = SpaceInfoReply {
                                space,
                                present: true,
                                highest_address: Some((size - 1) as u32),
                                read_only: false,
                                lowest_address: None,
                                description: Vec::new(),
                            };
                            send(&mut answers, Mti::DATAGRAM, Reply::SpaceInfo(info).to_bytes());
                        }
                        Ok(command @ Command::ReadStream { destination_stream, .. }) => {
                            commands.push(command);
                            did = destination_stream;
                            send(&mut answers, Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
                            send(&mut answers, Mti::STREAM_INITIATE_REQUEST, vec![0x08, 0x00, 0, 0, SID, did]);
                        }
                        Ok(command) => commands.push(command),
                        Err(_) => {}
                    },
                    Mti::STREAM_INITIATE_REPLY => {
                        let reply = Reply::ReadStreamOk {
                            space: Some(0xFD),
                            address: 0,
                            source_stream: SID,
                            destination_stream: did,
                            count: Some(u32::MAX),
                        };
                        send(&mut answers, Mti::DATAGRAM, reply.to_bytes());
                        for chunk in self.data.chunks(256) {
                            let mut payload = vec![did];
                            payload.extend_from_slice(chunk);
                            send(&mut answers, Mti::STREAM_DATA_SEND, payload);
                        }
                        let n = self.stated.to_be_bytes();
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
                    return (e, commands);
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
}

/// Runs a whole-space read by stream against a server that sends `data` and then a
/// Complete stating `stated` bytes; returns the client's final event.
fn read_against(data: &[u8], stated: u32) -> MemoryEvent {
    let space_len = u64::from(stated.max(data.len() as u32));
    Script { stated, info: Some((0xFD, space_len)), ..Script::honest(data) }.run().0
}

#[test]
fn a_whole_space_read_by_stream_that_lost_bytes_fails() {
    let space: Vec<u8> = (0..1_024u32).map(|i| (i * 7) as u8).collect();
    // 21 bytes lost after byte 500; the Complete states 1024.
    let lossy: Vec<u8> = space[..500].iter().chain(&space[521..]).copied().collect();
    let end = read_against(&lossy, 1_024);
    assert!(
        matches!(end, MemoryEvent::Failed { error: MemoryError::CountMismatch { stated: 1_024, received: 1_003 }, .. }),
        "{end:?}"
    );
    // All 1024 bytes, and a Complete that states 50.
    let end = read_against(&space, 50);
    assert!(
        matches!(end, MemoryEvent::Failed { error: MemoryError::CountMismatch { stated: 50, received: 1_024 }, .. }),
        "{end:?}"
    );
    // The honest stream is read.
    let end = read_against(&space, 1_024);
    assert!(matches!(&end, MemoryEvent::ReadDone { data, .. } if *data == space), "{end:?}");
}

#[test]
fn a_whole_read_of_a_space_larger_than_the_limit_fails_before_a_byte_moves() {
    let limit = u64::from(openlcb_node::MemoryConfigOptions::default().max_read_len);
    let script = Script { info: Some((0xFD, limit + 1)), ..Script::honest(&[7; 100]) };
    let (end, commands) = script.run();
    assert!(
        matches!(end, MemoryEvent::Failed { error: MemoryError::SpaceTooLarge { size: Some(s), limit: l }, .. }
            if s == limit + 1 && u64::from(l) == limit),
        "{end:?}"
    );
    assert!(!commands.iter().any(|c| matches!(c, Command::ReadStream { .. })), "no stream asked for: {commands:?}");
}

#[test]
fn a_whole_read_by_stream_asks_the_size_first_and_reads_the_space() {
    let space: Vec<u8> = (0..700u32).map(|i| (i * 3) as u8).collect();
    let (end, commands) = Script::honest(&space).run();
    assert!(matches!(&end, MemoryEvent::ReadDone { data, .. } if *data == space), "{end:?}");
    assert!(matches!(commands.first(), Some(Command::GetSpaceInfo { space: 0xFD })), "{commands:?}");
    // A node without Get Address Space Information is read to the end all the same.
    let (end, _) = Script { info: None, ..Script::honest(&space) }.run();
    assert!(matches!(&end, MemoryEvent::ReadDone { data, .. } if *data == space), "{end:?}");
}

#[test]
fn a_stream_longer_than_asked_fails_as_an_overrun() {
    let space = vec![5; 1_024];
    // A read of 100 bytes answered with 1024.
    let (end, _) = Script { len: Some(100), ..Script::honest(&space) }.run();
    assert!(matches!(end, MemoryEvent::Failed { error: MemoryError::Overrun { expected: 100 }, .. }), "{end:?}");
    // A whole-space read of a space that says it holds 600 bytes, answered with 1024.
    let (end, _) = Script { info: Some((0xFD, 600)), ..Script::honest(&space) }.run();
    assert!(matches!(end, MemoryEvent::Failed { error: MemoryError::Overrun { expected: 600 }, .. }), "{end:?}");
}

#[test]
fn a_space_information_reply_for_another_space_fails_at_once() {
    let (end, commands) = Script { info: Some((0xFE, 1_024)), ..Script::honest(&[1; 1_024]) }.run();
    assert!(
        matches!(end, MemoryEvent::Failed { error: MemoryError::WrongSpace { asked: 0xFD, answered: 0xFE }, .. }),
        "{end:?}"
    );
    assert_eq!(commands.len(), 1, "asked once, not retried until a timeout: {commands:?}");
}

#[test]
fn a_read_whose_stream_the_server_has_no_room_for_goes_by_datagrams() {
    // The server takes streams (its options say so) but has no stream transfer free: its
    // Read Stream Reply fails with 0x2020. The client reads the same bytes by datagrams.
    let data = (0..200u32).map(|i| (i * 7) as u8).collect::<Vec<u8>>();
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let _ = std::iter::from_fn(|| client.poll_transmit()).count();
    client.read_memory(Instant::ZERO, SERVER, 0xFD, 0, Some(200), TransferPath::Auto).unwrap();
    let mut commands = Vec::new();
    for _ in 0..100 {
        let mut answers = Vec::new();
        while let Some(m) = client.poll_transmit() {
            let Ok(command) = Command::parse(&m.payload) else { continue };
            let reply = match command {
                Command::GetOptions => Reply::Options(OptionsReply {
                    commands: 0,
                    write_lengths: 0xE2 | OptionsReply::STREAMS,
                    highest_space: 0xFF,
                    lowest_space: None,
                    name: Vec::new(),
                }),
                Command::ReadStream { space, address, .. } => {
                    Reply::Failed { kind: FailedKind::ReadStream, space: Some(space), address, code: ErrorCode(0x2020) }
                }
                Command::Read { space, address, count } => {
                    let at = address as usize;
                    Reply::ReadOk { space, address, data: data[at..at + usize::from(count)].to_vec() }
                }
                _ => continue,
            };
            commands.push(command);
            answers.push(Message::addressed(Mti::DATAGRAM_RECEIVED_OK, SERVER, CLIENT, vec![0x80]));
            answers.push(Message::addressed(Mti::DATAGRAM, SERVER, CLIENT, reply.to_bytes()));
        }
        for a in &answers {
            client.handle_message(Instant::ZERO, a.as_ref());
        }
        if let Some(NodeEvent::Memory(event)) = std::iter::from_fn(|| client.poll_event()).last() {
            match event {
                MemoryEvent::ReadDone { data: read, .. } => assert_eq!(read, data),
                other => panic!("{other:?}"),
            }
            assert!(matches!(commands[1], Command::ReadStream { .. }), "{commands:?}");
            assert!(
                matches!(
                    commands[2..],
                    [Command::Read { .. }, Command::Read { .. }, Command::Read { .. }, Command::Read { .. }]
                ),
                "{commands:?}"
            );
            return;
        }
    }
    panic!("no end: {commands:?}");
}

#[test]
fn the_unfreeze_after_a_firmware_stream_leaves_after_the_streams_last_data_and_complete() {
    // A target like OpenMRN's Bootloader: its Write Stream Reply comes before the stream, so
    // the client's Unfreeze is due the moment its last data and Complete are queued. Sent
    // before them, it ends the upgrade with the image short of those bytes.
    let mut client = Node::new(CLIENT, NodeConfig::default());
    let _ = std::iter::from_fn(|| client.poll_transmit()).count();
    client.upgrade_firmware(Instant::ZERO, SERVER, vec![0x5A; 300], TransferPath::Auto).unwrap();
    let mut order = Vec::new();
    let mut now = Instant::ZERO;
    for _ in 0..20 {
        let mut answers = Vec::new();
        let mut answer = |mti, payload: Vec<u8>| answers.push(Message::addressed(mti, SERVER, CLIENT, payload));
        while let Some(m) = client.poll_transmit() {
            order.push((m.mti, m.payload.get(..2).map(<[u8]>::to_vec)));
            match m.mti {
                Mti::PROTOCOL_SUPPORT_INQUIRY => answer(Mti::PROTOCOL_SUPPORT_REPLY, vec![0x70, 0, 0x10, 0, 0, 0]),
                Mti::DATAGRAM => match Command::parse(&m.payload) {
                    Ok(Command::WriteStream { space, address, .. }) => {
                        answer(Mti::DATAGRAM_RECEIVED_OK, vec![0x80]);
                        let reply = Reply::WriteStreamOk { space: Some(space), address, streams: None };
                        answer(Mti::DATAGRAM, reply.to_bytes());
                    }
                    _ => answer(Mti::DATAGRAM_RECEIVED_OK, vec![]),
                },
                Mti::STREAM_INITIATE_REQUEST => {
                    answer(Mti::STREAM_INITIATE_REPLY, vec![0x04, 0x00, 0x80, 0x00, m.payload[4], 0x5A]);
                }
                _ => {}
            }
        }
        // A drive loop runs the timers after the input, then sends what both queued.
        now += Duration::from_millis(1);
        for a in &answers {
            client.handle_message(now, a.as_ref());
        }
        client.handle_timeout(now);
        let _ = std::iter::from_fn(|| client.poll_event()).count();
    }
    let unfreeze = order.iter().position(|(mti, head)| *mti == Mti::DATAGRAM && head.as_deref() == Some(&[0x20, 0xA0]));
    let complete = order.iter().position(|(mti, _)| *mti == Mti::STREAM_DATA_COMPLETE);
    let last_data = order.iter().rposition(|(mti, _)| *mti == Mti::STREAM_DATA_SEND);
    assert!(complete.is_some() && last_data.is_some(), "{order:?}");
    assert!(unfreeze > complete && complete > last_data, "{order:?}");
}
