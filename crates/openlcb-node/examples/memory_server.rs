//! A node serving memory spaces, and a Memory Configuration client using them, back to back:
//! B serves its CDI (space 0xFF, read-only XML) and 64 bytes of configuration (space 0xFD,
//! RAM); A reads the CDI by stream, writes four configuration bytes by datagrams and reads
//! them back.
//!
//! `cargo run -p openlcb-node --example memory_server`

use openlcb_node::{MemoryEvent, MemoryServer, Node, NodeConfig, NodeEvent, RamSpace, ReadOnlySpace, TransferPath};
use openlcb_stream::{Instant, NodeId};

mod common;
use common::pump;

const CDI: &str = "<?xml version=\"1.0\"?><cdi><identification><model>Widget</model></identification></cdi>";

/// Passes messages both ways and drains both nodes' events until quiet; returns A's Memory
/// Configuration events.
fn pump_events(now: Instant, a: &mut Node, b: &mut Node) -> Vec<MemoryEvent> {
    let mut events = Vec::new();
    loop {
        // Events come after transmits and may queue more of them.
        let mut any = pump(now, a, b);
        while let Some(event) = a.poll_event() {
            if let NodeEvent::Memory(event) = event {
                events.push(event);
            }
            any = true;
        }
        while b.poll_event().is_some() {
            any = true;
        }
        if !any {
            return events;
        }
    }
}

/// The one event an operation ended with.
fn only(mut events: Vec<MemoryEvent>) -> MemoryEvent {
    assert_eq!(events.len(), 1, "{events:?}");
    events.remove(0)
}

fn main() {
    let a_id: NodeId = "05.01.01.01.22.00".parse().expect("a valid Node ID");
    let b_id: NodeId = "05.01.01.01.22.01".parse().expect("a valid Node ID");
    let server = MemoryServer::new().with_space(0xFF, ReadOnlySpace::cdi(CDI)).with_space(0xFD, RamSpace::new(64));
    let mut a = Node::new(a_id, NodeConfig::default());
    let mut b = Node::new(b_id, NodeConfig::default()).with_memory_server(server);
    let now = Instant::ZERO;
    pump(now, &mut a, &mut b); // both announce themselves

    a.read_memory(now, b_id, 0xFF, 0, None, TransferPath::Stream).expect("a free operation");
    let MemoryEvent::ReadDone { data, .. } = only(pump_events(now, &mut a, &mut b)) else {
        panic!("the CDI read failed")
    };
    let xml = String::from_utf8_lossy(&data);
    println!("A: CDI of {b_id} by stream, {} bytes: {}", data.len(), xml.trim_end_matches('\0'));
    assert!(xml.starts_with(CDI));

    a.write_memory(now, b_id, 0xFD, 8, vec![1, 2, 3, 4], TransferPath::Datagrams).expect("a free operation");
    let MemoryEvent::WriteDone { len, .. } = only(pump_events(now, &mut a, &mut b)) else { panic!("the write failed") };
    println!("A: wrote {len} bytes at 8 of space 0xFD by datagrams");

    a.read_memory(now, b_id, 0xFD, 0, None, TransferPath::Datagrams).expect("a free operation");
    let MemoryEvent::ReadDone { data, .. } = only(pump_events(now, &mut a, &mut b)) else { panic!("the read failed") };
    println!("A: space 0xFD reads back {:02X?}", &data[..16]);
    assert_eq!(data.len(), 64);
    assert_eq!(data[8..12], [1, 2, 3, 4]);
}

/// `cargo test` runs the example (`test = true` in Cargo.toml); it asserts on what it reads.
#[test]
fn serves_cdi_and_configuration() {
    main();
}
