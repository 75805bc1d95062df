//! Serial ports: USB GridConnect adapters (RR-CirKits LCC Buffer-USB, SPROG CANISB,
//! CANRS-style adapters) and anything else that carries GridConnect text over a tty.
//!
//! Opened with `tokio-serial` (raw mode, exclusive, no flow control), the serial crate the
//! tokio ecosystem keeps; the port is a [`ByteStream`](crate::ByteStream), so it goes to
//! [`Node::over`](crate::Node::over) or [`Hub::attach`](crate::Hub::attach). Built without
//! `libudev`: nothing here needs a C library.

use std::sync::Arc;

use crate::Error;

/// The line rate set by default, in bits per second. USB CDC adapters ignore it (the USB link
/// sets the pace); 115200 is the usual setting of GridConnect tools for them and suits an
/// adapter on a real UART too.
pub const DEFAULT_BAUD: u32 = 115_200;

/// A serial port, ready for [`Node::over`](crate::Node::over) or
/// [`Hub::attach`](crate::Hub::attach).
pub type SerialPort = tokio_serial::SerialStream;

/// Opens `device` (`/dev/ttyACM0`, `COM3`) at `baud` bits per second, 8 data bits, no parity,
/// one stop bit, no flow control. A device that cannot be opened is [`Error::Device`].
pub fn open(device: &str, baud: u32) -> Result<SerialPort, Error> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(device, baud).flow_control(tokio_serial::FlowControl::None).open_native_async().map_err(|error| {
        Error::Device { kind: "serial port", device: device.to_string(), source: Arc::new(error.into()) }
    })
}
