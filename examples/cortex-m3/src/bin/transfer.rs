//! Two OpenLCB nodes on one Cortex-M3, source and destination, each an `openlcb_node::Node`
//! (streams, datagrams, SNIP, the message-network basics) and a `CanLink` behind the
//! `openlcb-embedded` driver, on an in-memory CAN bus. They log in, move
//! 64 KiB through a stream on virtual time, and every byte is checked as it is read. The
//! result goes out through semihosting; the exit status is 0 only if everything verified.
//!
//! ```text
//! cargo run --release --bin transfer    # runs it under qemu-system-arm (see .cargo/config.toml)
//! cargo run --release --bin transfer --features inject-mismatch    # must exit 1
//! cargo run --release --bin transfer --features inject-hardfault   # must exit 1
//! ```

#![no_std]
#![no_main]

use core::cell::Cell;
use core::fmt::Write as _;

use cortex_m_rt::entry;
use cortex_m_semihosting::hio;
use openlcb_can::{CanConfig, CanFrame, CanLink};
use openlcb_cortex_m3::{HEAP, HEAP_SIZE, exit, init_heap};
use openlcb_embedded::Driver;
use openlcb_embedded::memory_bus::MemoryBus;
use openlcb_node::{Node, NodeConfig, NodeEvent};
use openlcb_stream::{Event, Instant, NodeId, OpenOptions, StreamHandle};

const LEN: u64 = 64 * 1024;
const WINDOW: u16 = 2048;
/// Rounds of the loop before giving up (a transfer needs about 40 000).
const ROUND_LIMIT: u32 = 1_000_000;
/// Virtual time before giving up.
const TIME_LIMIT: Instant = Instant::from_secs(600);

/// The byte at `offset` of the test data (not periodic in any window size).
fn pattern(offset: u64) -> u8 {
    let x = offset.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    (x >> 56) as u8 ^ offset as u8
}

/// Heap in use, in bytes.
fn heap() -> usize {
    HEAP.used()
}

#[derive(Default)]
struct Report {
    rounds: u32,
    sent: u64,
    received: u64,
    mismatches: u64,
    first_mismatch: Option<u64>,
    finished: bool,
    matched: bool,
    unexpected_events: u32,
    heap_start: usize,
    heap_logged_in: usize,
    heap_after_open: usize,
    heap_opened: usize,
    heap_peak: usize,
    heap_end: usize,
    streams_left: usize,
    second_ok: bool,
    heap_end_second: usize,
}

#[entry]
fn main() -> ! {
    init_heap();
    let report = run();
    let ok = report.finished
        && report.matched
        && report.received == LEN
        && report.mismatches == 0
        && report.unexpected_events == 0
        && report.streams_left == 0
        && report.second_ok
        && report.heap_end_second == report.heap_end;
    print(&report, ok);
    exit(ok)
}

