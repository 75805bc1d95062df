//! Optional Interaction Rejected (0x0068) and Terminate Due To Error (0x00A8) payloads.

use core::fmt;

use super::{BufferTooSmall, Emit, be16, put};
use crate::Mti;

/// A Message Network error code (MN §3.5.5); an open type keeping the raw value.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ErrorCode(pub u16);

impl ErrorCode {
    /// Permanent error, no detail.
    pub const PERMANENT: ErrorCode = ErrorCode(0x1000);
    /// Permanent error: this source is not permitted.
    pub const SOURCE_NOT_PERMITTED: ErrorCode = ErrorCode(0x1020);
    /// Permanent error: not implemented.
    pub const NOT_IMPLEMENTED: ErrorCode = ErrorCode(0x1040);
    /// Permanent error: not implemented, subcommand unknown.
    pub const NOT_IMPLEMENTED_SUBCOMMAND: ErrorCode = ErrorCode(0x1041);
    /// Permanent error: not implemented, datagram type (content ID) unknown.
    pub const NOT_IMPLEMENTED_DATAGRAM_TYPE: ErrorCode = ErrorCode(0x1042);
    /// Permanent error: not implemented, unknown MTI or transport protocol not supported.
    pub const NOT_IMPLEMENTED_MTI: ErrorCode = ErrorCode(0x1043);
    /// Permanent error: invalid arguments.
    pub const INVALID_ARGUMENTS: ErrorCode = ErrorCode(0x1080);
    /// Temporary error: timeout.
    pub const TIMEOUT: ErrorCode = ErrorCode(0x2010);
    /// Temporary error: buffer unavailable.
    pub const BUFFER_UNAVAILABLE: ErrorCode = ErrorCode(0x2020);
    /// Temporary error: not expected / out of order (window overrun).
    pub const OUT_OF_ORDER: ErrorCode = ErrorCode(0x2040);
    /// Temporary error, no detail: what this crate sends when the application aborts.
    pub const TEMPORARY: ErrorCode = ErrorCode(0x2000);

    /// What the code means, from the Message Network standard's table (MN §3.5.5); a code it
    /// does not list is described by its class.
    pub const fn meaning(self) -> &'static str {
        match self.0 {
            0x1000 => "permanent error",
            0x1020 => "source not permitted",
            0x1040 => "not implemented",
            0x1041 => "not implemented: unknown subcommand",
            0x1042 => "not implemented: unknown datagram type",
            0x1043 => "not implemented: unknown MTI or transport",
            0x1080..=0x108F => "invalid arguments",
            0x2000 => "temporary error",
            0x2010 => "timeout",
            0x2011 => "timeout waiting for the end frame",
            0x2020 => "buffer unavailable (busy)",
            0x2040 => "out of order",
            0x2041 => "out of order: middle or last frame without a first",
            0x2042 => "out of order: first frame before the last one ended",
            _ if self.0 & 0x2000 != 0 => "temporary error",
            _ => "permanent error",
        }
    }

    /// The permanent bit (0x1000) is set.
    pub const fn is_permanent(self) -> bool {
        self.0 & 0x1000 != 0
    }

    /// The temporary bit (0x2000) is set.
    pub const fn is_temporary(self) -> bool {
        self.0 & 0x2000 != 0
    }
}

impl fmt::Debug for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ErrorCode(0x{:04X})", self.0)
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}", self.0)
    }
}

/// The payload of an OIR or a TDE (MN §3.3.4-3.3.5, wire-spec §2.3): `CODE(2) MTI(2) [info]`.
///
/// Receivers must process these even when short (OpenMRN's bootloader sends only the code), so
/// parsing never fails: a missing code reads as 0x0000 (allowed by MN) and a missing MTI as
/// `None`. Optional info bytes are skipped. Emitted as 4 bytes, or 2 without an MTI.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorReport {
    /// Why.
    pub code: ErrorCode,
    /// The MTI of the rejected or terminated interaction.
    pub mti: Option<Mti>,
}

impl ErrorReport {
    /// Parses any payload.
    pub fn parse(payload: &[u8]) -> Self {
        ErrorReport { code: ErrorCode(be16(payload, 0)), mti: (payload.len() >= 4).then(|| Mti(be16(payload, 2))) }
    }
}

impl Emit for ErrorReport {
    /// 4, or 2 without an MTI.
    fn buffer_len(&self) -> usize {
        if self.mti.is_some() { 4 } else { 2 }
    }

    /// Writes `CODE [MTI]`.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let [c0, c1] = self.code.0.to_be_bytes();
        match self.mti {
            Some(mti) => {
                let [m0, m1] = mti.0.to_be_bytes();
                put(buf, &[c0, c1, m0, m1])
            }
            None => put(buf, &[c0, c1]),
        }
    }
}
