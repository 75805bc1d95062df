//! Counts heap allocations during a steady-state stream transfer through two `CanLink`s and
//! two `StreamEndpoint`s: the links allocate nothing per frame on either side; the core
//! allocates per message (one payload `Vec` per Data Send, one per Proceed), not per frame. Then
//! 72-byte datagrams through the same links: framing and reassembly allocate nothing either.
//!
//! One test only in this file: the counter is global to the process.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use common::{A_ID, B_ID, Bus, Node, can_config};
use openlcb_can::CanFrame;
use openlcb_node::NodeEvent;
use openlcb_stream::{Config, Event, Instant, Message, Mti, OpenOptions, StreamHandle};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Set on the test's own thread: allocations of the test harness's other threads (output
    /// capture, timers) are not the stack's and are not counted.
    static COUNTED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn count_one() {
    if COUNTED.try_with(std::cell::Cell::get).unwrap_or(false) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards to the system allocator; only counts.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.load(Ordering::Relaxed)
}

#[derive(Default, Debug)]
struct Tally {
    /// Allocations inside `CanLink` calls (send, poll_transmit, handle_frame minus the core).
    link: u64,
    /// Allocations inside `StreamEndpoint` calls.
    core: u64,
    stream_frames: u64,
    data_send_messages: u64,
    proceeds: u64,
}

/// Moves everything `from` has to send into `to`, counting allocations by owner.
fn deliver(now: Instant, from: &mut Node, to: &mut Node, tally: &mut Tally) {
    loop {
        let before = allocations();
        let Some(msg) = from.stack.poll_transmit() else {
            break;
        };
        tally.core += allocations() - before;
        match msg.mti {
            openlcb_stream::Mti::STREAM_DATA_SEND => tally.data_send_messages += 1,
            openlcb_stream::Mti::STREAM_DATA_PROCEED => tally.proceeds += 1,
            _ => {}
        }
        let before = allocations();
        from.link.send(now, msg).unwrap();
        tally.link += allocations() - before;
    }
    loop {
        let before = allocations();
        let frame: Option<CanFrame> = from.link.poll_transmit();
        tally.link += allocations() - before;
        let Some(frame) = frame else { break };
        if frame.raw_id() >> 24 == 0x1F {
            tally.stream_frames += 1;
        }
        let endpoint = &mut to.stack;
        let mut in_core = 0;
        let before = allocations();
        let mut counted = common::messages(|msg| {
            let before_core = allocations();
            endpoint.handle_message(now, msg);
            in_core += allocations() - before_core;
        });
        to.link.handle_frame(now, &frame, &mut counted);
        tally.link += allocations() - before - in_core;
        tally.core += in_core;
    }
}

/// Writes `total` bytes from A to B, reading at B, until B has all of them.
fn transfer(now: Instant, a: &mut Node, b: &mut Node, stream: StreamHandle, total: usize, tally: &mut Tally) {
    static DATA: [u8; 4096] = [0xA5; 4096];
    let mut buf = [0u8; 4096];
    let (mut written, mut read) = (0, 0);
    while read < total {
        if written < total {
            let chunk = &DATA[..(total - written).min(DATA.len())];
            let before = allocations();
            written += a.endpoint().write(now, stream, chunk).unwrap();
            tally.core += allocations() - before;
        }
        deliver(now, a, b, tally);
        let before = allocations();
        while let Some(event) = b.stack.poll_event() {
            if let NodeEvent::Stream(Event::Readable { handle }) = event {
                while let Ok(n @ 1..) = b.endpoint().read(now, handle, &mut buf) {
                    read += n;
                }
            }
        }
        while a.stack.poll_event().is_some() {}
        tally.core += allocations() - before;
        deliver(now, b, a, tally);
    }
}

#[test]
fn no_allocation_per_stream_frame_in_the_links() {
    COUNTED.set(true);
    let mut core = Config::default();
    core.max_window = 2048;
    let mut bus = Bus::new(vec![
        Node::new(Instant::ZERO, A_ID, core.clone(), can_config(0x123)),
        Node::new(Instant::ZERO, B_ID, core, can_config(0x456)),
    ]);
    bus.advance_to(Instant::from_millis(200));
    let now = bus.now;
    let stream = bus.nodes[0].endpoint().open(now, OpenOptions::new(common::node_id(B_ID), 2048)).unwrap();
    bus.pump();
    let mut nodes = bus.nodes.into_iter();
    let (mut a, mut b) = (nodes.next().unwrap(), nodes.next().unwrap());
    a.reading = false;
    b.reading = false;

    // Warm up: queues and receive buffers reach their working size.
    transfer(now, &mut a, &mut b, stream, 64 * 1024, &mut Tally::default());

    let mut tally = Tally::default();
    let total = 256 * 1024;
    transfer(now, &mut a, &mut b, stream, total, &mut tally);
    println!("{tally:?}");

    assert!(tally.stream_frames >= (total / 7) as u64, "{} frames for {total} bytes", tally.stream_frames);
    assert_eq!(tally.link, 0, "allocations in the links over {} stream frames", tally.stream_frames);
    // The core: one payload `Vec` per Data Send message and per Proceed, nothing per frame.
    assert!(
        tally.core <= tally.data_send_messages + tally.proceeds,
        "core allocations {} for {} Data Send messages and {} Proceeds",
        tally.core,
        tally.data_send_messages,
        tally.proceeds
    );

    // Datagrams of 72 bytes, nine frames each, from A to B: the messages are built before
    // counting (their payload is static), then sent, framed, reassembled and delivered.
    static DATAGRAM: [u8; 72] = [0x5A; 72];
    let (a_id, b_id) = (common::node_id(A_ID), common::node_id(B_ID));
    let datagrams: Vec<Message> =
        (0..100).map(|_| Message::addressed(Mti::DATAGRAM, a_id, b_id, &DATAGRAM[..])).collect();
    let (mut in_links, mut frames, mut delivered) = (0, 0, 0);
    for datagram in datagrams {
        let before = allocations();
        a.link.send(now, datagram).unwrap();
        while let Some(frame) = a.link.poll_transmit() {
            frames += 1;
            let mut counted = common::messages(|msg| {
                delivered += usize::from(msg.mti == Mti::DATAGRAM && msg.payload == DATAGRAM);
            });
            b.link.handle_frame(now, &frame, &mut counted);
        }
        in_links += allocations() - before;
    }
    assert_eq!((frames, delivered), (900, 100));
    assert_eq!(in_links, 0, "allocations in the links over {frames} datagram frames");
}
