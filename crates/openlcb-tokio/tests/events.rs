//! Event reports by the thousand into a node over an in-memory GridConnect pipe: each one
//! reaches a listener or is counted in its [`EventNotices::dropped`]. Every wait is bounded.

mod common;

use common::bounded;
use openlcb_tokio::openlcb_node::Listen;
use openlcb_tokio::{EventNotices, Framing, Node, NodeId, NodeOptions};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _, DuplexStream};

const LISTENER: &str = "05.01.01.01.22.D0";

/// A node that hands every event message to its listeners, and the other end of its pipe.
async fn listening_node() -> (Node, DuplexStream) {
    let (ours, theirs) = tokio::io::duplex(64 * 1024);
    let mut options = NodeOptions::new(LISTENER.parse().unwrap());
    options.node.events.listen = Listen::Everything;
    let node = bounded("login", Node::over(ours, Framing::GridConnect, options)).await.unwrap();
    (node, theirs)
}

/// `count` Producer/Consumer Event Reports from alias 123, as one piece of text.
fn reports(count: usize) -> String {
    (0..count).map(|i| format!(":X195B4123N05010101220{i:05X};\n")).collect()
}

/// Sends a global Verify Node ID after `text` and waits for the node's Verified Node ID: by
/// then the node has handled every frame of `text`.
async fn send_and_settle(pipe: &mut DuplexStream, text: String) {
    let node: NodeId = LISTENER.parse().unwrap();
    let verified = format!("N{};", node.to_string().replace('.', ""));
    let (mut reader, mut writer) = tokio::io::split(pipe);
    let writing = async move {
        writer.write_all(text.as_bytes()).await.unwrap();
        writer.write_all(b":X19490123N;\n").await.unwrap();
    };
    let answered = async {
        let mut seen = String::new();
        let mut buf = vec![0u8; 4096];
        while !seen.lines().any(|l| l.starts_with(":X19170") && l.ends_with(&verified)) {
            let n = reader.read(&mut buf).await.unwrap();
            assert!(n > 0, "the node closed the pipe");
            seen.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
    };
    bounded("the node's Verified Node ID", async { tokio::join!(writing, answered) }).await;
}

/// The notices waiting for `listener`, taken without waiting.
fn waiting(listener: &mut EventNotices) -> u64 {
    let mut taken = 0;
    while listener.try_next().is_some() {
        taken += 1;
    }
    taken
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_thousand_reports_in_one_read_all_reach_a_listener_that_has_not_read_yet() {
    const REPORTS: usize = 2000;
    let (node, mut pipe) = listening_node().await;
    let mut listener = node.event_notices().await.unwrap();
    send_and_settle(&mut pipe, reports(REPORTS)).await;
    assert_eq!((waiting(&mut listener), listener.dropped()), (REPORTS as u64, 0));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_past_the_queue_is_counted_for_each_listener_that_lost_it() {
    const REPORTS: usize = 20_000;
    let (node, mut pipe) = listening_node().await;
    let (mut first, mut second) = (node.event_notices().await.unwrap(), node.event_notices().await.unwrap());
    send_and_settle(&mut pipe, reports(REPORTS)).await;
    let (first_dropped, second_dropped) = (first.dropped(), second.dropped());
    assert!(first_dropped > 0, "nobody read: the queue overflowed");
    assert_eq!(waiting(&mut first) + first_dropped, REPORTS as u64);
    assert_eq!(waiting(&mut second) + second_dropped, REPORTS as u64);
    let stats = bounded("stats", node.stats()).await.unwrap();
    assert_eq!(stats.event_notices_dropped, first_dropped + second_dropped);
}
