//! [`TcpLink`]: one node's adapter between the stream core's messages and an OpenLCB-TCP
//! byte stream.

use alloc::vec::Vec;

use openlcb_stream::{Instant, Message, MessageRef, NodeId};

use crate::{CaptureTime, DecodeError, Decoder, EncodeError, LinkPrefix, TcpFrame};

/// Counters of a link's traffic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct LinkStats {
    /// OpenLCB messages received and handed out by [`TcpLink::read_message`].
    pub messages_in: u64,
    /// Messages encoded for sending.
    pub messages_out: u64,
    /// Bytes received (fed to the decoder).
    pub bytes_in: u64,
    /// Bytes encoded for sending.
    pub bytes_out: u64,
    /// Received messages or parts refused by the decoder.
    pub decode_errors: u64,
    /// Messages that could not be encoded (and were dropped).
    pub encode_errors: u64,
}

/// One node's OpenLCB-TCP link: socket bytes in, [`MessageRef`]s out for
/// [`StreamEndpoint::handle_message`](openlcb_stream::StreamEndpoint::handle_message);
/// [`Message`]s from [`StreamEndpoint::poll_transmit`](openlcb_stream::StreamEndpoint::poll_transmit)
/// in, encoded bytes out for the socket. It does no I/O and reads no clock.
///
/// Every message it sends carries this node as the originating gateway and `now` in
/// milliseconds as the capture time. Stream Data Send messages go out whole, as large as the
/// core made them (up to the credit), never cut into CAN-sized pieces.
///
/// # The drive loop
///
/// - **input**: for each read from the socket, call [`read_message`](Self::read_message)
///   with the bytes until it returns `None`, passing each message to the endpoint at once
///   (it borrows the link's buffer until the next call). If [`failure`](Self::failure) is
///   then `Some`, close the connection: the peer's length field cannot be trusted.
/// - **output**: after every endpoint call (input, command or timeout), call
///   [`send_from`](Self::send_from) to drain the endpoint's transmits into the link, then
///   write [`transmit_pending`](Self::transmit_pending) to the socket and report what was
///   written with [`advance_transmit`](Self::advance_transmit).
///
/// The output buffer is reused: once the socket has taken everything, encoding more
/// allocates nothing. It holds whatever the socket has not taken yet; the endpoint's credit
/// bounds how much stream data that can be, so stop calling `send_from` while the socket is
/// blocked and the buffer stops growing too.
#[derive(Debug)]
pub struct TcpLink {
    gateway: NodeId,
    decoder: Decoder,
    /// Encoded bytes; those before `taken` have been handed to the socket.
    transmit: Vec<u8>,
    taken: usize,
    stats: LinkStats,
}

impl TcpLink {
    /// A link for the node `gateway` (written as the originating node of every message sent),
    /// decoding with the default bound ([`MAX_STREAM_DATA_LENGTH`](crate::MAX_STREAM_DATA_LENGTH)).
    pub fn new(gateway: NodeId) -> Self {
        TcpLink::with_decoder(gateway, Decoder::default())
    }

    /// A link using `decoder` (for example one with a smaller bound).
    pub fn with_decoder(gateway: NodeId, decoder: Decoder) -> Self {
        TcpLink { gateway, decoder, transmit: Vec::new(), taken: 0, stats: LinkStats::default() }
    }

    // ----- getters -----

    /// The node written as originating gateway.
    pub fn gateway(&self) -> NodeId {
        self.gateway
    }

    /// The receiving decoder (its bound, counters and state).
    pub fn decoder(&self) -> &Decoder {
        &self.decoder
    }

    /// Traffic counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Why the link must be closed, if the peer sent a length that cannot be trusted.
    pub fn failure(&self) -> Option<DecodeError> {
        self.decoder.failure()
    }

    // ----- input -----

    /// Decodes the next received message from `input`, advancing `input` past what it used;
    /// call until `None` (then `input` is empty). An `Err` reports one refused message, or,
    /// if it [closes the link](DecodeError::closes_link), the end of decoding.
    ///
    /// The link prefix is dropped here; use a [`Decoder`] directly to see it.
    pub fn read_message<'s, 'i: 's>(&'s mut self, input: &mut &'i [u8]) -> Option<Result<MessageRef<'s>, DecodeError>> {
        let before = input.len();
        let decoded = self.decoder.decode(input);
        self.stats.bytes_in = self.stats.bytes_in.saturating_add((before - input.len()) as u64);
        match &decoded {
            Some(Ok(_)) => self.stats.messages_in = self.stats.messages_in.saturating_add(1),
            Some(Err(_)) => self.stats.decode_errors = self.stats.decode_errors.saturating_add(1),
            None => {}
        }
        decoded.map(|result| result.map(|frame| frame.message))
    }

    // ----- commands -----

