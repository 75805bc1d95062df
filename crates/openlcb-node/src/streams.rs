//! The node's stream endpoint: `openlcb_stream::StreamEndpoint` with the `streams` feature;
//! without it, [`Endpoint`] is an endpoint that has no streams and takes none, so that a
//! firmware that moves nothing by stream (its image comes by datagrams) links none of the
//! stream code. The node then behaves as with [`NodeConfig::streams_enabled`] off: it does
//! not announce streams, stream messages are refused as unknown, and Memory Configuration
//! moves everything by datagrams.
//!
//! [`NodeConfig::streams_enabled`]: crate::NodeConfig::streams_enabled

#[cfg(feature = "streams")]
pub(crate) use openlcb_stream::StreamEndpoint as Endpoint;

#[cfg(not(feature = "streams"))]
pub(crate) use absent::Endpoint;

/// Streams are in use: the feature is built in and the configuration turns them on.
#[cfg(feature = "streams")]
pub(crate) fn enabled(config: &crate::NodeConfig) -> bool {
    config.streams_enabled
}

/// Streams are in use: never without the feature.
#[cfg(not(feature = "streams"))]
pub(crate) fn enabled(_config: &crate::NodeConfig) -> bool {
    false
}

/// The node's stream endpoint, bounded by its configuration.
#[cfg(feature = "streams")]
pub(crate) fn endpoint(node: openlcb_stream::NodeId, config: &crate::NodeConfig) -> Endpoint {
    Endpoint::new(node, config.stream.clone())
}

/// The node's stream endpoint: one without streams.
#[cfg(not(feature = "streams"))]
pub(crate) fn endpoint(_node: openlcb_stream::NodeId, _config: &crate::NodeConfig) -> Endpoint {
    Endpoint
}

/// What becomes of a stream request that Memory Configuration does not claim.
#[cfg(feature = "streams")]
pub(crate) fn accept_policy(config: &crate::NodeConfig) -> openlcb_stream::AcceptPolicy {
    config.stream.accept_policy
}

/// What becomes of a stream request that Memory Configuration does not claim: without an
/// endpoint none ever comes.
#[cfg(not(feature = "streams"))]
pub(crate) fn accept_policy(_config: &crate::NodeConfig) -> openlcb_stream::AcceptPolicy {
    openlcb_stream::AcceptPolicy::Ask
}

#[cfg(not(feature = "streams"))]
mod absent {
    use openlcb_stream::wire::{ErrorCode, ReplyCode};
    use openlcb_stream::{
        AcceptOptions, AcceptPolicy, Event, Instant, Message, MessageRef, NodeId, OpenOptions, PeerChange, Stats,
        StreamError, StreamHandle, StreamId, StreamInfo,
    };

    /// An endpoint without streams: it holds none, so every command on a stream finds none
    /// (`UnknownStream`), opening one finds no room (`TableFull`), and it has nothing to send,
    /// to report or to wait for.
    #[derive(Debug, Default)]
    pub(crate) struct Endpoint;

    impl Endpoint {
        pub(crate) fn handle_message(&mut self, _now: Instant, _msg: MessageRef<'_>) {}
        pub(crate) fn handle_timeout(&mut self, _now: Instant) {}
        pub(crate) fn peer_changed(&mut self, _change: PeerChange) {}
        pub(crate) fn medium_busy(&mut self, _now: Instant) {}
        pub(crate) fn link_lost(&mut self) {}
        pub(crate) fn set_accept_policy(&mut self, _policy: AcceptPolicy) {}
        pub(crate) fn poll_transmit(&mut self) -> Option<Message> {
            None
        }
        pub(crate) fn poll_event(&mut self) -> Option<Event> {
            None
        }
        pub(crate) fn poll_timeout(&self) -> Option<Instant> {
            None
        }
        pub(crate) fn stats(&self) -> Stats {
            Stats::default()
        }
        pub(crate) fn stream_info(&self, _handle: StreamHandle) -> Option<StreamInfo> {
            None
        }
        pub(crate) fn credit(&self, _handle: StreamHandle) -> Option<u32> {
            None
        }
        pub(crate) fn next_destination_id(&self, _peer: NodeId) -> Option<StreamId> {
            None
        }
        pub(crate) fn handles(&self) -> impl Iterator<Item = StreamHandle> + '_ {
            core::iter::empty()
        }
        pub(crate) fn sends_to_peer(&self, _peer: NodeId) -> bool {
            false
        }
        pub(crate) fn open(&mut self, _now: Instant, _options: OpenOptions) -> Result<StreamHandle, StreamError> {
            Err(StreamError::TableFull)
        }
        pub(crate) fn write(&mut self, _now: Instant, _h: StreamHandle, _data: &[u8]) -> Result<usize, StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn read(&mut self, _now: Instant, _h: StreamHandle, _buf: &mut [u8]) -> Result<usize, StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn finish(&mut self, _now: Instant, _h: StreamHandle) -> Result<(), StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn abort(&mut self, _now: Instant, _h: StreamHandle, _code: ErrorCode) -> Result<(), StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn accept(&mut self, _now: Instant, _h: StreamHandle, _w: Option<u16>) -> Result<(), StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn accept_with(
            &mut self,
            _now: Instant,
            _h: StreamHandle,
            _options: AcceptOptions,
        ) -> Result<(), StreamError> {
            Err(StreamError::UnknownStream)
        }
        pub(crate) fn reject(&mut self, _now: Instant, _h: StreamHandle, _code: ReplyCode) -> Result<(), StreamError> {
            Err(StreamError::UnknownStream)
        }
    }
}
