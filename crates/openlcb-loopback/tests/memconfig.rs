//! Memory Configuration server and client against each other on the harness, over CAN,
//! OpenLCB-TCP and through the gateway: backups, restores and firmware upgrades by stream
//! and by datagrams, verified byte for byte, with faults; and the stream-vs-datagram figure.

use openlcb_gateway::GatewayConfig;
use openlcb_loopback::{FrameFaults, Network, NodeIndex, NodeOptions, ScheduledFault};
use openlcb_node::{MemoryError, MemoryEvent, MemoryServer, NodeEvent, RamSpace, ReadOnlySpace, TransferPath};
use openlcb_stream::{Duration, Instant, NodeId};

const MIB: u32 = 1024 * 1024;
const KIB64: u32 = 64 * 1024;

fn node(n: u64) -> NodeId {
    NodeId::new(0x0501_0101_4000 + n).unwrap()
}

fn pattern(len: u32, key: u32) -> Vec<u8> {
    (0..len).map(|i| (i.wrapping_mul(2_654_435_761).wrapping_add(key) >> 13) as u8).collect()
}

/// A server with a 1 MiB configuration space (0xFD, a pattern), a CDI, the ACDI spaces
/// and a 128 KiB firmware target.
fn big_server() -> MemoryServer {
    MemoryServer::new()
        .with_space(0xFD, RamSpace::from_bytes(pattern(MIB, 1)))
        .with_space(0xFF, ReadOnlySpace::cdi("<?xml version=\"1.0\"?><cdi/>"))
        .with_space(0xEF, RamSpace::new(128 * 1024))
        .with_acdi()
}

/// The same with a 64 KiB configuration space.
fn small_server() -> MemoryServer {
    MemoryServer::new()
        .with_space(0xFD, RamSpace::from_bytes(pattern(KIB64, 1)))
        .with_space(0xEF, RamSpace::new(128 * 1024))
}

enum Link {
    Can,
    Tcp,
    /// The client behind a gateway (full format), the server on CAN.
    Gateway,
}

/// A client and a server on `link`, logged in; returns (network, client, server).
fn network(link: Link, make: fn() -> MemoryServer, server: NodeOptions) -> (Network, NodeIndex, NodeIndex) {
    let mut net = Network::new(7);
    let mut server = server;
    server.memory_server = Some(make);
    let (client, server) = match link {
        Link::Can => {
            let bus = net.add_bus(125_000, 16);
            let c = net.add_can_node(node(1), bus, NodeOptions::default());
            let s = net.add_can_node(node(2), bus, server);
            (c, s)
        }
        Link::Tcp => {
            let [c, s] = net.add_tcp_pair(
                [node(1), node(2)],
                [NodeOptions::default(), server],
                Duration::from_millis(1),
                1_000_000,
            );
            (c, s)
        }
        Link::Gateway => {
            let bus = net.add_bus(125_000, 16);
            let gateway = net.add_gateway(node(0x10), bus, GatewayConfig::default(), Duration::from_millis(1));
            let s = net.add_can_node(node(2), bus, server);
            let c = net.add_node_behind(gateway, node(1), NodeOptions::default(), Duration::from_millis(1), 1_000_000);
            (c, s)
        }
    };
    net.run_until(Instant::from_millis(1_000), 1_000_000).unwrap();
    (net, client, server)
}

/// Runs until `client` raises the end of an operation, at most `limit` of virtual time.
fn finish(net: &mut Network, client: NodeIndex, limit: Duration) -> MemoryEvent {
    let end = net.now() + limit;
    while net.now() < end {
        let step = net.now() + Duration::from_millis(250);
        net.run_until(step, 100_000_000).unwrap();
        for event in net.take_events(client) {
            if let NodeEvent::Memory(
                event @ (MemoryEvent::ReadDone { .. } | MemoryEvent::WriteDone { .. } | MemoryEvent::Failed { .. }),
            ) = event
            {
                return event;
            }
        }
    }
    panic!("no end within {limit:?}: a hang");
}

