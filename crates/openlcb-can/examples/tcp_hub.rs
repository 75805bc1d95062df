//! A CAN link over a TCP socket to a GridConnect hub, with nothing but `std::net`: the
//! program a newcomer writes to put a node on a layout's hub. Node A logs in (alias
//! reservation), sends a global Verify Node ID and asks every node that answers for its
//! Simple Node Information; it lists them after 2 s of quiet.
//!
//! Without an address it starts its own two-client relay on 127.0.0.1 (standing in for a
//! hub) and a second node, B, on it, so it needs no peer. With one, it joins that hub
//! (`lcc-stream hub`, JMRI, OpenMRN's `hub`) and lists the nodes there:
//!
//! `cargo run -p openlcb-can --example tcp_hub [-- HOST:PORT]`

use std::io::{self, ErrorKind, Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::thread;
use std::time::{Duration, Instant as Clock};

use openlcb_can::gridconnect::{self, GridConnectDecoder};
use openlcb_can::{CanConfig, CanLink, LinkEvent};
use openlcb_node::{Node, NodeConfig, NodeEvent, SnipInfo};
use openlcb_stream::{Instant, NodeId};

/// How long either node runs at most.
const DEADLINE: Duration = Duration::from_secs(10);
/// Quiet after the last answer before A's list is complete.
const QUIET: Duration = Duration::from_secs(2);
/// How long one read waits for the hub: the loop's tick.
const TICK: Duration = Duration::from_millis(10);

/// One node on a GridConnect connection: socket bytes -> GridConnect decoder -> CAN frames ->
/// `CanLink` -> messages -> `Node`, and back.
struct CanNode {
    socket: TcpStream,
    decoder: GridConnectDecoder,
    link: CanLink,
    node: Node,
    started: Clock,
    out: Vec<u8>,
}

impl CanNode {
    fn connect(addr: &str, id: NodeId, config: NodeConfig) -> io::Result<Self> {
        let socket = TcpStream::connect(addr)?;
        socket.set_read_timeout(Some(TICK))?;
        socket.set_nodelay(true)?;
        let started = Clock::now();
        let link = CanLink::new(Instant::ZERO, id, CanConfig::default());
        Ok(CanNode {
            socket,
            decoder: GridConnectDecoder::default(),
            link,
            node: Node::new(id, config),
            started,
            out: Vec::new(),
        })
    }

    /// The stack's time: microseconds since this node started.
    fn now(&self) -> Instant {
        Instant::from_micros(u64::try_from(self.started.elapsed().as_micros()).unwrap_or(u64::MAX))
    }

    /// One turn of the drive loop: what arrived (waiting at most a tick), the timers, then
    /// everything there is to send. `Ok(false)` once the hub closed the connection.
    fn turn(&mut self) -> io::Result<bool> {
        let mut buf = [0u8; 4096];
        let len = match self.socket.read(&mut buf) {
            Ok(0) => return Ok(false),
            Ok(len) => len,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => 0,
            Err(e) => return Err(e),
        };
        let now = self.now();
        let CanNode { decoder, link, node, out, .. } = self;
        // The link hands the node what it learns of its peers (gone, renamed) as it learns
        // it, then the messages: the node is its `Receiver`.
        link.handle_timeout(now, node);
        node.handle_timeout(now);
        decoder.decode_all(&buf[..len], |frame| {
            // Garbage between frames is skipped by the decoder; a bad frame is dropped here.
            if let Ok(frame) = frame {
                link.handle_frame(now, &frame, node);
            }
        });
        apply_link_events(link, node);
        // Take from the node only what the link has room for: the rest waits there.
        while link.can_send() {
            let Some(msg) = node.poll_transmit() else { break };
            let _ = link.send(now, msg); // a message with no CAN form is counted and dropped
        }
        while let Some(frame) = link.poll_transmit() {
            gridconnect::encode_to(&frame, out).map_err(io::Error::other)?;
        }
        self.socket.write_all(&self.out)?;
        self.out.clear();
        Ok(true)
    }
}

/// The link's own status, for the node.
fn apply_link_events(link: &mut CanLink, node: &mut Node) {
    while let Some(event) = link.poll_event() {
        match event {
            LinkEvent::AliasLost { .. } => node.link_lost(),
            // Another node has our Node ID: say so; the one that came second leaves.
            LinkEvent::DuplicateNodeId { newcomer: false, .. } => node.report_duplicate_node_id(),
            LinkEvent::DuplicateNodeId { newcomer: true, .. } => {
                link.leave(Some(node.duplicate_node_id_report()));
                node.link_lost();
            }
            _ => {}
        }
    }
}

/// A relay for two clients, standing in for a hub: what one sends, the other receives.
fn start_relay() -> io::Result<String> {
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let addr = listener.local_addr()?.to_string();
    thread::spawn(move || -> io::Result<()> {
        let (a, _) = listener.accept()?;
        let (b, _) = listener.accept()?;
        let (mut a_in, mut b_out, mut b_in, mut a_out) = (a.try_clone()?, b.try_clone()?, b, a);
        let one_way = thread::spawn(move || {
            let _ = io::copy(&mut a_in, &mut b_out);
            let _ = b_out.shutdown(std::net::Shutdown::Write);
        });
        let _ = io::copy(&mut b_in, &mut a_out);
        let _ = a_out.shutdown(std::net::Shutdown::Write);
        let _ = one_way.join();
        Ok(())
    });
    Ok(addr)
}

/// Node B: answers whatever is asked (Verify Node ID, SNIP) until the relay closes.
fn run_b(addr: &str) -> io::Result<()> {
    let mut config = NodeConfig::default();
    config.snip =
        SnipInfo { manufacturer: "openlcb-stream".into(), model: "tcp_hub example B".into(), ..SnipInfo::default() };
    let mut b = CanNode::connect(addr, "05.01.01.01.22.B1".parse().map_err(io::Error::other)?, config)?;
    while b.started.elapsed() < DEADLINE && b.turn()? {
        while b.node.poll_event().is_some() {}
    }
    Ok(())
}

/// Node A: logs in, asks who is there, lists them; returns the nodes that answered with SNIP.
fn run_a(addr: &str) -> io::Result<Vec<(NodeId, SnipInfo)>> {
    let me: NodeId = "05.01.01.01.22.A1".parse().map_err(io::Error::other)?;
    let mut a = CanNode::connect(addr, me, NodeConfig::default())?;
    let (mut asked, mut last_answer, mut found) = (false, Clock::now(), Vec::new());
    while a.started.elapsed() < DEADLINE && a.turn()? {
        if !asked && a.link.alias().is_some() {
            println!(
                "A: {me} logged in as alias {:03X}; Verify Node ID to all",
                a.link.alias().map_or(0, |x| x.as_raw())
            );
            a.node.verify_all();
            (asked, last_answer) = (true, Clock::now());
        }
        while let Some(event) = a.node.poll_event() {
            match event {
                NodeEvent::Verified { node } if node != me => {
                    let _ = a.node.request_snip(a.now(), node);
                    last_answer = Clock::now();
                }
                NodeEvent::SnipReceived { peer, info } => {
                    println!("  {peer}  {} / {}", info.manufacturer, info.model);
                    found.push((peer, *info));
                    last_answer = Clock::now();
                }
                _ => {}
            }
        }
        if asked && last_answer.elapsed() >= QUIET {
            break;
        }
    }
    println!("A: {} node(s) answered", found.len());
    Ok(found)
}

/// Joins the hub at `hub_addr`, or at a relay of its own with node B on it.
fn run(hub_addr: Option<String>) -> io::Result<Vec<(NodeId, SnipInfo)>> {
    let Some(addr) = hub_addr else {
        let addr = start_relay()?;
        println!("relay listening on {addr}");
        let b_addr = addr.clone();
        let b = thread::spawn(move || run_b(&b_addr));
        let found = run_a(&addr);
        // A's socket closes with it; the relay then closes B's and B stops.
        let _ = b.join();
        return found;
    };
    run_a(&addr)
}

fn main() -> io::Result<()> {
    run(std::env::args().nth(1))?;
    Ok(())
}

/// `cargo test` runs the example on its own relay (`test = true` in Cargo.toml): A finds B.
#[test]
fn a_finds_b_through_the_relay() {
    let found = run(None).unwrap();
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].1.model, "tcp_hub example B");
}