fn run() -> Report {
    let mut r = Report { heap_start: heap(), ..Report::default() };
    let (Some(a_id), Some(b_id)) = (NodeId::new(0x05_01_01_01_22_00), NodeId::new(0x05_01_01_01_22_01)) else {
        return r;
    };
    // Receive FIFOs of 3 frames, like a bxcan's: the source meets WouldBlock all the time.
    let bus: MemoryBus<CanFrame, 2, 3> = MemoryBus::new();
    let time = Cell::new(Instant::ZERO);
    let clock = || time.get();
    let (Some(port_a), Some(port_b)) = (bus.port(0), bus.port(1)) else {
        return r;
    };
    let mut a = Driver::new(port_a, clock, CanLink::new(time.get(), a_id, can_config()));
    let mut b = Driver::new(port_b, clock, CanLink::new(time.get(), b_id, can_config()));
    let mut source = Node::new(a_id, node_config());
    let mut destination = Node::new(b_id, node_config());

    let mut stream: Option<StreamHandle> = None;
    let mut opened = (false, false);
    let mut chunk = [0u8; 256];
    // The `inject-hardfault` feature proves that a fault fails the run.
    let fault_at = cfg!(feature = "inject-hardfault").then_some(LEN / 2);
    let mut buf = [0u8; 200];
    while !r.finished && r.rounds < ROUND_LIMIT && time.get() < TIME_LIMIT {
        r.rounds += 1;
        let (Ok(pa), Ok(pb)) = (a.poll(&mut source), b.poll(&mut destination)) else {
            r.unexpected_events += 1;
            break;
        };
        let mut worked = false;
        if stream.is_none() && a.link().alias().is_some() && b.link().alias().is_some() && pa.is_idle() && pb.is_idle()
        {
            r.heap_logged_in = heap();
            stream = source.streams_mut().open(time.get(), OpenOptions::new(b_id, WINDOW)).ok();
            r.heap_after_open = heap();
            worked = true;
        }
        while let Some(event) = source.poll_event() {
            match event {
                NodeEvent::Stream(Event::Opened { .. }) => opened.0 = true,
                NodeEvent::Stream(Event::Writable { .. } | Event::Sent { total: LEN, .. }) => {}
                _ => r.unexpected_events += 1,
            }
        }
        // Data goes out once the heap of the open stream was measured, both ends quiet.
        let measured = r.heap_opened != 0;
        if let Some(handle) =
            stream.filter(|h| measured && r.sent < LEN && source.streams().credit(*h).unwrap_or(0) > 0)
        {
            let n = chunk.len().min((LEN - r.sent) as usize);
            for (i, byte) in chunk.iter_mut().take(n).enumerate() {
                *byte = pattern(r.sent + i as u64);
            }
            let taken = source.streams_mut().write(time.get(), handle, chunk.get(..n).unwrap_or(&[])).unwrap_or(0);
            r.sent += taken as u64;
            if fault_at.is_some_and(|at| r.sent >= at) {
                cortex_m::asm::udf(); // undefined instruction: UsageFault, escalated to HardFault
            }
            if r.sent == LEN && source.streams_mut().finish(time.get(), handle).is_err() {
                r.unexpected_events += 1;
            }
            worked |= taken > 0;
        }
        while let Some(event) = destination.poll_event() {
            match event {
                NodeEvent::Stream(Event::Opened { .. }) => opened.1 = true,
                NodeEvent::Stream(Event::Readable { .. }) => {}
                NodeEvent::Stream(Event::Finished { total, matched, .. }) => {
                    r.finished = true;
                    r.matched = matched && total == LEN;
                }
                _ => r.unexpected_events += 1,
            }
        }
        let handles = destination.streams().handles().next();
        if let Some(handle) = handles {
            while let Ok(n @ 1..) = destination.streams_mut().read(time.get(), handle, &mut buf) {
                for (i, byte) in buf.iter().take(n).enumerate() {
                    let offset = r.received + i as u64;
                    // The `inject-mismatch` feature proves that a bad byte fails the run.
                    let expected = pattern(offset) ^ u8::from(cfg!(feature = "inject-mismatch") && offset == 40_000);
                    if *byte != expected {
                        r.mismatches += 1;
                        r.first_mismatch.get_or_insert(offset);
                    }
                }
                r.received += n as u64;
                worked = true;
            }
        }
        if opened == (true, true) && r.heap_opened == 0 && pa.is_idle() && pb.is_idle() {
            r.heap_opened = heap();
            worked = true;
        }
        r.heap_peak = r.heap_peak.max(heap());
        if !worked && pa.is_idle() && pb.is_idle() {
            // Both nodes are idle: sleep until the next deadline (on virtual time, jump there).
            match [pa.deadline, pb.deadline].into_iter().flatten().min() {
                Some(next) => time.set(next.max(time.get())),
                None => break,
            }
        }
    }
    // Let the last messages settle, then see what is left allocated.
    for _ in 0..8 {
        let _ = (a.poll(&mut source), b.poll(&mut destination));
        while source.poll_event().is_some() {}
        while destination.poll_event().is_some() {}
    }
    r.heap_end = heap();
    r.streams_left = source.streams().stream_count() + destination.streams().stream_count();
    // A second, empty stream: the heap must come back to the same level (no leak per stream).
    if let Ok(second) = source.streams_mut().open(time.get(), OpenOptions::new(b_id, WINDOW)) {
        let mut finished = false;
        for _ in 0..64 {
            let _ = (a.poll(&mut source), b.poll(&mut destination));
            while let Some(event) = source.poll_event() {
                if let NodeEvent::Stream(Event::Opened { .. }) = event {
                    let _ = source.streams_mut().finish(time.get(), second);
                }
            }
            while let Some(event) = destination.poll_event() {
                finished |= matches!(event, NodeEvent::Stream(Event::Finished { total: 0, .. }));
            }
            let handle = destination.streams().handles().next();
            if let Some(handle) = handle {
                let _ = destination.streams_mut().read(time.get(), handle, &mut buf);
            }
        }
        r.second_ok = finished && source.streams().stream_count() + destination.streams().stream_count() == 0;
    }
    r.heap_end_second = heap();
    let bus_stats = bus.stats();
    let mut out = Out;
    let _ = writeln!(
        out,
        "bus: {} frames, {} data bytes, {} WouldBlock; virtual time {} ms",
        bus_stats.frames,
        bus_stats.data_bytes,
        bus_stats.would_block,
        time.get().as_millis()
    );
    let (sa, sb) = (a.stats(), b.stats());
    let _ = writeln!(
        out,
        "source driver: {} frames out, {} in, {} WouldBlock kept and retried; destination driver: {} out, {} in",
        sa.frames_transmitted, sa.frames_received, sa.would_block, sb.frames_transmitted, sb.frames_received
    );
    r
}

