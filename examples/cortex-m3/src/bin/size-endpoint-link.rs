//! Flash budget: the baseline plus a `StreamEndpoint` and a `CanLink` between it and a fake
//! mailbox.

#![no_std]
#![no_main]

extern crate alloc;

use cortex_m_rt::entry;
use openlcb_cortex_m3::{exercise, init_heap};

#[entry]
fn main() -> ! {
    init_heap();
    let mut buf = alloc::vec::Vec::new();
    let mut endpoint = exercise::endpoint();
    let mut link = exercise::link();
    loop {
        exercise::baseline_turn(&mut buf);
        exercise::endpoint_turn(&mut endpoint);
        exercise::link_turn(&mut link, &mut endpoint);
        exercise::endpoint_outputs(&mut endpoint);
    }
}
