//! Flash budget: the baseline plus a `StreamEndpoint` and a `CanLink` between it and a fake
//! mailbox.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::exercise;

#[entry]
fn main() -> ! {
    exercise::run(
        || (exercise::endpoint(), exercise::link()),
        |(endpoint, link)| {
            exercise::endpoint_turn(endpoint);
            exercise::link_turn(link, endpoint);
            exercise::endpoint_outputs(endpoint);
        },
    )
}
