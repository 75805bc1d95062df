//! The few nRF51822 peripherals the board uses, by their registers (nRF51 Series Reference
//! Manual v3.0): the UART (its CAN bus, as GridConnect text), TIMER0 (the node's clock), the
//! NVMC (flash pages for the configuration and the firmware image) and the system reset.
//!
//! Only unsafe code of the firmware besides the runtime: volatile accesses to these registers
//! and to the flash the NVMC writes.

use core::ptr::{read_volatile, write_volatile};

use openlcb_stream::Instant;

/// Writes `value` to the 32-bit register at `address`.
fn write_register(address: usize, value: u32) {
    // SAFETY: `address` is one of this module's peripheral registers (or flash words under
    // the NVMC's write enable), which take 32-bit writes; single core, no interrupts used.
    #[allow(unsafe_code)]
    unsafe {
        write_volatile(address as *mut u32, value)
    }
}

/// Reads the 32-bit register (or flash word) at `address`.
fn read_register(address: usize) -> u32 {
    // SAFETY: as in `write_register`, for reads.
    #[allow(unsafe_code)]
    unsafe {
        read_volatile(address as *const u32)
    }
}

const UART: usize = 0x4000_2000;
const UART_STARTRX: usize = UART;
const UART_STARTTX: usize = UART + 0x008;
const UART_RXDRDY: usize = UART + 0x108;
const UART_TXDRDY: usize = UART + 0x11C;
const UART_ENABLE: usize = UART + 0x500;
const UART_RXD: usize = UART + 0x518;
const UART_TXD: usize = UART + 0x51C;
const UART_BAUDRATE: usize = UART + 0x524;

/// The UART, 8N1 (the baud rate is moot under QEMU, whose UART runs as fast as its socket).
pub struct Uart(());

impl Uart {
    /// Enables the UART and starts both directions.
    pub fn new() -> Self {
        write_register(UART_BAUDRATE, 0x01D7_E000); // 115200 baud
        write_register(UART_ENABLE, 4);
        write_register(UART_STARTRX, 1);
        write_register(UART_STARTTX, 1);
        Uart(())
    }

    /// Sends one byte, waiting until the UART has taken it.
    pub fn write_byte(&mut self, byte: u8) {
        write_register(UART_TXDRDY, 0);
        write_register(UART_TXD, u32::from(byte));
        while read_register(UART_TXDRDY) == 0 {}
    }

    /// The next received byte, if one is waiting.
    pub fn read_byte(&mut self) -> Option<u8> {
        if read_register(UART_RXDRDY) == 0 {
            return None;
        }
        write_register(UART_RXDRDY, 0);
        Some(read_register(UART_RXD) as u8)
    }
}

const TIMER0: usize = 0x4000_8000;
const TIMER_START: usize = TIMER0;
const TIMER_STOP: usize = TIMER0 + 0x004;
const TIMER_CLEAR: usize = TIMER0 + 0x00C;
const TIMER_CAPTURE0: usize = TIMER0 + 0x040;
const TIMER_MODE: usize = TIMER0 + 0x504;
const TIMER_BITMODE: usize = TIMER0 + 0x508;
const TIMER_PRESCALER: usize = TIMER0 + 0x510;
const TIMER_CC0: usize = TIMER0 + 0x540;

/// TIMER0 as a 32-bit microsecond counter (16 MHz / 2^4), extended to 64 bits in software:
/// read at least once every 71 minutes (the main loop reads it on every pass).
pub struct Clock {
    high: u64,
    last: u32,
}

impl Clock {
    /// Starts TIMER0 from zero. It is stopped and cleared first: a reset that does not reach
    /// the peripherals (a bootloader's jump, QEMU's system reset) can leave it running, and
    /// configuring a running timer is undefined.
    pub fn new() -> Self {
        write_register(TIMER_STOP, 1);
        write_register(TIMER_CLEAR, 1);
        write_register(TIMER_MODE, 0);
        write_register(TIMER_BITMODE, 3);
        write_register(TIMER_PRESCALER, 4);
        write_register(TIMER_START, 1);
        Clock { high: 0, last: 0 }
    }

    /// The time since start-up.
    pub fn now(&mut self) -> Instant {
        write_register(TIMER_CAPTURE0, 1);
        let low = read_register(TIMER_CC0);
        if low < self.last {
            self.high += 1 << 32;
        }
        self.last = low;
        Instant::from_micros(self.high | u64::from(low))
    }
}

const NVMC: usize = 0x4001_E000;
const NVMC_READY: usize = NVMC + 0x400;
const NVMC_CONFIG: usize = NVMC + 0x504;
const NVMC_ERASEPAGE: usize = NVMC + 0x508;

/// Bytes in one flash page, the unit of erasure.
pub const PAGE_SIZE: u32 = 1024;

fn wait_for_nvmc() {
    while read_register(NVMC_READY) == 0 {}
}

/// Erases the flash page at `address` (a multiple of [`PAGE_SIZE`]) to all ones.
pub fn erase_page(address: u32) {
    write_register(NVMC_CONFIG, 2);
    write_register(NVMC_ERASEPAGE, address);
    wait_for_nvmc();
    write_register(NVMC_CONFIG, 0);
}

/// Writes `words` to flash from `address` (word-aligned). Flash only clears bits: the words
/// must have been erased.
pub fn write_flash(address: u32, words: impl Iterator<Item = u32>) {
    write_register(NVMC_CONFIG, 1);
    for (i, word) in words.enumerate() {
        write_register(address as usize + 4 * i, word);
        wait_for_nvmc();
    }
    write_register(NVMC_CONFIG, 0);
}

/// Reads flash bytes from `address` into `buf`.
pub fn read_flash(address: u32, buf: &mut [u8]) {
    for (i, byte) in buf.iter_mut().enumerate() {
        let at = address as usize + i;
        *byte = (read_register(at & !3) >> (8 * (at & 3))) as u8;
    }
}

/// Restarts the chip (the system reset request of the Cortex-M0).
pub fn reset() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

impl openlcb_embedded::Clock for Clock {
    fn now(&mut self) -> Instant {
        Clock::now(self)
    }
}
