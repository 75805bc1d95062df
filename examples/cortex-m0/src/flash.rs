//! The board's two flash-backed memory spaces: its configuration (space 0xFD, one flash page,
//! kept in RAM and saved when a write command is done) and the firmware image (space 0xEF, the
//! flash a bootloader would copy from, each page erased the first time an upgrade writes it).

use alloc::vec;
use alloc::vec::Vec;

use openlcb_node::{MemorySpace, SpaceError};

use crate::nrf51::{PAGE_SIZE, erase_page, read_flash, write_flash};

/// The flash page of the configuration: the last page of the nRF51822's 256 KiB.
const CONFIG_PAGE: u32 = 0x3_FC00;
/// The last word of the configuration page holds this once the page holds a configuration.
const CONFIG_MAGIC: u32 = 0x4C43_4301;
/// Where space 0xEF lies in flash: above the 32 KiB of code, below the configuration page.
const FIRMWARE_START: u32 = 0x2_0000;
/// Bytes of space 0xEF.
pub const FIRMWARE_LEN: u32 = CONFIG_PAGE - FIRMWARE_START;

/// Packs bytes into little-endian words, padding the last one with ones (erased flash).
fn words(bytes: &[u8]) -> impl Iterator<Item = u32> + '_ {
    bytes.chunks(4).map(|chunk| {
        let mut word = [0xFF; 4];
        word[..chunk.len()].copy_from_slice(chunk);
        u32::from_le_bytes(word)
    })
}

/// Space 0xFD: the settings, read and written in RAM; a write command's end saves them to the
/// configuration page (erased and written whole), so a reset or power cycle keeps them.
pub struct ConfigSpace {
    bytes: Vec<u8>,
    dirty: bool,
}

impl ConfigSpace {
    /// The configuration of `len` bytes as flash holds it; `None` if the page holds none
    /// (a new board: the caller writes the defaults).
    pub fn load(len: u32) -> (Self, bool) {
        let mut bytes = vec![0; len as usize];
        let mut magic = [0; 4];
        read_flash(CONFIG_PAGE + PAGE_SIZE - 4, &mut magic);
        let found = u32::from_le_bytes(magic) == CONFIG_MAGIC;
        if found {
            read_flash(CONFIG_PAGE, &mut bytes);
        }
        (ConfigSpace { bytes, dirty: false }, found)
    }
}

impl MemorySpace for ConfigSpace {
    fn len(&self) -> u32 {
        self.bytes.len() as u32
    }

    fn read_only(&self) -> bool {
        false
    }

    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        let tail = self.bytes.get(address as usize..).ok_or(SpaceError::OutOfBounds)?;
        let n = tail.len().min(buf.len());
        buf[..n].copy_from_slice(&tail[..n]);
        Ok(n)
    }

    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        let at = address as usize;
        self.bytes.get_mut(at..at + data.len()).ok_or(SpaceError::OutOfBounds)?.copy_from_slice(data);
        self.dirty = true;
        Ok(())
    }

    fn commit(&mut self) -> Result<(), SpaceError> {
        if self.dirty {
            erase_page(CONFIG_PAGE);
            write_flash(CONFIG_PAGE, words(&self.bytes));
            write_flash(CONFIG_PAGE + PAGE_SIZE - 4, [CONFIG_MAGIC].into_iter());
            self.dirty = false;
        }
        Ok(())
    }
}

/// Space 0xEF: the firmware image, written straight to flash. Each page is erased the first
/// time an upgrade writes into it; a new upgrade (a Freeze, a retry) starts over. Readable,
/// so that a tool can verify what it wrote.
pub struct FirmwareSpace {
    /// Bit n % 32 of word n / 32: page n of the space was erased during this upgrade (32-bit
    /// words: a Cortex-M0 shifts a `u128` in a library call).
    erased: [u32; ERASED_WORDS],
}

/// Words of [`FirmwareSpace::erased`]: a bit for each page of space 0xEF.
const ERASED_WORDS: usize = FIRMWARE_LEN.div_ceil(PAGE_SIZE * 32) as usize;

impl FirmwareSpace {
    /// The space; nothing is erased until an upgrade writes.
    pub fn new() -> Self {
        FirmwareSpace { erased: [0; ERASED_WORDS] }
    }
}

impl MemorySpace for FirmwareSpace {
    fn len(&self) -> u32 {
        FIRMWARE_LEN
    }

    fn read_only(&self) -> bool {
        false
    }

    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        let n = buf.len().min((FIRMWARE_LEN - address) as usize);
        read_flash(FIRMWARE_START + address, &mut buf[..n]);
        Ok(n)
    }

    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        // Byte by byte into words whose other bytes are ones: flash ANDs what is written, so
        // the bytes around are kept whatever the alignment of `address`.
        for (i, byte) in data.iter().enumerate() {
            let at = address + i as u32;
            let page = at / PAGE_SIZE;
            let (index, bit) = (page as usize / 32, 1 << (page % 32));
            if let Some(erased) = self.erased.get_mut(index)
                && *erased & bit == 0
            {
                erase_page(FIRMWARE_START + page * PAGE_SIZE);
                *erased |= bit;
            }
            let shift = 8 * (at & 3);
            let word = !(0xFF << shift) | (u32::from(*byte) << shift);
            write_flash(FIRMWARE_START + (at & !3), [word].into_iter());
        }
        Ok(())
    }

    fn discard(&mut self) {
        self.erased = [0; ERASED_WORDS];
    }
}
