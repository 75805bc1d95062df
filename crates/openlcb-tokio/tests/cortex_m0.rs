//! The Cortex-M0 I/O board (`examples/cortex-m0`) under QEMU, on a bus this test drives: a
//! hub the firmware's UART joins through a bridge (binary frames on the UART, GridConnect on
//! the hub), a raw tap that records every frame, and a tool node. It checks, in order: the
//! board's alias login on the wire (four CIDs carrying its Node ID, RID 200 ms (on the first
//! login) after the last, AMD, Initialization Complete) and its answer to a duplicate-alias
//! check; Lock, Write Under Mask and both stream commands refused (the board is built
//! without them); its CDI (which it renders on each
//! read) read whole by datagrams and parsed, each line's settings where it keeps them;
//! Identify Events answered from its configuration; a configuration write by datagrams read
//! back; Update Complete making the new Event ID the one it answers for; an event its output
//! line consumes; a firmware image written into space 0xEF and read back; a Reboot (a real
//! reset: it logs in again, and the configuration it got survives in flash). Before the
//! Reboot it measures the RAM the run used, in a copy taken through QEMU's monitor, and
//! prints it (`ram: ...`).
//!
//! It needs `qemu-system-arm` and the firmware, so it is ignored by `cargo test`; `.ci/run`
//! runs it through `.ci/firmware-m0`:
//!
//! ```text
//! OPENLCB_M0_FIRMWARE=/tmp/openlcb-size-report/examples/cortex-m0/target/thumbv6m-none-eabi/release/io-board \
//!     cargo test -p openlcb-tokio --test cortex_m0 -- --ignored --nocapture
//! ```

mod common;

use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::bounded;
use openlcb_tokio::openlcb_can::embedded_can::Frame as _;
use openlcb_tokio::openlcb_can::{CanFrame, GridConnectDecoder, gridconnect};
use openlcb_tokio::{
    EventId, EventNotice, EventRole, Framing, Hub, HubOptions, Listen, Node, NodeCommand, NodeId, NodeOptions,
    Protocols, TransferPath,
};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::OwnedWriteHalf;
use tokio::process::{Child, Command};

/// The board's Node ID (`examples/cortex-m0/src/main.rs`).
const BOARD: u64 = 0x05_01_01_01_22_D0;
/// Bytes of the configuration before line 1's settings: the board name.
const NAME_LEN: u32 = 16;
/// Bytes of one line's settings: name (8), mode (1), Event On (8), Event Off (8).
const LINE_LEN: u32 = 8 + 1 + 8 + 8;

/// The address of line `line`'s (0-based) Event On.
fn event_on_address(line: u32) -> u32 {
    NAME_LEN + line * LINE_LEN + 9
}

/// A line's factory event: the Node ID's, two a line.
fn factory_event(line: u32, off: bool) -> EventId {
    EventId(BOARD << 16 | u64::from(2 * line + u32::from(off)))
}

/// Every frame seen on the hub, with when it was seen.
#[derive(Default)]
struct Tap {
    frames: Vec<(std::time::Instant, CanFrame)>,
}

/// What QEMU's console (the firmware's semihosting) printed.
#[derive(Default)]
struct Console {
    lines: Vec<String>,
}

