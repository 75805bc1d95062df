//! A hub and two nodes on 127.0.0.1, nothing else needed: the receiver accepts one stream and
//! reads it to the end, the sender opens it and writes 1 MB through real sockets. Pass a hub's
//! address (`HOST:PORT`, GridConnect) to use that hub instead of starting one.
//!
//! `cargo run -p openlcb-tokio --example send_and_receive [-- HOST:PORT]`

use openlcb_tokio::{Error, Framing, Hub, HubOptions, Node, NodeId, NodeOptions, OpenOptions};

const LEN: usize = 1_000_000;

#[tokio::main]
async fn main() -> Result<(), Error> {
    run(std::env::args().nth(1)).await
}

/// The transfer through the hub at `hub_addr`, or through a hub of its own.
async fn run(hub_addr: Option<String>) -> Result<(), Error> {
    // Our own hub on an ephemeral port, unless told where one is; kept alive to the end.
    let (_hub, addr) = match hub_addr {
        Some(addr) => (None, addr),
        None => {
            let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await?;
            let addr = hub.local_addr().to_string();
            println!("hub listening on {addr}");
            (Some(hub), addr)
        }
    };
    let receiver_id: NodeId = "05.01.01.01.22.F1".parse().expect("a valid Node ID");
    let sender_id: NodeId = "05.01.01.01.22.F0".parse().expect("a valid Node ID");
    let mut receiver = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(receiver_id)).await?;
    let sender = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(sender_id)).await?;
    println!("{receiver_id} and {sender_id} logged in");

    let data: Vec<u8> = (0..LEN).map(|i| (i % 253) as u8).collect();
    let send = async {
        let mut stream = sender.open(OpenOptions::new(receiver_id, 2048)).await?;
        println!("stream open, window {}", stream.info().window);
        stream.write_all(data.clone()).await?;
        stream.finish().await
    };
    let receive = async {
        let mut stream = receiver.accept().await?;
        let mut received = Vec::with_capacity(LEN);
        while let Some(chunk) = stream.read().await? {
            received.extend_from_slice(&chunk);
        }
        Ok::<_, Error>(received)
    };
    let (sent, received) = tokio::try_join!(send, receive)?;
    assert_eq!(sent, LEN as u64);
    assert_eq!(received, data, "the data arrived changed");
    println!("{sent} bytes sent and received, verified");
    sender.close().await;
    receiver.close().await;
    Ok(())
}

/// `cargo test` runs the example against its own hub (`test = true` in Cargo.toml).
#[tokio::test]
async fn moves_a_stream_through_its_own_hub() {
    run(None).await.expect("the transfer");
}
