//! One type per stream message, each with `parse`, `emit` and `buffer_len`.
//!
//! Parsing is liberal exactly where real peers differ (wire-spec §3.2, §4, §10): 5/6/12-byte
//! requests, accept code 0x8000 or 0x0000 with a non-zero buffer, 2- or 4-byte Proceed,
//! 2/4/6/7-byte Complete, short OIR/TDE. Emitting is strict and always picks one form.
//! Offsets are into the message payload, after the MTI and Node IDs.

mod complete;
mod data;
mod error_report;
mod initiate;

pub use complete::{CompleteCount, DataComplete};
pub use data::{DataProceed, DataSend};
pub use error_report::{ErrorCode, ErrorReport};
pub use initiate::{InitiateReply, InitiateRequest, ReplyClass, ReplyCode};

use crate::{Mti, StreamId};

/// Why a payload is not a valid message of its type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Fewer bytes than the shortest accepted form.
    #[error("{mti:?} needs at least {needed} payload bytes, got {got}")]
    TooShort {
        /// The message type being parsed.
        mti: Mti,
        /// The shortest accepted payload.
        needed: u8,
        /// What arrived.
        got: usize,
    },
    /// A stream ID field holds the reserved value 0xFF (draft §4: ignore on receipt).
    #[error("{mti:?} carries the reserved stream ID 0xFF in its {field} field")]
    ReservedStreamId {
        /// The message type being parsed.
        mti: Mti,
        /// `"SID"` or `"DID"`.
        field: &'static str,
    },
    /// An Initiate Request proposing a Max Buffer Size of 0 (draft §5.1: 1..65535).
    #[error("Stream Initiate Request proposes a Max Buffer Size of 0")]
    ZeroBufferSize,
}

/// The caller's buffer is smaller than `buffer_len()`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("buffer of {got} bytes is too small, {needed} needed")]
pub struct BufferTooSmall {
    /// What `buffer_len()` asked for.
    pub needed: usize,
    /// What the caller gave.
    pub got: usize,
}

/// Copies `bytes` to the front of `buf`, or says how much room was needed.
fn put(buf: &mut [u8], bytes: &[u8]) -> Result<usize, BufferTooSmall> {
    let too_small = BufferTooSmall { needed: bytes.len(), got: buf.len() };
    let out = buf.get_mut(..bytes.len()).ok_or(too_small)?;
    out.copy_from_slice(bytes);
    Ok(bytes.len())
}

/// Fails with [`DecodeError::TooShort`] unless `payload` holds `needed` bytes.
fn need(mti: Mti, payload: &[u8], needed: u8) -> Result<(), DecodeError> {
    if payload.len() < usize::from(needed) {
        Err(DecodeError::TooShort { mti, needed, got: payload.len() })
    } else {
        Ok(())
    }
}

/// A stream ID field that must not be 0xFF.
fn stream_id(mti: Mti, raw: u8, field: &'static str) -> Result<StreamId, DecodeError> {
    StreamId::new(raw).ok_or(DecodeError::ReservedStreamId { mti, field })
}

/// Byte `i`, or 0 past the end (only called after a length check).
fn byte(payload: &[u8], i: usize) -> u8 {
    payload.get(i).copied().unwrap_or(0)
}

/// Big-endian u16 at `i`, or 0 past the end (only called after a length check).
fn be16(payload: &[u8], i: usize) -> u16 {
    u16::from_be_bytes([byte(payload, i), byte(payload, i + 1)])
}

/// The emitting half shared by every wire type.
pub trait Emit {
    /// The exact length `emit` writes.
    fn buffer_len(&self) -> usize;

    /// Writes the strict form to the front of `buf` and returns its length. Never panics: a
    /// buffer shorter than [`buffer_len`](Emit::buffer_len) gets [`BufferTooSmall`].
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall>;

    /// The emitted bytes (one allocation).
    fn to_bytes(&self) -> alloc::vec::Vec<u8> {
        let mut out = alloc::vec![0u8; self.buffer_len()];
        let written = self.emit(&mut out).unwrap_or(0);
        out.truncate(written);
        out
    }
}

#[cfg(test)]
mod tests;
