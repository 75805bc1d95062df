//! Steady-state allocation count of a 1 MiB transfer between two endpoints, measured with a
//! counting global allocator: exactly one allocation per Data Send (its payload `Vec`) and
//! one per Proceed, nothing else.

// A global allocator is unsafe by nature; this test file is the only place that needs it.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use openlcb_stream::{Config, Event, Instant, Mti, NodeId, OpenOptions, StreamEndpoint};

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

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn one_allocation_per_data_send_and_per_proceed() {
    const TOTAL: usize = 1 << 20;
    const WARM_UP: usize = 64 << 10;
    COUNTED.set(true);
    let a_id = NodeId::new(0x0501_0101_2200).unwrap();
    let b_id = NodeId::new(0x0501_0101_2201).unwrap();
    let mut config = Config::default();
    config.max_window = 2048;
    config.early_proceed = true;
    let mut a = StreamEndpoint::new(a_id, config.clone());
    let mut b = StreamEndpoint::new(b_id, config);
    let now = Instant::ZERO;
    let data = vec![0xA5u8; 4096];
    let mut buf = vec![0u8; 4096];
    let stream = a.open(now, OpenOptions::new(b_id, 2048)).unwrap();
    let mut dest = None;
    let (mut sent, mut received) = (0usize, 0usize);
    let (mut data_sends, mut proceeds) = (0u64, 0u64);
    let mut baseline = None;
    while received < TOTAL {
        if baseline.is_none() && received >= WARM_UP {
            baseline = Some(ALLOCATIONS.load(Ordering::Relaxed));
            (data_sends, proceeds) = (0, 0);
        }
        if sent < TOTAL && a.credit(stream).unwrap_or(0) > 0 {
            sent += a.write(now, stream, &data[..(TOTAL - sent).min(data.len())]).unwrap();
        }
        while let Some(msg) = a.poll_transmit() {
            data_sends += u64::from(msg.mti == Mti::STREAM_DATA_SEND);
            b.handle_message(now, msg.as_ref());
        }
        while let Some(event) = b.poll_event() {
            if let Event::Opened { handle, .. } = event {
                dest = Some(handle);
            }
        }
        if let Some(h) = dest {
            received += b.read(now, h, &mut buf).unwrap();
        }
        while let Some(msg) = b.poll_transmit() {
            proceeds += u64::from(msg.mti == Mti::STREAM_DATA_PROCEED);
            a.handle_message(now, msg.as_ref());
        }
        while a.poll_event().is_some() {}
    }
    let allocations = ALLOCATIONS.load(Ordering::Relaxed) - baseline.unwrap();
    println!("steady state: {allocations} allocations for {data_sends} Data Sends and {proceeds} Proceeds");
    assert!(data_sends >= 400, "the measured part moved {data_sends} messages");
    assert_eq!(allocations, data_sends + proceeds);
}