    /// Encodes `message` for sending, stamped with this node and `now`; returns the bytes
    /// added. A message that cannot be encoded is dropped, counted and reported.
    pub fn send(&mut self, now: Instant, message: &Message) -> Result<usize, EncodeError> {
        let prefix = LinkPrefix { gateway: self.gateway, capture_time: CaptureTime::from_instant(now) };
        match TcpFrame::new(prefix, message.as_ref()).encode_to(&mut self.transmit) {
            Ok(written) => {
                self.stats.messages_out = self.stats.messages_out.saturating_add(1);
                self.stats.bytes_out = self.stats.bytes_out.saturating_add(written as u64);
                Ok(written)
            }
            Err(error) => {
                self.stats.encode_errors = self.stats.encode_errors.saturating_add(1);
                Err(error)
            }
        }
    }

    /// Drains a node's or an endpoint's transmits into the link ([`send`](Self::send) each),
    /// usually `link.send_from(now, || node.poll_transmit())`; returns how many messages were
    /// encoded. Every message is drained even if one fails; the first failure is returned (the
    /// stack never builds such a message).
    pub fn send_from(
        &mut self,
        now: Instant,
        mut poll_transmit: impl FnMut() -> Option<Message>,
    ) -> Result<usize, EncodeError> {
        let mut sent = 0;
        let mut first_error = None;
        while let Some(message) = poll_transmit() {
            match self.send(now, &message) {
                Ok(_) => sent += 1,
                Err(error) => {
                    first_error.get_or_insert(error);
                }
            }
        }
        first_error.map_or(Ok(sent), Err)
    }

    // ----- output -----

    /// The encoded bytes the socket has not taken yet.
    pub fn transmit_pending(&self) -> &[u8] {
        self.transmit.get(self.taken..).unwrap_or_default()
    }

    /// The socket took `n` bytes of [`transmit_pending`](Self::transmit_pending) (more than
    /// are pending counts as all of them).
    pub fn advance_transmit(&mut self, n: usize) {
        self.taken = self.taken.saturating_add(n).min(self.transmit.len());
        if self.taken == self.transmit.len() {
            self.transmit.clear();
            self.taken = 0;
        } else if self.taken > self.transmit.capacity() / 2 {
            self.transmit.drain(..self.taken);
            self.taken = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use openlcb_stream::Mti;

    fn node(raw: u64) -> NodeId {
        NodeId::new(raw).unwrap()
    }

    fn data_send(len: usize) -> Message {
        let payload: Vec<u8> = (0..=len).map(|i| i as u8).collect();
        Message::addressed(Mti::STREAM_DATA_SEND, node(0x0501_0101_2200), node(0x0501_0101_2201), payload)
    }

    #[test]
    fn transmit_buffer_is_reused_once_the_socket_has_taken_it() {
        let mut link = TcpLink::new(node(0x0501_0101_2200));
        let now = Instant::from_millis(5);
        let message = data_send(2048);
        link.send(now, &message).unwrap();
        link.advance_transmit(usize::MAX);
        let (pointer, capacity) = (link.transmit.as_ptr(), link.transmit.capacity());
        for _ in 0..100 {
            assert_eq!(link.send(now, &message), Ok(2049 + 31));
            assert_eq!(link.transmit_pending().len(), 2049 + 31);
            link.advance_transmit(2049 + 31);
            assert_eq!((link.transmit.as_ptr(), link.transmit.capacity()), (pointer, capacity));
        }
        assert!(link.transmit_pending().is_empty());
        assert_eq!(link.stats().messages_out, 101);
        assert_eq!(link.stats().bytes_out, 101 * (2049 + 31));
    }

    #[test]
    fn partial_socket_writes_keep_the_bytes_in_order() {
        let mut link = TcpLink::new(node(0x0501_0101_2200));
        let mut expected = Vec::new();
        let mut written = Vec::new();
        for (i, len) in [10, 300, 0, 77, 1024].into_iter().enumerate() {
            let now = Instant::from_millis(i as u64);
            let message = data_send(len);
            let prefix = LinkPrefix { gateway: link.gateway(), capture_time: CaptureTime::from_instant(now) };
            TcpFrame::new(prefix, message.as_ref()).encode_to(&mut expected).unwrap();
            link.send(now, &message).unwrap();
            // The socket takes 100 bytes per write.
            while link.transmit_pending().len() > 100 {
                written.extend_from_slice(&link.transmit_pending()[..100]);
                link.advance_transmit(100);
            }
        }
        written.extend_from_slice(link.transmit_pending());
        link.advance_transmit(link.transmit_pending().len());
        assert_eq!(written, expected);
        assert!(link.transmit_pending().is_empty());
    }

    #[test]
    fn untrustworthy_length_reports_the_failure_and_stops_receiving() {
        let mut link = TcpLink::with_decoder(node(0x0501_0101_2201), Decoder::new(64));
        let mut input: &[u8] = &[0x80, 0x00, 0x00, 0x01, 0x00, 0xAA, 0xBB];
        let error = DecodeError::LengthTooLong { length: 256, max: 64 };
        assert_eq!(link.read_message(&mut input), Some(Err(error)));
        assert_eq!(link.read_message(&mut input), None);
        assert!(input.is_empty());
        assert_eq!(link.failure(), Some(error));
        assert_eq!(link.stats().decode_errors, 1);
        assert_eq!(link.stats().bytes_in, 7);
    }
}