fn server_space(net: &mut Network, server: NodeIndex, space: u8) -> Vec<u8> {
    let s = net.node(server).unwrap().memory_server_mut().unwrap().space_mut(space).unwrap();
    let mut buf = vec![0; s.len() as usize];
    let n = s.read(0, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

fn read(net: &mut Network, client: NodeIndex, space: u8, len: Option<u32>, path: TransferPath) -> MemoryEvent {
    let (now, peer) = (net.now(), node(2));
    net.node(client).unwrap().read_memory(now, peer, space, 0, len, path).unwrap();
    finish(net, client, Duration::from_secs(3_000))
}

fn backup_and_restore(link: Link, make: fn() -> MemoryServer, len: u32) {
    let (mut net, client, server) = network(link, make, NodeOptions::default());
    for path in [TransferPath::Auto, TransferPath::Datagrams] {
        // Backup: the whole space.
        match read(&mut net, client, 0xFD, None, path) {
            MemoryEvent::ReadDone { data, .. } => assert!(data == pattern(len, 1), "{path:?}: backup differs"),
            other => panic!("{path:?}: {other:?}"),
        }
        // Restore another image, then read it back.
        let image = pattern(len, 77 + path as u32);
        let now = net.now();
        net.node(client).unwrap().write_memory(now, node(2), 0xFD, 0, image.clone(), path).unwrap();
        match finish(&mut net, client, Duration::from_secs(3_000)) {
            MemoryEvent::WriteDone { len: n, .. } => assert_eq!(n, u64::from(len)),
            other => panic!("{path:?}: {other:?}"),
        }
        assert!(server_space(&mut net, server, 0xFD) == image, "{path:?}: restore differs");
        // Put the original back for the next path.
        let original = pattern(len, 1);
        let space = net.node(server).unwrap().memory_server_mut().unwrap().space_mut(0xFD).unwrap();
        space.write(0, &original).unwrap();
    }
}

fn firmware(link: Link) {
    let (mut net, client, server) = network(link, small_server, NodeOptions::default());
    for path in [TransferPath::Auto, TransferPath::Datagrams] {
        let image = pattern(KIB64, 5 + path as u32);
        let now = net.now();
        net.node(client).unwrap().upgrade_firmware(now, node(2), image.clone(), path).unwrap();
        match finish(&mut net, client, Duration::from_secs(3_000)) {
            MemoryEvent::WriteDone { len, .. } => assert_eq!(len, u64::from(KIB64)),
            other => panic!("{path:?}: {other:?}"),
        }
        assert!(server_space(&mut net, server, 0xEF)[..KIB64 as usize] == image[..], "{path:?}: image differs");
        let unfrozen = net.take_events(server).into_iter().find_map(|e| match e {
            NodeEvent::Memory(MemoryEvent::Unfrozen { image_len, .. }) => Some(image_len),
            _ => None,
        });
        assert_eq!(unfrozen, Some(KIB64), "{path:?}");
    }
}

// ----- CAN -----

#[test]
fn can_backup_and_restore_64k_by_stream_and_by_datagrams() {
    backup_and_restore(Link::Can, small_server, KIB64);
}

#[test]
fn can_firmware_64k_by_stream_and_by_datagrams() {
    firmware(Link::Can);
}

#[test]
fn can_backup_and_restore_1mib_by_stream_and_by_datagrams() {
    backup_and_restore(Link::Can, big_server, MIB);
}

// ----- OpenLCB-TCP -----

#[test]
fn tcp_backup_and_restore_1mib_by_stream_and_by_datagrams() {
    backup_and_restore(Link::Tcp, big_server, MIB);
}

#[test]
fn tcp_firmware_64k_by_stream_and_by_datagrams() {
    firmware(Link::Tcp);
}

// ----- through the gateway -----

#[test]
fn gateway_backup_and_restore_1mib_by_stream_and_by_datagrams() {
    backup_and_restore(Link::Gateway, big_server, MIB);
}

#[test]
fn gateway_firmware_64k_by_stream_and_by_datagrams() {
    firmware(Link::Gateway);
}

// ----- faults -----

#[test]
fn lost_frames_end_in_a_verified_result_or_a_reported_error() {
    for (seed, path) in [(1, TransferPath::Datagrams), (2, TransferPath::Datagrams), (3, TransferPath::Stream)] {
        let (mut net, client, _) = network(Link::Can, small_server, NodeOptions::default());
        net.set_frame_faults(FrameFaults { drop: 0.002 * seed as f64, ..FrameFaults::default() });
        match read(&mut net, client, 0xFD, Some(16 * 1024), path) {
            MemoryEvent::ReadDone { data, .. } => assert!(data[..] == pattern(KIB64, 1)[..16 * 1024], "{path:?}"),
            MemoryEvent::Failed { error, .. } => eprintln!("seed {seed} {path:?}: reported {error:?}"),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn a_temporary_rejection_is_resent() {
    // One stream at a time on the server: the second client's Read Stream is rejected with
    // 0x2020 (temporary), its datagram is sent again after a pause, and both end verified.
    let mut server = NodeOptions::default();
    server.node.memory.max_server_streams = 1;
    server.memory_server = Some(small_server);
    let mut net = Network::new(3);
    let bus = net.add_bus(125_000, 16);
    let a = net.add_can_node(node(1), bus, NodeOptions::default());
    let b = net.add_can_node(node(3), bus, NodeOptions::default());
    let s = net.add_can_node(node(2), bus, server);
    net.run_until(Instant::from_millis(1_000), 1_000_000).unwrap();
    let now = net.now();
    for client in [a, b] {
        net.node(client).unwrap().read_memory(now, node(2), 0xFD, 0, Some(2048), TransferPath::Stream).unwrap();
    }
    for client in [a, b] {
        match finish(&mut net, client, Duration::from_secs(60)) {
            MemoryEvent::ReadDone { data, .. } => assert!(data[..] == pattern(KIB64, 1)[..2048]),
            other => panic!("{other:?}"),
        }
    }
    let stats = net.node(s).unwrap().memory_server().unwrap().stats();
    assert!(stats.rejected >= 1, "{stats:?}");
    assert!(net.node(a).unwrap().stats().datagrams.resent + net.node(b).unwrap().stats().datagrams.resent >= 1);
}

#[test]
fn server_reset_in_the_middle_of_an_upgrade_is_reported_then_a_retry_succeeds() {
    let (mut net, client, server) = network(Link::Can, small_server, NodeOptions::default());
    let image = pattern(KIB64, 9);
    let now = net.now();
    net.node(client).unwrap().upgrade_firmware(now, node(2), image.clone(), TransferPath::Auto).unwrap();
    net.schedule(now + Duration::from_secs(3), ScheduledFault::Reset(server));
    match finish(&mut net, client, Duration::from_secs(600)) {
        MemoryEvent::Failed { error, .. } => {
            assert!(matches!(error, MemoryError::PeerRestarted | MemoryError::StreamEnded(_)), "{error:?}")
        }
        other => panic!("the reset went unnoticed: {other:?}"),
    }
    // FWU §5.4.3: a retry starts again at offset 0.
    net.run_until(net.now() + Duration::from_secs(1), 1_000_000).unwrap();
    let now = net.now();
    net.node(client).unwrap().upgrade_firmware(now, node(2), image.clone(), TransferPath::Auto).unwrap();
    assert!(matches!(finish(&mut net, client, Duration::from_secs(600)), MemoryEvent::WriteDone { .. }));
    assert!(server_space(&mut net, server, 0xEF)[..KIB64 as usize] == image[..]);
}

#[test]
fn client_gone_in_the_middle_leaves_the_server_clean() {
    for path in [TransferPath::Stream, TransferPath::Datagrams] {
        let (mut net, client, server) = network(Link::Can, small_server, NodeOptions::default());
        let now = net.now();
        net.node(client).unwrap().read_memory(now, node(2), 0xFD, 0, None, path).unwrap();
        net.schedule(now + Duration::from_secs(2), ScheduledFault::Silence(client));
        net.run_until(now + Duration::from_secs(120), 100_000_000).unwrap();
        let s = net.node(server).unwrap();
        assert_eq!(s.memory_server().unwrap().active_streams(), 0, "{path:?}");
        assert_eq!(s.streams().stream_count(), 0, "{path:?}: a stream to the silent client is left");
    }
}

// ----- the figure -----

/// The figure: a 64 KiB backup on the 125 kbit/s bus with 1 ms latency, by stream and by
/// datagrams, in virtual time (deterministic). Print it with
/// `cargo test -p openlcb-loopback --test memconfig figure -- --nocapture`.
#[test]
fn figure_stream_backup_is_faster_than_datagram_backup() {
    let time = |path| {
        let (mut net, client, _) = network(Link::Can, small_server, NodeOptions::default());
        net.record_frames();
        let start = net.now();
        match read(&mut net, client, 0xFD, None, path) {
            MemoryEvent::ReadDone { data, .. } => assert!(data == pattern(KIB64, 1)),
            other => panic!("{other:?}"),
        }
        let end = net.recorded_frames().last().map_or(net.now(), |(t, _)| *t);
        (end.as_micros() - start.as_micros()) as f64 / 1e6
    };
    let stream = time(TransferPath::Stream);
    let datagrams = time(TransferPath::Datagrams);
    let rate = |s: f64| f64::from(KIB64) / s;
    println!(
        "64 KiB backup on 125 kbit/s CAN, 1 ms latency: stream {:.0} B/s ({stream:.2} s), datagrams {:.0} B/s ({datagrams:.2} s), ratio {:.2}",
        rate(stream),
        rate(datagrams),
        datagrams / stream
    );
    assert!(stream < datagrams, "stream {stream} s, datagrams {datagrams} s");
}

// ----- the worked examples, frame by frame -----

const CDI: &str = "<?xml version=\"1.0\"?>\n<cdi xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\"></cdi>";

fn example_server() -> MemoryServer {
    MemoryServer::new().with_space(0xFD, RamSpace::new(512)).with_space(0xFF, ReadOnlySpace::cdi(CDI))
}

fn text(frame: &openlcb_can::CanFrame) -> String {
    let mut buf = [0u8; 32];
    let n = openlcb_can::gridconnect::encode(frame, &mut buf).unwrap();
    String::from_utf8(buf[..n].to_vec()).unwrap()
}

#[test]
fn worked_examples_9_1_9_2_and_9_6_frame_by_frame() {
    let mut net = Network::new(1);
    let bus = net.add_bus(125_000, 16);
    let mut ct = NodeOptions::default();
    ct.can.first_alias = openlcb_can::NodeAlias::new(0x123);
    let mut target = NodeOptions::default();
    target.can.first_alias = openlcb_can::NodeAlias::new(0x456);
    target.memory_server = Some(example_server);
    let client = net.add_can_node(node(1), bus, ct);
    net.add_can_node(node(2), bus, target);
    net.run_until(Instant::from_millis(1_000), 1_000_000).unwrap();
    let exchange = |net: &mut Network, start: &dyn Fn(&mut Network)| -> Vec<String> {
        net.record_frames();
        start(net);
        assert!(!matches!(finish(net, client, Duration::from_secs(10)), MemoryEvent::Failed { .. }));
        net.recorded_frames().iter().map(|(_, f)| text(f)).collect()
    };
    // §9.1: a datagram write of 01..08 to 0xFD at 0, in the form OpenMRN and OpenLcbCLib use
    // (OK with Reply Pending, then a Write Reply the client acknowledges): OpenMRN's
    // memconfig_utils stops after one chunk when a write is answered by the OK alone.
    let frames = exchange(&mut net, &|net| {
        let now = net.now();
        net.node(client)
            .unwrap()
            .write_memory(now, node(2), 0xFD, 0, (1..=8).collect::<Vec<u8>>(), TransferPath::Datagrams)
            .unwrap();
    });
    assert_eq!(
        frames,
        [
            ":X1B456123N2001000000000102;",
            ":X1D456123N030405060708;",
            ":X19A28456N012380;",
            ":X1A123456N201100000000;",
            ":X19A28123N045600;"
        ]
    );
    // §9.2: a read of 64 bytes of the CDI.
    let frames = exchange(&mut net, &|net| {
        let now = net.now();
        net.node(client).unwrap().read_memory(now, node(2), 0xFF, 0, Some(64), TransferPath::Datagrams).unwrap();
    });
    assert_eq!(
        frames,
        [
            ":X1A456123N20430000000040;",
            ":X19A28456N012380;",
            ":X1B123456N2053000000003C3F;",
            ":X1C123456N786D6C2076657273;",
            ":X1C123456N696F6E3D22312E30;",
            ":X1C123456N223F3E0A3C636469;",
            ":X1C123456N20786D6C6E733A78;",
            ":X1C123456N73693D2268747470;",
            ":X1C123456N3A2F2F7777772E77;",
            ":X1C123456N332E6F72672F3230;",
            ":X1D123456N30312F584D4C;",
            ":X19A28123N045600;",
        ]
    );
    // §9.6: Get Address Space Information for 0xFD (a datagram read to the end asks it first).
    let frames = exchange(&mut net, &|net| {
        let now = net.now();
        net.node(client).unwrap().read_memory(now, node(2), 0xFD, 0, None, TransferPath::Datagrams).unwrap();
    });
    assert_eq!(
        frames[..4],
        [":X1A456123N2084FD;", ":X19A28456N012380;", ":X1A123456N2087FD000001FF00;", ":X19A28123N045600;"]
    );
}

#[test]
fn the_unfreeze_after_a_firmware_stream_goes_after_its_last_data_and_complete() {
    // A firmware target that acts on the Unfreeze at once (OpenMRN's Bootloader) would keep
    // an image without the bytes an early Unfreeze overtook. Like that Bootloader, the
    // server sends its Write Stream Reply before the stream, so nothing holds the client
    // back once its last data is queued.
    let mut server = NodeOptions::default();
    server.node.memory.write_stream_reply_delay = Duration::ZERO;
    let (mut net, client, _) = network(Link::Can, small_server, server);
    net.record_frames();
    let now = net.now();
    let image = pattern(10_000, 5);
    net.node(client).unwrap().upgrade_firmware(now, node(2), image, TransferPath::Stream).unwrap();
    assert!(matches!(finish(&mut net, client, Duration::from_secs(60)), MemoryEvent::WriteDone { .. }));
    let frames: Vec<u32> = net.recorded_frames().iter().map(|(_, f)| f.raw_id()).collect();
    let payloads: Vec<&[u8]> = net.recorded_frames().iter().map(|(_, f)| f.payload()).collect();
    let last_data = frames.iter().rposition(|id| id >> 24 == 0x1F).unwrap();
    let complete = frames.iter().position(|id| id >> 12 == 0x198A8).expect("a Data Complete");
    let unfreeze = (0..frames.len()).find(|&i| frames[i] >> 24 == 0x1A && payloads[i].starts_with(&[0x20, 0xA0, 0xEF]));
    let unfreeze = unfreeze.expect("an Unfreeze went out");
    assert!(
        unfreeze > last_data && unfreeze > complete,
        "Unfreeze at {unfreeze}, data until {last_data}, Complete at {complete}"
    );
}
