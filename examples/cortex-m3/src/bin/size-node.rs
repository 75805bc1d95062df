//! Flash budget: the baseline plus an `openlcb_node::Node` (its stream endpoint, datagrams,
//! SNIP, and a Memory Configuration server serving a RAM space), fed messages directly.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::exercise;

#[entry]
fn main() -> ! {
    exercise::run(exercise::node, exercise::node_turn)
}
