//! Stream Data Send (0x1F88) and Stream Data Proceed (0x0888).

use super::{BufferTooSmall, DecodeError, Emit, byte, need, put, stream_id};
use crate::{Mti, StreamId};

/// Stream Data Send, source to destination (draft §5.3, wire-spec §4.3): `DID payload…`.
///
/// It carries no SID. A DID with no payload is a flush / keep-alive and uses no window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataSend<'a> {
    /// The destination's stream ID.
    pub destination_stream: StreamId,
    /// The stream bytes, possibly none.
    pub data: &'a [u8],
}

impl<'a> DataSend<'a> {
    const MTI: Mti = Mti::STREAM_DATA_SEND;

    /// Parses a Data Send of at least the DID byte; DID 0xFF is refused.
    pub fn parse(payload: &'a [u8]) -> Result<Self, DecodeError> {
        need(Self::MTI, payload, 1)?;
        let destination_stream = stream_id(Self::MTI, byte(payload, 0), "DID")?;
        Ok(DataSend { destination_stream, data: payload.get(1..).unwrap_or(&[]) })
    }
}

impl Emit for DataSend<'_> {
    /// 1 + the data length.
    fn buffer_len(&self) -> usize {
        self.data.len().saturating_add(1)
    }

    /// Writes the DID and the data.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let too_small = BufferTooSmall { needed: self.buffer_len(), got: buf.len() };
        let (first, rest) = buf.split_first_mut().ok_or(too_small)?;
        let n = put(rest, self.data).map_err(|_| too_small)?;
        *first = self.destination_stream.as_raw();
        Ok(n.saturating_add(1))
    }
}

/// Stream Data Proceed, destination to source (draft §5.4, wire-spec §4.4): `SID DID [flags]`.
///
/// Emitted as 4 bytes, `SID DID 00 00`: the form OpenMRN sends and the only one JMRI's
/// OpenLCB_Java parses (it reads bytes 2-3 unconditionally); valid per wire-spec §4.4. The
/// optional flags have no defined values and are ignored on receipt, so 2 bytes and more are
/// accepted (wire-spec C-11: termination is by TDE, not by Proceed flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataProceed {
    /// The source's stream ID.
    pub source_stream: StreamId,
    /// The destination's stream ID.
    pub destination_stream: StreamId,
}

impl DataProceed {
    const MTI: Mti = Mti::STREAM_DATA_PROCEED;

    /// Parses a Proceed of 2 or more bytes; either ID 0xFF is refused.
    pub fn parse(payload: &[u8]) -> Result<Self, DecodeError> {
        need(Self::MTI, payload, 2)?;
        Ok(DataProceed {
            source_stream: stream_id(Self::MTI, byte(payload, 0), "SID")?,
            destination_stream: stream_id(Self::MTI, byte(payload, 1), "DID")?,
        })
    }
}

impl Emit for DataProceed {
    /// Always 4.
    fn buffer_len(&self) -> usize {
        4
    }

    /// Writes `SID DID 00 00`.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
        put(buf, &[self.source_stream.as_raw(), self.destination_stream.as_raw(), 0, 0])
    }
}