fn can_config() -> CanConfig {
    let mut config = CanConfig::default();
    config.alias_cache_size = 8;
    config.reassembly_slots = 2;
    config.transmit_queue_limit = 16;
    config
}

fn node_config() -> NodeConfig {
    let mut config = NodeConfig::default();
    config.stream.max_streams = 4;
    config.stream.max_streams_per_peer = 2;
    config.stream.max_window = WINDOW;
    config
}

/// Semihosting stdout as a `core::fmt::Write`.
struct Out;

impl core::fmt::Write for Out {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        hio::hstdout().map_err(|_| core::fmt::Error)?.write_all(s.as_bytes()).map_err(|_| core::fmt::Error)
    }
}

fn print(r: &Report, ok: bool) {
    let mut out = Out;
    let _ = writeln!(
        out,
        "moved {} of {} bytes through one stream (window {}) in {} rounds: {} mismatched bytes{}",
        r.received,
        LEN,
        WINDOW,
        r.rounds,
        r.mismatches,
        if r.finished && r.matched { ", Complete matched" } else { ", NOT completed" }
    );
    if let Some(offset) = r.first_mismatch {
        let _ = writeln!(out, "first mismatch at byte {offset}");
    }
    let _ = writeln!(
        out,
        "heap ({HEAP_SIZE} B): {} B at start, {} B with both nodes logged in, +{} B after open() \
         (source stream + queued Initiate Request), +{} B with the stream open at both ends, \
         peak +{} B during the transfer, {:+} B after it ended ({} streams left)",
        r.heap_start,
        r.heap_logged_in,
        r.heap_after_open.saturating_sub(r.heap_logged_in),
        r.heap_opened.saturating_sub(r.heap_logged_in),
        r.heap_peak.saturating_sub(r.heap_logged_in),
        r.heap_end as i64 - r.heap_logged_in as i64,
        r.streams_left,
    );
    let _ = writeln!(
        out,
        "a second (empty) stream {}; heap after it {:+} B",
        if r.second_ok { "opened and finished" } else { "FAILED" },
        r.heap_end_second as i64 - r.heap_logged_in as i64
    );
    let _ = writeln!(out, "{}", if ok { "PASS: 64 KiB verified" } else { "FAIL" });
}
