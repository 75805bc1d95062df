//! A complete LCC board on tokio: an 8-line I/O board. Its configuration is declared once
//! (the kit, `openlcb_node::board`): a name, and per line a name, a mode and two events. The
//! CDI and the addresses come from that; the settings live in a file (`FileSpace`), served by
//! Memory Configuration and shared with the board (`SharedSpace`); space 0xEF takes a firmware
//! upgrade. Input lines produce their
//! events, output lines consume theirs, always as the configuration holds them: a tool's
//! change takes effect at its Update Complete, and a Factory Reset writes the defaults.
//!
//! `cargo run -p openlcb-tokio --example io_board -- HUB:PORT [CONFIG_FILE]` runs the board
//! until Ctrl-C (typing `3` produces line 3's event On, `-3` its Off). With no argument it
//! shows itself: a hub, the board and a tool on 127.0.0.1, the tool setting line 1's event and
//! driving line 5 (what `cargo test` runs).

use openlcb_tokio::openlcb_node::board::{Board, BoardBuilder, EventRole, EventSetting, IntSetting, StringSetting};
use openlcb_tokio::{
    EventId, EventNotice, EventRole as Role, FileSpace, Framing, Hub, HubOptions, MemoryEvent, MemoryServer, Node,
    NodeCommand, NodeId, NodeOptions, RamSpace, ReadOnlySpace, SharedSpace, SnipInfo, TransferPath,
};

/// What the example's functions fail with.
type Failure = Box<dyn std::error::Error + Send + Sync>;

/// The firmware space (0xEF) a firmware upgrade writes.
const FIRMWARE_SPACE: u32 = 128 * 1024;

/// One I/O line's settings.
#[allow(dead_code)] // `name` and `mode` are settings for the tools; the board does not read them.
struct Line {
    name: StringSetting,
    mode: IntSetting,
    on: EventSetting,
    off: EventSetting,
}

/// The board's configuration: lines 1-4 inputs (they produce), 5-8 outputs (they consume);
/// the factory events are the Node ID's, two a line.
fn declare(node: NodeId) -> (Board, Vec<Line>) {
    let mut config = BoardBuilder::new("I/O board");
    config.string("Board name", 32, "");
    let base = node.as_raw() << 16;
    let lines = config.group("Line", 8, |g, i| {
        let (role, mode) = if i < 4 { (EventRole::Produced, 0) } else { (EventRole::Consumed, 1) };
        Line {
            name: g.string("Name", 16, ""),
            mode: g.int("Mode", 1, mode, &[(0, "Input"), (1, "Output")]),
            on: g.event("Event On", role, EventId(base | u64::from(2 * i))),
            off: g.event("Event Off", role, EventId(base | u64::from(2 * i + 1))),
        }
    });
    let snip =
        SnipInfo { manufacturer: "openlcb-stream".into(), model: "io_board example".into(), ..SnipInfo::default() };
    (config.finish(&snip), lines)
}

/// Runs the board at `addr` with its settings in `path` until `stop`; returns what its
/// outputs did (`line 5 on`, ...).
async fn board(
    addr: &str,
    node: NodeId,
    path: &str,
    stop: tokio::sync::oneshot::Receiver<()>,
) -> Result<Vec<String>, Failure> {
    let (board, lines) = declare(node);
    let (file, new) = FileSpace::open_or_create(path, board.len())?;
    let mut space = SharedSpace::new(file);
    if new {
        board.factory_reset(&mut space)?;
    }
    let mut options = NodeOptions::new(node);
    options.node.events = board.events(&mut space);
    let bus = Node::connect(addr, Framing::GridConnect, options).await?;
    let server = MemoryServer::new()
        .with_space(0xFF, ReadOnlySpace::cdi(board.cdi()))
        .with_space(0xFD, space.clone())
        .with_space(0xEF, RamSpace::new(FIRMWARE_SPACE))
        .with_acdi();
    let mut asked = bus.set_memory_server(server).await?;
    let mut reports = bus.event_notices().await?;
    let mut keys = keys();
    let (mut outputs, mut stop) = (Vec::new(), stop);
    loop {
        tokio::select! {
            Some(event) = asked.next() => match event {
                // A tool finished writing: the events are what the settings hold now.
                MemoryEvent::UpdateComplete { .. } => bus.set_events(board.events(&mut space)).await?,
                // A real board writes the image to flash here and resets into it.
                MemoryEvent::Unfrozen { image_len, .. } => println!("firmware image of {image_len} bytes received"),
                MemoryEvent::FactoryResetRequested { .. } => {
                    board.factory_reset(&mut space)?;
                    bus.set_events(board.events(&mut space)).await?;
                }
                _ => {}
            },
            Some(EventNotice::Report { event, .. }) = reports.next() => {
                for (i, line) in lines.iter().enumerate().skip(4) {
                    let state = if line.on.read(&mut space).ok() == Some(event) { "on" } else if line.off.read(&mut space).ok() == Some(event) { "off" } else { continue };
                    println!("line {} {state}", i + 1);
                    outputs.push(format!("line {} {state}", i + 1));
                }
            }
            Some(key) = keys.recv() => {
                let (number, on) = key.trim().strip_prefix('-').map_or((key.trim(), true), |n| (n, false));
                if let Some(line) = number.parse::<usize>().ok().and_then(|n| lines.get(n.wrapping_sub(1))) {
                    let setting = if on { line.on } else { line.off };
                    bus.send_event(setting.read(&mut space)?, Vec::new()).await?;
                }
            }
            _ = &mut stop => break,
        }
    }
    bus.close().await;
    Ok(outputs)
}

