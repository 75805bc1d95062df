//! One verified transfer, for the tests of links and CAN interfaces.

use openlcb_stream::OpenOptions;
use openlcb_tokio::{Error, Node};

use crate::common::bounded;

/// Sends `payload` from `sender` to `receiver` in one stream, which must arrive whole.
pub(crate) async fn moves(sender: &Node, receiver: &mut Node, payload: &[u8], window: u16) {
    let destination = receiver.node_id();
    let send = async {
        let mut stream = sender.open(OpenOptions::new(destination, window)).await?;
        for chunk in payload.chunks(64 * 1024) {
            stream.write_all(chunk.to_vec()).await?;
        }
        stream.finish().await
    };
    let receive = async {
        let mut stream = receiver.accept().await?;
        let mut received = Vec::new();
        while let Some(chunk) = stream.read().await? {
            received.extend_from_slice(&chunk);
        }
        Ok::<_, Error>(received)
    };
    let (sent, received) = bounded("a transfer", async { tokio::try_join!(send, receive) }).await.unwrap();
    assert_eq!(sent, payload.len() as u64);
    assert!(received == payload, "the data differs after {} bytes", received.len());
}
