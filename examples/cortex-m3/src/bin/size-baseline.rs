//! Flash budget, row 0: the runtime and the allocator, no OpenLCB code. The other size
//! firmwares are measured as increments over this one.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::exercise;

#[entry]
fn main() -> ! {
    exercise::run(|| (), |_| {})
}
