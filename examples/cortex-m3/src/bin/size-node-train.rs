//! Flash budget: `size-node` plus a train (Traction Control and Train Search), fed messages
//! directly: the difference to `size-node` is the traction service alone.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::exercise;

#[entry]
fn main() -> ! {
    exercise::run(exercise::train_node, exercise::train_turn)
}