/// The board shown on a hub of its own: a tool sets line 1's Event On, says Update Complete,
/// finds the board producing the new event, and drives output line 5.
async fn demo() -> Result<(), Failure> {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await?;
    let addr = hub.local_addr().to_string();
    let node: NodeId = "05.01.01.01.22.B0".parse().expect("a Node ID");
    let path = std::env::temp_dir().join(format!("io-board-{}.bin", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let (stop, stopped) = tokio::sync::oneshot::channel();
    let running = tokio::spawn({
        let (addr, path) = (addr.clone(), path.to_string_lossy().into_owned());
        async move { board(&addr, node, &path, stopped).await }
    });
    let mut options = NodeOptions::new("05.01.01.01.22.B1".parse().expect("a Node ID"));
    options.node.events.listen = openlcb_tokio::Listen::Everything;
    let tool = Node::connect(&addr, Framing::GridConnect, options).await?;
    let mut seen = tool.event_notices().await?;
    tokio::time::sleep(std::time::Duration::from_millis(500)).await; // the board logs in
    let (_, lines) = declare(node);
    let new = EventId(0x0501_0101_22B1_0001);
    tool.write_memory(node, 0xFD, lines[0].on.address(), new.to_bytes().to_vec(), TransferPath::Datagrams)
        .await?
        .finish()
        .await?;
    tool.send_command(node, NodeCommand::UpdateComplete).await?.finish().await?;
    tool.identify(Role::Producer, new).await?;
    loop {
        if let Some(EventNotice::Identified { from, range, .. }) = seen.next().await
            && from == node
            && range.first() == new
        {
            break;
        }
    }
    println!("the board now produces {new} for line 1");
    let line5 = EventId((node.as_raw() << 16) | 8);
    tool.send_event(line5, Vec::new()).await?;
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    let _ = stop.send(());
    let outputs = running.await??;
    assert_eq!(outputs, ["line 5 on"]);
    tool.close().await;
    let _ = std::fs::remove_file(&path);
    Ok(())
}

#[tokio::main]
async fn main() -> Result<(), Failure> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(addr) = args.first() else { return demo().await };
    let path = args.get(1).map_or("io-board-config.bin", String::as_str);
    let (stop, stopped) = tokio::sync::oneshot::channel();
    tokio::spawn(async move {
        let _ = tokio::signal::ctrl_c().await;
        let _ = stop.send(());
    });
    board(addr, "05.01.01.01.22.B0".parse().expect("a Node ID"), path, stopped).await.map(|_| ())
}

/// Lines typed on stdin, read by a thread of their own (the runtime's would hold the exit).
fn keys() -> tokio::sync::mpsc::Receiver<String> {
    let (sink, keys) = tokio::sync::mpsc::channel(16);
    std::thread::spawn(move || {
        for line in std::io::stdin().lines().map_while(Result::ok) {
            if sink.blocking_send(line).is_err() {
                break;
            }
        }
    });
    keys
}

/// `cargo test` runs the example (`test = true` in Cargo.toml).
#[tokio::test]
async fn the_board_follows_its_configuration_and_drives_its_outputs() {
    tokio::time::timeout(std::time::Duration::from_secs(60), demo()).await.expect("within a minute").unwrap();
}
