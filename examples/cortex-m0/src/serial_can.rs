//! The board's CAN bus as GridConnect text on its UART, the way a USB-CAN adapter or a CAN
//! hub's serial port carries it: an `embedded_can::nb::Can` peripheral, so that the
//! `openlcb-embedded` driver runs on it unchanged. QEMU models no Cortex-M0 with a CAN
//! controller; on a board with one (or an MCP2515 on SPI) its HAL driver takes this place.

use embedded_can::ErrorKind;
use openlcb_can::CanFrame;
use openlcb_can::gridconnect::{GridConnectDecoder, encode};

use crate::nrf51::Uart;

/// GridConnect frames on the UART.
pub struct SerialCan {
    uart: Uart,
    decoder: GridConnectDecoder,
}

impl SerialCan {
    /// The bus on `uart`.
    pub fn new(uart: Uart) -> Self {
        SerialCan { uart, decoder: GridConnectDecoder::new() }
    }
}

impl embedded_can::nb::Can for SerialCan {
    type Frame = CanFrame;
    type Error = ErrorKind;

    /// Writes the frame's text out whole (the UART waits byte by byte): never refuses.
    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ErrorKind> {
        let mut text = [0u8; 28];
        let len = encode(frame, &mut text).map_err(|_| nb::Error::Other(ErrorKind::Other))?;
        for byte in &text[..len] {
            self.uart.write_byte(*byte);
        }
        Ok(None)
    }

    /// Decodes received text up to the next whole frame; bad text is a receive error (the
    /// decoder has resynchronised, the driver counts it).
    fn receive(&mut self) -> nb::Result<CanFrame, ErrorKind> {
        while let Some(byte) = self.uart.read_byte() {
            if let Some(result) = self.decoder.decode(&mut &[byte][..]) {
                return result.map_err(|_| nb::Error::Other(ErrorKind::Other));
            }
        }
        Err(nb::Error::WouldBlock)
    }
}
