//! GridConnect text framing (wire-spec §9): `:X19CC8123N04560010000004;`.
//!
//! - [`encode`] writes `:X` + exactly 8 upper-case hex digits + `N` + 2 digits a data byte +
//!   `;` into the caller's buffer (standard frames as `:S` + 3 digits, remote frames with `R`);
//!   [`encode_to`] appends the same text to a `Vec<u8>`, a `BytesMut` or any `BufMut`.
//! - [`GridConnectDecoder`] takes text in arbitrary pieces and keeps no text buffer, only the
//!   frame being read. It accepts lower-case hex and any number of id digits, skips CR, LF,
//!   tabs and spaces between frames, counts and skips standard (`:S`) and remote (`R`)
//!   frames, and after garbage, a malformed frame or one longer than
//!   [`MAX_FRAME_TEXT`] characters reports a typed error and resynchronises on the next `:`.

#[cfg(feature = "bytes")]
use bytes::BufMut;
use embedded_can::Frame;

use crate::frame::CanFrame;

/// The longest text [`encode`] writes: `:X` + 8 + `N` + 16 + `;`.
pub const MAX_ENCODED_LEN: usize = 28;

/// The longest frame text the decoder accepts, from `:` to `;` inclusive. Leading zeros in
/// the id are allowed up to this bound.
pub const MAX_FRAME_TEXT: usize = 64;

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// The length of `frame`'s text.
pub fn encoded_len(frame: &CanFrame) -> usize {
    let id_digits = if frame.is_extended() { 8 } else { 3 };
    2 + id_digits + 1 + 2 * frame.data().len() + 1
}

/// The buffer given to [`encode`] or [`encode_to`] has no room for the frame's text.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("a GridConnect frame needs {needed} bytes of buffer, {got} were free")]
pub struct BufferTooSmall {
    /// Bytes the text takes.
    pub needed: usize,
    /// Bytes the buffer had free.
    pub got: usize,
}

/// Appends `frame` as GridConnect text to `out` and returns its length. A growable buffer
/// (`Vec<u8>`, `BytesMut`) always has room; a fixed one may not.
///
/// ```
/// use openlcb_can::{CanFrame, gridconnect};
///
/// let frame = CanFrame::extended(0x19490123, &[]).unwrap();
/// let mut text = Vec::new();
/// gridconnect::encode_to(&frame, &mut text).unwrap();
/// assert_eq!(text, b":X19490123N;");
/// ```
#[cfg(feature = "bytes")]
pub fn encode_to(frame: &CanFrame, out: &mut impl BufMut) -> Result<usize, BufferTooSmall> {
    let mut text = [0u8; MAX_ENCODED_LEN];
    let len = encode(frame, &mut text)?;
    if out.remaining_mut() < len {
        return Err(BufferTooSmall { needed: len, got: out.remaining_mut() });
    }
    out.put_slice(text.get(..len).unwrap_or_default());
    Ok(len)
}

/// Writes `frame` as GridConnect text to the front of `buf` and returns the length.
pub fn encode(frame: &CanFrame, buf: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let needed = encoded_len(frame);
    let too_small = BufferTooSmall { needed, got: buf.len() };
    let out = buf.get_mut(..needed).ok_or(too_small)?;
    let (kind, id_digits) = if frame.is_extended() { (b'X', 8) } else { (b'S', 3) };
    let mut slots = out.iter_mut();
    let mut put = |byte: u8| {
        if let Some(slot) = slots.next() {
            *slot = byte;
        }
    };
    put(b':');
    put(kind);
    let id = frame.raw_id();
    for shift in (0..id_digits).rev() {
        put(hex_digit(id >> (4 * shift)));
    }
    put(if frame.is_remote_frame() { b'R' } else { b'N' });
    for byte in frame.data() {
        put(hex_digit(u32::from(*byte >> 4)));
        put(hex_digit(u32::from(*byte)));
    }
    put(b';');
    Ok(needed)
}

fn hex_digit(nibble: u32) -> u8 {
    HEX.get((nibble & 0xF) as usize).copied().unwrap_or(b'0')
}

fn hex_value(byte: u8) -> Option<u8> {
    match byte {
        b'0'..=b'9' => Some(byte - b'0'),
        b'A'..=b'F' => Some(byte - b'A' + 10),
        b'a'..=b'f' => Some(byte - b'a' + 10),
        _ => None,
    }
}