/// Waits for `check`; fails at once if the firmware reported a failure (it has stopped).
async fn until(what: &str, console: &Mutex<Console>, mut check: impl FnMut() -> bool) {
    bounded(what, async {
        while !check() {
            if let Some(failure) = console.lock().unwrap().lines.iter().find(|l| l.starts_with("FAIL")) {
                panic!("the firmware failed while waiting for {what}: {failure}");
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
}

fn firmware() -> String {
    std::env::var("OPENLCB_M0_FIRMWARE").expect("OPENLCB_M0_FIRMWARE names the firmware ELF (see the module docs)")
}

/// Starts the firmware under QEMU, its UART a client of `uart` (see [`start_uart_bridge`]),
/// its console lines into `console`, its QMP monitor on the Unix socket `qmp`.
fn start_qemu(uart: std::net::SocketAddr, qmp: &std::path::Path, console: Arc<Mutex<Console>>) -> Child {
    let mut qemu = Command::new("qemu-system-arm")
        .args(["-machine", "microbit", "-display", "none", "-monitor", "none"])
        .arg("-qmp")
        .arg(format!("unix:{},server=on,wait=off", qmp.display()))
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-serial")
        .arg(format!("tcp:{uart}"))
        .arg("-kernel")
        .arg(firmware())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("qemu-system-arm runs");
    let stdout = qemu.stdout.take().expect("piped");
    tokio::spawn(async move {
        let mut lines = BufReader::new(stdout).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            println!("board: {line}");
            console.lock().unwrap().lines.push(line);
        }
    });
    qemu
}

/// Where the nRF51's RAM starts.
const RAM_START: u32 = 0x2000_0000;
/// The word the firmware paints its free RAM with at start-up (`examples/cortex-m0/src/ram.rs`).
const PAINT: u32 = 0x5A5A_A5A5;

/// What the board's RAM shows: static data up to the painted stack's floor, the deepest the
/// stack went since start-up (down to the first word that lost its paint), and the heap's
/// high-water mark, from a copy of the RAM taken through QEMU's monitor (QMP) while it runs.
/// `layout` is the board's `ram layout: FLOOR TOP PEAK` line (addresses in decimal).
async fn measure_ram(qmp: &std::path::Path, layout: &str) -> String {
    let numbers: Vec<u32> = layout.split_whitespace().filter_map(|word| word.parse().ok()).collect();
    let [floor, top, peak] = numbers[..] else { panic!("not a layout: {layout:?}") };
    let copy = qmp.with_extension("ram");
    let socket = tokio::net::UnixStream::connect(qmp).await.expect("QEMU's QMP socket");
    let (read, mut write) = socket.into_split();
    let mut lines = BufReader::new(read).lines();
    // The greeting, then each command's answer (events in between are skipped).
    let mut answer = async || loop {
        let line = lines.next_line().await.expect("QMP reads").expect("QMP stays open");
        if line.contains("\"return\"") || line.contains("\"error\"") || line.contains("\"QMP\"") {
            return line;
        }
    };
    bounded("QMP's greeting", answer()).await;
    let memsave = format!("memsave {RAM_START} {} \\\"{}\\\"", top - RAM_START, copy.display());
    for command in [
        r#"{"execute": "qmp_capabilities"}"#.to_string(),
        format!(r#"{{"execute": "human-monitor-command", "arguments": {{"command-line": "{memsave}"}}}}"#),
    ] {
        write.write_all(format!("{command}\n").as_bytes()).await.unwrap();
        let reply = bounded("QMP's answer", answer()).await;
        assert!(reply.contains("\"return\""), "QMP refused {command}: {reply}");
    }
    let ram = std::fs::read(&copy).expect("QEMU saved the RAM");
    let _ = std::fs::remove_file(&copy);
    let word = |address: u32| {
        let at = (address - RAM_START) as usize;
        u32::from_le_bytes(ram[at..at + 4].try_into().unwrap())
    };
    let deepest = (floor..top).step_by(4).find(|address| word(*address) != PAINT).unwrap_or(top);
    let (statics, stack) = (floor - RAM_START, top - deepest);
    format!("ram: static {statics} B + stack {stack} B = {} B; heap peak {} B", statics + stack, word(peak))
}

/// The first byte of a frame on the board's UART, plus its data length
/// (`examples/cortex-m0/src/serial_can.rs`).
const UART_START: u8 = 0xC0;

/// Bridges the board's UART to `hub`: listens for QEMU's serial port on an ephemeral port
/// (returned) and carries each binary frame it sends to the hub as GridConnect, and each
/// frame of the hub back to it in binary. A byte that cannot start a frame ends the bridge
/// (the firmware never sends one).
async fn start_uart_bridge(hub: std::net::SocketAddr) -> std::net::SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("a port for QEMU's UART");
    let uart_addr = listener.local_addr().expect("bound");
    let (mut hub_in, mut hub_out) = TcpStream::connect(hub).await.expect("the hub listens").into_split();
    tokio::spawn(async move {
        let Ok((uart, _)) = listener.accept().await else { return };
        let (mut uart_in, mut uart_out) = uart.into_split();
        tokio::spawn(async move {
            let (mut decoder, mut buf) = (GridConnectDecoder::new(), [0u8; 512]);
            while let Ok(n @ 1..) = hub_in.read(&mut buf).await {
                let mut input = &buf[..n];
                while let Some(result) = decoder.decode(&mut input) {
                    let Ok(frame) = result else { continue };
                    let mut bytes = vec![UART_START + frame.data().len() as u8];
                    bytes.extend(frame.raw_id().to_be_bytes());
                    bytes.extend(frame.data());
                    if uart_out.write_all(&bytes).await.is_err() {
                        return;
                    }
                }
            }
        });
        let mut start = [0u8; 1];
        while uart_in.read_exact(&mut start).await.is_ok() && (UART_START..=UART_START + 8).contains(&start[0]) {
            let mut rest = vec![0u8; 4 + usize::from(start[0] - UART_START)];
            if uart_in.read_exact(&mut rest).await.is_err() {
                return;
            }
            let id = u32::from_be_bytes([rest[0], rest[1], rest[2], rest[3]]);
            let frame = CanFrame::extended(id, &rest[4..]).expect("a frame of at most 8 bytes");
            let mut text = [0u8; 32];
            let len = gridconnect::encode(&frame, &mut text).expect("room for one frame");
            if hub_out.write_all(&text[..len]).await.is_err() {
                return;
            }
        }
    });
    uart_addr
}

/// Connects a raw GridConnect client to the hub, recording every frame into `tap`; returns
/// its sending half.
async fn start_tap(hub: std::net::SocketAddr, tap: Arc<Mutex<Tap>>) -> OwnedWriteHalf {
    let stream = TcpStream::connect(hub).await.expect("the hub listens");
    let (mut read, write) = stream.into_split();
    tokio::spawn(async move {
        let (mut decoder, mut buf) = (GridConnectDecoder::new(), [0u8; 512]);
        while let Ok(n @ 1..) = read.read(&mut buf).await {
            let mut input = &buf[..n];
            while let Some(result) = decoder.decode(&mut input) {
                if let Ok(frame) = result {
                    tap.lock().unwrap().frames.push((std::time::Instant::now(), frame));
                }
            }
        }
    });
    write
}

/// The 12-bit alias in a frame's identifier.
fn alias_of(frame: &CanFrame) -> u32 {
    frame.raw_id() & 0xFFF
}

/// The board's `n`-th alias login (0-based) in `tap`, checked frame by frame: four CIDs
/// carrying its Node ID 12 bits at a time, under one alias; RID 200 ms after
/// the last CID; AMD and Initialization Complete with its Node ID. Returns the alias.
fn login(tap: &Tap, n: usize) -> Option<u32> {
    let node = BOARD.to_be_bytes()[2..].to_vec();
    let is_cid = |frame: &CanFrame, k: u32| {
        let id = frame.raw_id();
        id >> 24 == 0x17 - k && (id >> 12) & 0xFFF == ((BOARD >> (36 - 12 * k)) & 0xFFF) as u32
    };
    let starts: Vec<usize> = (0..tap.frames.len().saturating_sub(3))
        .filter(|&i| (0..4).all(|k| is_cid(&tap.frames[i + k as usize].1, k)))
        .collect();
    let start = *starts.get(n)?;
    let alias = alias_of(&tap.frames[start].1);
    assert!((1..4).all(|k| alias_of(&tap.frames[start + k].1) == alias), "the CIDs of one login share an alias");
    let last_cid = tap.frames[start + 3].0;
    let mine = |id: u32| tap.frames[start + 4..].iter().find(|(_, f)| f.raw_id() == id | alias);
    let (rid_at, _) = mine(0x1070_0000)?;
    // The tap stamps frames as the hub relays them, late and not always by the same amount
    // (up to 15 ms seen on a busy machine): 180 ms seen stands for the 200 ms the firmware
    // waits from handing its CIDs to the UART (a RID sent with no wait, or well short of it,
    // still fails; `openlcb-embedded`'s tests check that the wait counts from the CIDs sent,
    // not from when they were queued). Only the first login is timed: after QEMU's system
    // reset the CIDs reach the hub late, in one burst (their stamps a microsecond apart), so
    // the gap seen is shorter than the board's.
    assert!(
        n > 0 || *rid_at - last_cid >= Duration::from_millis(180),
        "RID sent {:?} after the last CID",
        *rid_at - last_cid
    );
    let (_, amd) = mine(0x1070_1000)?;
    assert_eq!(amd.data(), node, "AMD carries the Node ID");
    let (_, init) = mine(0x1910_0000)?;
    assert_eq!(init.data(), node, "Initialization Complete carries the Node ID");
    if n == 0 {
        println!("login: RID {:?} after the last CID, as the tap saw them", *rid_at - last_cid);
    }
    Some(alias)
}

/// Waits up to `wait` for the board to identify `event` in `role`.
async fn identified(
    notices: &mut openlcb_tokio::EventNotices,
    role: EventRole,
    event: EventId,
    wait: Duration,
) -> bool {
    let board = NodeId::new(BOARD).unwrap();
    tokio::time::timeout(wait, async {
        loop {
            match notices.next().await {
                Some(EventNotice::Identified { from, role: r, range, .. })
                    if from == board && r == role && range.first() == event =>
                {
                    return;
                }
                Some(_) => {}
                None => std::future::pending().await,
            }
        }
    })
    .await
    .is_ok()
}

fn printed(console: &Mutex<Console>, line: &str) -> usize {
    console.lock().unwrap().lines.iter().filter(|l| l.as_str() == line).count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs qemu-system-arm and the Cortex-M0 firmware: .ci/firmware-m0 runs it"]
async fn io_board_on_a_cortex_m0() {
    let board = NodeId::new(BOARD).unwrap();
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.expect("a hub");
    let addr = hub.local_addr();
    let tap = Arc::new(Mutex::new(Tap::default()));
    let mut tap_out = start_tap(addr, tap.clone()).await;
    let mut options = NodeOptions::new(NodeId::new(0x05_01_01_01_22_D1).unwrap());
    options.node.events.listen = Listen::Everything;
    let tool = Node::connect(&addr.to_string(), Framing::GridConnect, options).await.expect("the tool joins");
    let mut notices = tool.event_notices().await.expect("event notices");
    let console = Arc::new(Mutex::new(Console::default()));
    let qmp = std::env::temp_dir().join(format!("openlcb-m0-qmp-{}.sock", std::process::id()));
    let _ = std::fs::remove_file(&qmp);
    let mut qemu = start_qemu(start_uart_bridge(addr).await, &qmp, console.clone());

    // The alias login on the wire, then a duplicate-alias check: another node's CID with the
    // board's alias must get a RID from it.
    until("the board's alias login", &console, || login(&tap.lock().unwrap(), 0).is_some()).await;
    let alias = login(&tap.lock().unwrap(), 0).unwrap();
    println!("logged in as alias {alias:03X}");
    let seen = tap.lock().unwrap().frames.len();
    tap_out.write_all(format!(":X17ABC{alias:03X}N;").as_bytes()).await.unwrap();
    until("the board's RID to a CID with its alias", &console, || {
        tap.lock().unwrap().frames[seen..].iter().any(|(_, f)| f.raw_id() == 0x1070_0000 | alias)
    })
    .await;

    // Commands the board is built without, each sent in one frame by a tap that announced an
    // alias, each answered with Datagram Rejected, 0x1041 (unknown command): Lock/Reserve and
    // Write Under Mask (`openlcb-node`'s `optional-commands` feature; OpenMRN's nodes have
    // neither), Write Stream and Read Stream (its `streams` feature).
    tap_out.write_all(b":X107015A5N0501010122D2;").await.unwrap();
    for (name, command) in [
        ("Lock", "20880501010122D2"),
        ("Write Under Mask", "200900000000FF00"),
        ("Write Stream", "20210000000004"),
        ("Read Stream", "206100000000FF04"),
    ] {
        let seen = tap.lock().unwrap().frames.len();
        tap_out.write_all(format!(":X1A{alias:03X}5A5N{command};").as_bytes()).await.unwrap();
        until(&format!("the board's rejection of {name}"), &console, || {
            tap.lock().unwrap().frames[seen..]
                .iter()
                .any(|(_, f)| f.raw_id() == 0x19A4_8000 | alias && f.data() == [0x05, 0xA5, 0x10, 0x41])
        })
        .await;
        println!("{name}: :X1A{alias:03X}5A5N{command}; rejected with :X19A48{alias:03X}N05A51041;");
    }

    // Its PIP: what an I/O board serves, and no streams (the firmware is built without them).
    let protocols =
        tool.protocols(board, Duration::from_secs(5)).await.expect("the board answers Protocol Support Inquiry");
    println!("protocols: {protocols:?}");
    for needed in [
        Protocols::DATAGRAM,
        Protocols::MEMORY_CONFIGURATION,
        Protocols::EVENT_EXCHANGE,
        Protocols::SIMPLE_NODE_INFORMATION,
        Protocols::CDI,
        Protocols::FIRMWARE_UPGRADE,
    ] {
        assert!(protocols.contains(needed), "the board announces {needed:?}");
    }
    assert!(!protocols.contains(Protocols::STREAM), "a board built without streams announces none");

    // Its SNIP: answered by a node built without `snip-client` (it asks nobody for theirs).
    let snip = bounded("the SNIP", tool.snip(board)).await.expect("the board answers SNIP");
    println!("snip: {} {}", snip.manufacturer, snip.model);
    assert_eq!((snip.manufacturer.as_str(), snip.model.as_str()), ("openlcb-stream", "Cortex-M0 I/O board"));

    // A datagram that is not Memory Configuration's (content ID 0x30), from a sender known
    // only by its alias: rejected at once as of an unknown type (0x1042), as a board built
    // without `app-datagrams` claims no content ID.
    let sender = 0x5A5;
    assert_ne!(tool.alias_of(tool.node_id()).await.unwrap(), Some(sender as u16), "the tap's alias is free");
    let seen = tap.lock().unwrap().frames.len();
    tap_out.write_all(format!(":X1A{alias:03X}{sender:03X}N3001;").as_bytes()).await.unwrap();
    until("the board's Datagram Rejected", &console, || {
        tap.lock().unwrap().frames[seen..]
            .iter()
            .any(|(_, f)| f.raw_id() == 0x19A4_8000 | alias && f.payload() == [0x05, 0xA5, 0x10, 0x42])
    })
    .await;

    // The CDI, which the board renders on each read from its declaration (it keeps no copy):
    // read whole by datagrams, it parses, and a tool finds each line's settings where the
    // board keeps them.
    let cdi = bounded("the CDI", async {
        tool.read_memory(board, 0xFF, 0, None, TransferPath::Datagrams).await?.finish().await
    })
    .await
    .expect("the board serves its CDI");
    assert_eq!(cdi.last(), Some(&0), "the CDI ends with its NUL");
    let text = std::str::from_utf8(&cdi[..cdi.len() - 1]).expect("the CDI is UTF-8");
    let layout = openlcb_cdi::Layout::parse(text).expect("the CDI parses");
    for line in 0..8 {
        let key = format!("I/O board.Line({line}).Event On");
        let entry = layout.find(&key).next().unwrap_or_else(|| panic!("the CDI has {key}"));
        assert_eq!((entry.space, entry.address), (0xFD, event_on_address(line)), "{key}");
    }
    println!("CDI: {} bytes, read by datagrams", cdi.len());

    // Identify Events, answered from the configuration (the factory events).
    let wait = Duration::from_secs(5);
    assert!(
        identified(&mut notices, EventRole::Consumer, factory_event(4, false), wait).await || {
            tool.identify(EventRole::Consumer, factory_event(4, false)).await.unwrap();
            identified(&mut notices, EventRole::Consumer, factory_event(4, false), wait).await
        }
    );
    tool.identify(EventRole::Producer, factory_event(0, false)).await.unwrap();
    assert!(identified(&mut notices, EventRole::Producer, factory_event(0, false), wait).await);

    // A configuration write by datagrams, read back; Update Complete makes it the event.
    let new = EventId(0x0501_0101_22D1_0001);
    let address = event_on_address(0);
    let path = TransferPath::Datagrams;
    bounded("the write", async {
        tool.write_memory(board, 0xFD, address, new.to_bytes().to_vec(), path).await?.finish().await
    })
    .await
    .expect("the board takes the write");
    let back =
        bounded("the read", async { tool.read_memory(board, 0xFD, address, Some(8), path).await?.finish().await })
            .await
            .expect("the board answers the read");
    assert_eq!(back, new.to_bytes());
    bounded("Update Complete", async { tool.update_complete(board).await?.finish().await }).await.expect("OK");
    tool.identify(EventRole::Producer, new).await.unwrap();
    assert!(
        identified(&mut notices, EventRole::Producer, new, wait).await,
        "the board produces the event its configuration now holds"
    );
    tool.identify(EventRole::Producer, factory_event(0, false)).await.unwrap();
    assert!(!identified(&mut notices, EventRole::Producer, factory_event(0, false), Duration::from_secs(1)).await);

    // An output line acts on its event.
    tool.send_event(factory_event(4, false), Vec::new()).await.unwrap();
    until("line 5 on", &console, || printed(&console, "line 5 on") == 1).await;

    // A firmware image into space 0xEF (Freeze, write, Unfreeze), read back.
    let image: Vec<u8> = (0..20_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    let before_upgrade = tap.lock().unwrap().frames.len();
    let written = bounded("the upgrade", async {
        tool.upgrade_firmware(board, image.clone(), TransferPath::Auto).await?.finish().await
    })
    .await
    .expect("the upgrade succeeds");
    assert_eq!(written, image.len() as u64);
    until("the board's word on the image", &console, || printed(&console, "firmware image of 20000 bytes") == 1).await;
    // At its Unfreeze the board announces itself again (Initialization Complete); a read sent
    // before the tool has taken that would end as the board's restart. A round trip after it
    // on the wire shows that the tool has.
    until("the board's Initialization Complete after the upgrade", &console, || {
        tap.lock().unwrap().frames[before_upgrade..].iter().any(|(_, f)| f.raw_id() == 0x1910_0000 | alias)
    })
    .await;
    tool.protocols(board, Duration::from_secs(5)).await.expect("the board answers after its Unfreeze");
    let read = bounded("the image read back", async {
        tool.read_memory(board, 0xEF, 0, Some(image.len() as u32), TransferPath::Auto).await?.finish().await
    })
    .await
    .expect("the image reads back");
    assert!(read == image, "space 0xEF holds the image");

    // What the run used of the RAM, before the reset paints it again.
    let layout = console.lock().unwrap().lines.iter().find(|l| l.starts_with("ram layout: ")).cloned();
    let ram = measure_ram(&qmp, &layout.expect("the board prints its RAM layout at start-up")).await;
    println!("{ram}");

    // Reboot: a real reset. The board logs in again and its configuration survived.
    bounded("Reboot", async { tool.send_command(board, NodeCommand::Reboot).await?.finish().await })
        .await
        .expect("rebooted");
    until("the board's second login", &console, || login(&tap.lock().unwrap(), 1).is_some()).await;
    assert_eq!(printed(&console, "booted"), 2);
    // The board answers for its configured event (which also shows that the tool has taken
    // its Initialization Complete, sent before: a read started earlier would end as the
    // board's restart).
    tool.identify(EventRole::Producer, new).await.unwrap();
    assert!(identified(&mut notices, EventRole::Producer, new, wait).await);
    let back = bounded("the read after reboot", async {
        tool.read_memory(board, 0xFD, address, Some(8), path).await?.finish().await
    })
    .await
    .expect("the board answers after its reboot");
    assert_eq!(back, new.to_bytes(), "the configuration survived the reboot (flash)");

    let frames = tap.lock().unwrap().frames.len();
    println!("{frames} frames on the bus; {ram}");
    assert!(qemu.try_wait().unwrap().is_none(), "the firmware still runs");
    qemu.kill().await.unwrap();
    tool.close().await;
}
