//! Flash budget: the baseline plus a `StreamEndpoint` and a `CanLink` behind the
//! `openlcb-embedded` driver, on a fake CAN peripheral.

#![no_std]
#![no_main]

extern crate alloc;

use cortex_m_rt::entry;
use openlcb_cortex_m3::{exercise, init_heap, opaque};
use openlcb_embedded::Driver;
use openlcb_stream::Instant;

#[entry]
fn main() -> ! {
    init_heap();
    let mut buf = alloc::vec::Vec::new();
    let mut endpoint = exercise::endpoint();
    let clock = || Instant::from_micros(u64::from(opaque::input()));
    let mut driver = Driver::new(exercise::OpaqueCan, clock, exercise::link());
    loop {
        exercise::baseline_turn(&mut buf);
        exercise::endpoint_turn(&mut endpoint);
        let poll = driver.poll(&mut endpoint);
        opaque::output(poll.map_or(1, |p| p.transmitted as u32));
        exercise::endpoint_outputs(&mut endpoint);
    }
}