/// What was wrong with the text. The decoder has already resynchronised when it reports one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum GridConnectError {
    /// A character other than CR, LF, tab or space between frames (reported once per run of
    /// garbage; everything up to the next `:` is skipped).
    #[error("garbage 0x{byte:02X} between frames")]
    Garbage {
        /// The first unexpected character.
        byte: u8,
    },
    /// An unexpected character inside a frame (after `:`, not `X`/`S`, a hex digit, `N`/`R`
    /// or `;` where one belongs).
    #[error("unexpected character 0x{byte:02X} in a frame")]
    InvalidCharacter {
        /// The character.
        byte: u8,
    },
    /// `N` or `R` with no id digit before it.
    #[error("frame without id digits")]
    MissingId,
    /// The id does not fit 29 bits (`:X`) or 11 bits (`:S`).
    #[error("id does not fit the frame type")]
    IdOutOfRange,
    /// An odd number of data digits before `;`.
    #[error("odd number of data digits")]
    OddDataDigits,
    /// More than 8 data bytes.
    #[error("more than 8 data bytes")]
    TooManyDataBytes,
    /// More than [`MAX_FRAME_TEXT`] characters without `;`.
    #[error("frame text longer than {MAX_FRAME_TEXT} characters")]
    TooLong,
    /// A `:` inside a frame: the frame before it was cut off; the new one is being read.
    #[error("frame cut off by a new ':'")]
    Truncated,
}

/// Counters of a [`GridConnectDecoder`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct DecoderStats {
    /// Extended data frames returned.
    pub frames: u64,
    /// Well-formed standard (`:S`) frames skipped.
    pub standard_ignored: u64,
    /// Well-formed remote (`R`) frames skipped.
    pub remote_ignored: u64,
    /// Errors reported.
    pub errors: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Between frames.
    Idle,
    /// Skipping garbage between frames (already reported).
    Garbage,
    /// After `:`.
    Type,
    /// Reading id digits.
    Id,
    /// Reading data digits.
    Data,
    /// Skipping the rest of a bad frame up to `;` or `:`.
    Discard,
}

/// A resumable GridConnect decoder. Memory is fixed: the frame being read, nothing else.
#[derive(Debug, Clone)]
pub struct GridConnectDecoder {
    state: State,
    extended: bool,
    remote: bool,
    id: u32,
    id_digits: usize,
    data: [u8; 8],
    len: usize,
    high_nibble: Option<u8>,
    frame_chars: usize,
    stats: DecoderStats,
}

