//! Flash budget: the baseline plus one `StreamEndpoint`, both roles, every input, command and
//! output.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::exercise;

#[entry]
fn main() -> ! {
    exercise::run(exercise::endpoint, |endpoint| {
        exercise::endpoint_turn(endpoint);
        exercise::endpoint_transmits(endpoint);
        exercise::endpoint_outputs(endpoint);
    })
}
