//! The board's CAN bus on its UART, each frame in binary as a CAN controller's mailbox holds
//! it: a byte `0xC0 + length` (length 0 to 8), the 29-bit identifier in 4 bytes (big-endian),
//! then the data. It is an `embedded_can::nb::Can` peripheral, so that the `openlcb-embedded`
//! driver runs on it unchanged. QEMU models no Cortex-M0 with a CAN controller; on a board
//! with one (or an MCP2515 on SPI) its HAL driver takes this place. The test bridges the UART
//! to a GridConnect hub (`crates/openlcb-tokio/tests/cortex_m0.rs`).

use embedded_can::ErrorKind;
use openlcb_can::CanFrame;

use crate::nrf51::Uart;

/// The first byte of a frame, plus its data length.
const START: u8 = 0xC0;
/// The longest frame on the UART: the start byte, the identifier, 8 data bytes.
const LONGEST: usize = 1 + 4 + 8;

/// Binary CAN frames on the UART.
pub struct SerialCan {
    uart: Uart,
    /// The frame being received, `received` bytes of it so far.
    frame: [u8; LONGEST],
    received: usize,
}

impl SerialCan {
    /// The bus on `uart`.
    pub fn new(uart: Uart) -> Self {
        SerialCan { uart, frame: [0; LONGEST], received: 0 }
    }
}

impl embedded_can::nb::Can for SerialCan {
    type Frame = CanFrame;
    type Error = ErrorKind;

    /// Writes the frame out whole (the UART waits byte by byte): never refuses.
    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ErrorKind> {
        let data = frame.payload();
        self.uart.write_byte(START + data.len() as u8);
        for byte in frame.raw_id().to_be_bytes().iter().chain(data) {
            self.uart.write_byte(*byte);
        }
        Ok(None)
    }

    /// Collects received bytes up to the next whole frame; a byte where a frame should start
    /// that cannot start one is a receive error (the driver counts it) and is skipped, so
    /// the next frame is found again.
    fn receive(&mut self) -> nb::Result<CanFrame, ErrorKind> {
        while let Some(byte) = self.uart.read_byte() {
            if self.received == 0 && !(START..=START + 8).contains(&byte) {
                return Err(nb::Error::Other(ErrorKind::Other));
            }
            if let Some(slot) = self.frame.get_mut(self.received) {
                *slot = byte;
            }
            self.received += 1;
            let [start, id @ .., _, _, _, _, _, _, _, _] = self.frame;
            let len = 5 + usize::from(start - START);
            if self.received == len {
                self.received = 0;
                let data = self.frame.get(5..len).unwrap_or_default();
                return CanFrame::extended(u32::from_be_bytes(id), data).ok_or(nb::Error::Other(ErrorKind::Other));
            }
        }
        Err(nb::Error::WouldBlock)
    }
}
