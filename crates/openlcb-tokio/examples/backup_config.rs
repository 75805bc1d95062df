//! Memory Configuration from a program: a node that serves 256 bytes of configuration (space
//! 0xFD) and a tool node that writes part of it, then backs the whole space up, through a hub
//! on 127.0.0.1. The README's "Use it from your Rust program" shows the tool's half.
//!
//! `cargo run -p openlcb-tokio --example backup_config`

use openlcb_tokio::{Error, Framing, Hub, HubOptions, MemoryServer, Node, NodeId, NodeOptions, RamSpace, TransferPath};

#[tokio::main]
async fn main() -> Result<(), Error> {
    run().await
}

/// The write and the backup through a hub of its own.
async fn run() -> Result<(), Error> {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await?;
    let addr = hub.local_addr().to_string();
    // The configured node: space 0xFD in memory.
    let board_id: NodeId = "05.01.01.01.22.E0".parse().expect("a valid Node ID");
    let board = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(board_id)).await?;
    let _events = board.set_memory_server(MemoryServer::new().with_space(0xFD, RamSpace::new(256))).await?;

    // The tool: write 4 bytes at address 16, then read the whole space back.
    let tool_id: NodeId = "05.01.01.01.22.E1".parse().expect("a valid Node ID");
    let tool = Node::connect(&addr, Framing::GridConnect, NodeOptions::new(tool_id)).await?;
    let written = tool.write_memory(board_id, 0xFD, 16, vec![1, 2, 3, 4], TransferPath::Auto).await?;
    written.finish().await?;
    let backup = tool.read_memory(board_id, 0xFD, 0, None, TransferPath::Auto).await?.finish().await?;
    assert_eq!(backup.len(), 256);
    assert_eq!(&backup[16..20], &[1, 2, 3, 4]);
    println!("backed up {} bytes of space 0xFD from {board_id}", backup.len());
    tool.close().await;
    board.close().await;
    Ok(())
}

/// `cargo test` runs the example (`test = true` in Cargo.toml).
#[tokio::test]
async fn backs_up_what_it_wrote() {
    run().await.unwrap();
}