impl Default for GridConnectDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl GridConnectDecoder {
    /// A decoder between frames.
    pub const fn new() -> Self {
        GridConnectDecoder {
            state: State::Idle,
            extended: false,
            remote: false,
            id: 0,
            id_digits: 0,
            data: [0; 8],
            len: 0,
            high_nibble: None,
            frame_chars: 0,
            stats: DecoderStats { frames: 0, standard_ignored: 0, remote_ignored: 0, errors: 0 },
        }
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// A frame has been started and not finished.
    pub fn is_mid_frame(&self) -> bool {
        matches!(self.state, State::Type | State::Id | State::Data)
    }

    /// Consumes text from the front of `input` until an extended data frame is complete
    /// (`Some(Ok)`), an error is found (`Some(Err)`, the decoder has resynchronised), or the
    /// input is used up (`None`; a partial frame is kept for the next call).
    pub fn decode(&mut self, input: &mut &[u8]) -> Option<Result<CanFrame, GridConnectError>> {
        while let Some((&byte, rest)) = input.split_first() {
            *input = rest;
            if let Some(outcome) = self.step(byte) {
                match &outcome {
                    Ok(_) => self.stats.frames = self.stats.frames.saturating_add(1),
                    Err(_) => self.stats.errors = self.stats.errors.saturating_add(1),
                }
                return Some(outcome);
            }
        }
        None
    }

    /// Decodes all of `input`, handing every frame and error to `on_result`.
    pub fn decode_all(&mut self, mut input: &[u8], mut on_result: impl FnMut(Result<CanFrame, GridConnectError>)) {
        while let Some(result) = self.decode(&mut input) {
            on_result(result);
        }
    }

    fn start(&mut self) {
        self.state = State::Type;
        self.extended = false;
        self.remote = false;
        self.id = 0;
        self.id_digits = 0;
        self.len = 0;
        self.high_nibble = None;
        self.frame_chars = 1;
    }

    fn fail(&mut self, error: GridConnectError) -> Option<Result<CanFrame, GridConnectError>> {
        self.state = State::Discard;
        Some(Err(error))
    }

    fn step(&mut self, byte: u8) -> Option<Result<CanFrame, GridConnectError>> {
        if self.is_mid_frame() {
            if byte == b':' {
                self.start();
                return Some(Err(GridConnectError::Truncated));
            }
            self.frame_chars += 1;
            if self.frame_chars > MAX_FRAME_TEXT {
                return self.fail(GridConnectError::TooLong);
            }
        }
        match self.state {
            State::Idle | State::Garbage | State::Discard if byte == b':' => {
                self.start();
                None
            }
            State::Idle if matches!(byte, b' ' | b'\t' | b'\r' | b'\n') => None,
            State::Idle => {
                self.state = State::Garbage;
                Some(Err(GridConnectError::Garbage { byte }))
            }
            State::Garbage => None,
            State::Discard => {
                if byte == b';' {
                    self.state = State::Idle;
                }
                None
            }
            State::Type => {
                match byte {
                    b'X' | b'x' => self.extended = true,
                    b'S' | b's' => self.extended = false,
                    _ => return self.fail(GridConnectError::InvalidCharacter { byte }),
                }
                self.state = State::Id;
                None
            }
            State::Id => self.on_id_char(byte),
            State::Data => self.on_data_char(byte),
        }
    }

    fn on_id_char(&mut self, byte: u8) -> Option<Result<CanFrame, GridConnectError>> {
        let max = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        if let Some(digit) = hex_value(byte) {
            if self.id > max >> 4 {
                return self.fail(GridConnectError::IdOutOfRange);
            }
            self.id = self.id << 4 | u32::from(digit);
            self.id_digits += 1;
            if self.id > max {
                return self.fail(GridConnectError::IdOutOfRange);
            }
            return None;
        }
        match byte {
            b'N' | b'n' | b'R' | b'r' if self.id_digits == 0 => self.fail(GridConnectError::MissingId),
            b'N' | b'n' => {
                self.state = State::Data;
                None
            }
            b'R' | b'r' => {
                self.remote = true;
                self.state = State::Data;
                None
            }
            _ => self.fail(GridConnectError::InvalidCharacter { byte }),
        }
    }

    fn on_data_char(&mut self, byte: u8) -> Option<Result<CanFrame, GridConnectError>> {
        if let Some(digit) = hex_value(byte) {
            match self.high_nibble.take() {
                None => self.high_nibble = Some(digit),
                Some(high) => {
                    let Some(slot) = self.data.get_mut(self.len) else {
                        return self.fail(GridConnectError::TooManyDataBytes);
                    };
                    *slot = high << 4 | digit;
                    self.len += 1;
                }
            }
            return None;
        }
        if byte != b';' {
            return self.fail(GridConnectError::InvalidCharacter { byte });
        }
        if self.high_nibble.is_some() {
            self.state = State::Idle;
            return Some(Err(GridConnectError::OddDataDigits));
        }
        self.state = State::Idle;
        let data = self.data.get(..self.len).unwrap_or(&[]);
        if self.remote {
            self.stats.remote_ignored = self.stats.remote_ignored.saturating_add(1);
            return None;
        }
        if !self.extended {
            self.stats.standard_ignored = self.stats.standard_ignored.saturating_add(1);
            return None;
        }
        CanFrame::extended(self.id, data).map(Ok)
    }
}

#[cfg(test)]
mod tests {
    use embedded_can::Frame;

    use super::*;

    fn text(frame: &CanFrame) -> String {
        let mut buf = [0u8; MAX_ENCODED_LEN];
        let n = encode(frame, &mut buf).unwrap();
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    #[test]
    fn encodes_extended_frames_with_eight_upper_case_digits() {
        let frame = CanFrame::extended(0x195B_4576, &[0xF0, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7]).unwrap();
        assert_eq!(text(&frame), ":X195B4576NF0F1F2F3F4F5F6F7;");
        assert_eq!(text(&CanFrame::extended(0x1070_0123, &[]).unwrap()), ":X10700123N;");
        assert_eq!(text(&CanFrame::extended(0x0000_0ABC, &[0xab]).unwrap()), ":X00000ABCNAB;");
    }

    #[test]
    fn encodes_standard_and_remote_frames() {
        let standard = CanFrame::standard(0x72D, &[0xF0, 0xF1]).unwrap();
        assert_eq!(text(&standard), ":S72DNF0F1;");
        let remote = CanFrame::new_remote(embedded_can::ExtendedId::new(0x1910_0123).unwrap(), 0).unwrap();
        assert_eq!(text(&remote), ":X19100123R;");
    }

    #[test]
    fn encode_refuses_a_short_buffer() {
        let frame = CanFrame::extended(0x1070_0123, &[]).unwrap();
        let mut buf = [0u8; 11];
        assert_eq!(encode(&frame, &mut buf), Err(BufferTooSmall { needed: 12, got: 11 }));
        let mut fixed = [0u8; 11];
        assert_eq!(encode_to(&frame, &mut &mut fixed[..]), Err(BufferTooSmall { needed: 12, got: 11 }));
        let mut growable = Vec::from(&b"x"[..]);
        assert_eq!(encode_to(&frame, &mut growable), Ok(12));
        assert_eq!(growable.len(), 13, "appended after what was there");
    }
}
