//! Memory Configuration between two `Node`s through a `Hub` on 127.0.0.1: a server's
//! spaces read, written and upgraded by stream and by datagrams, with progress and the
//! server's events.

mod common;

use common::bounded;
use openlcb_tokio::openlcb_node::MemoryError;
use openlcb_tokio::{
    Error, Framing, Hub, HubOptions, MemoryEvent, MemoryServer, Node, NodeId, NodeOptions, RamSpace, TransferPath,
};

fn data(len: usize, key: u8) -> Vec<u8> {
    (0..len).map(|i| (i as u8).wrapping_mul(31).wrapping_add(key) ^ (i >> 8) as u8).collect()
}

async fn pair(protocol: Framing) -> (Hub, Node, Node, openlcb_tokio::ServerEvents) {
    let hub = Hub::bind("127.0.0.1:0", Some("127.0.0.1:0"), HubOptions::default()).await.unwrap();
    let addr = match protocol {
        Framing::Tcp => hub.tcp_local_addr().unwrap().to_string(),
        _ => hub.local_addr().to_string(),
    };
    let server_id: NodeId = "05.01.01.01.22.D2".parse().unwrap();
    let server = Node::connect(&addr, protocol, NodeOptions::new(server_id)).await.unwrap();
    let spaces = MemoryServer::new()
        .with_space(0xFD, RamSpace::from_bytes(data(20_000, 1)))
        .with_space(0xEF, RamSpace::new(200_000))
        .with_acdi();
    let events = server.set_memory_server(spaces).await.unwrap();
    let client_id: NodeId = "05.01.01.01.22.D3".parse().unwrap();
    let client = Node::connect(&addr, protocol, NodeOptions::new(client_id)).await.unwrap();
    (hub, server, client, events)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_write_and_upgrade_by_stream_and_by_datagrams() {
    for protocol in [Framing::GridConnect, Framing::Tcp] {
        let (_hub, server, client, mut events) = pair(protocol).await;
        let peer = server.node_id();
        for path in [TransferPath::Stream, TransferPath::Datagrams, TransferPath::Auto] {
            let transfer = client.read_memory(peer, 0xFD, 0, None, path).await.unwrap();
            let progress = transfer.watch_progress();
            let read = bounded("read", transfer.finish()).await.unwrap();
            assert_eq!(read, data(20_000, 1), "{protocol:?} {path:?}");
            assert!(*progress.borrow() <= 20_000);

            let written = client.write_memory(peer, 0xFD, 100, data(3000, 7), path).await.unwrap();
            assert_eq!(bounded("write", written.finish()).await.unwrap(), 3000);
            let back = client.read_memory(peer, 0xFD, 100, Some(3000), path).await.unwrap();
            assert_eq!(bounded("read back", back.finish()).await.unwrap(), data(3000, 7));
            let restore = client.write_memory(peer, 0xFD, 100, data(20_000, 1)[100..3100].to_vec(), path);
            assert_eq!(bounded("restore", restore.await.unwrap().finish()).await.unwrap(), 3000);

            let image = data(100_000, 9);
            let upgrade = client.upgrade_firmware(peer, image.clone(), path).await.unwrap();
            let shown = upgrade.watch_progress();
            assert_eq!(bounded("upgrade", upgrade.finish()).await.unwrap(), 100_000);
            assert_eq!(*shown.borrow(), 100_000, "the progress ends at the whole image");
            let mut seen = Vec::new();
            while !matches!(seen.last(), Some(MemoryEvent::Unfrozen { .. })) {
                seen.push(bounded("server events", events.next()).await.unwrap());
            }
            assert!(seen.contains(&MemoryEvent::Frozen { by: client.node_id() }), "{seen:?}");
            assert_eq!(seen.last(), Some(&MemoryEvent::Unfrozen { by: client.node_id(), image_len: 100_000 }));
            let flashed = client.read_memory(peer, 0xEF, 0, Some(100_000), path).await.unwrap();
            assert_eq!(bounded("read the image", flashed.finish()).await.unwrap(), image, "{protocol:?} {path:?}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn errors_are_typed() {
    let (_hub, server, client, _events) = pair(Framing::GridConnect).await;
    let peer = server.node_id();
    let unknown = client.read_memory(peer, 0x42, 0, Some(10), TransferPath::Datagrams).await.unwrap();
    let error = bounded("unknown space", unknown.finish()).await.unwrap_err();
    assert!(matches!(error, Error::Memory { error: MemoryError::Rejected(_) | MemoryError::Failed(_), .. }), "{error}");
    let past = client.read_memory(peer, 0xFD, 30_000, Some(10), TransferPath::Datagrams).await.unwrap();
    let error = bounded("past the end", past.finish()).await.unwrap_err();
    assert!(matches!(error, Error::Memory { error: MemoryError::Failed(_), .. }), "{error}");
    let itself = client.read_memory(client.node_id(), 0xFD, 0, None, TransferPath::Auto).await.unwrap();
    assert!(matches!(bounded("self", itself.finish()).await, Err(Error::MemoryRequest(_))));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn own_snip_carries_the_user_name_a_tool_wrote() {
    let (_hub, server, client, mut events) = pair(Framing::GridConnect).await;
    assert_eq!(server.own_snip().await.unwrap().user_name, "");
    // Space 0xFB: the layout's version byte, then the user name (NUL-terminated).
    let write = client.write_memory(server.node_id(), 0xFB, 1, b"Yard 7\0".to_vec(), TransferPath::Datagrams);
    assert_eq!(bounded("write the name", write.await.unwrap().finish()).await.unwrap(), 7);
    assert_eq!(bounded("the server's event", events.next()).await, Some(MemoryEvent::UserInfoChanged));
    let own = server.own_snip().await.unwrap();
    assert_eq!((own.user_name.as_str(), own.user_description.as_str()), ("Yard 7", ""));
}
