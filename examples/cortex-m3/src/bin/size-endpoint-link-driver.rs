//! Flash budget: the baseline plus a `StreamEndpoint` and a `CanLink` behind the
//! `openlcb-embedded` driver, on a fake CAN peripheral.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use openlcb_cortex_m3::{exercise, opaque};
use openlcb_embedded::Driver;
use openlcb_stream::Instant;

#[entry]
fn main() -> ! {
    let clock = || Instant::from_micros(u64::from(opaque::input()));
    exercise::run(
        || (exercise::endpoint(), Driver::new(exercise::OpaqueCan, clock, exercise::link())),
        |(endpoint, driver)| {
            exercise::endpoint_turn(endpoint);
            opaque::output(driver.poll(endpoint).map_or(1, |p| p.transmitted as u32));
            exercise::endpoint_outputs(endpoint);
        },
    )
}
