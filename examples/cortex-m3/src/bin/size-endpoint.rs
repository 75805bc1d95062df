//! Flash budget: the baseline plus one `StreamEndpoint`, both roles, every input, command and
//! output.

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
    loop {
        exercise::baseline_turn(&mut buf);
        exercise::endpoint_turn(&mut endpoint);
        exercise::endpoint_transmits(&mut endpoint);
        exercise::endpoint_outputs(&mut endpoint);
    }
}
