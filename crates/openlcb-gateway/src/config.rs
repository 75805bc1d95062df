//! [`GatewayConfig`]: every bound and timer of a [`Gateway`](crate::Gateway).

use openlcb_stream::Duration;

/// Bounds and timers. Every table, queue and buffer the gateway keeps is sized from here, and
/// [`memory_bound`](GatewayConfig::memory_bound) adds them up.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct GatewayConfig {
    /// Streams tracked at once. A Stream Initiate Request over the bound is still forwarded,
    /// but its stream is not tracked: its data crosses frame by frame, unmerged.
    pub max_streams: usize,
    /// The largest Max Buffer Size forwarded in a Stream Initiate Request (1..=65535): larger
    /// proposals are lowered to it (draft §7.5). It is also the most a tracked stream buffers.
    pub max_window: u16,
    /// Full-format nodes the gateway holds a CAN alias for at once. A new node over the bound
    /// takes the place of the least recently used one that has no stream and nothing queued;
    /// if there is none its message is dropped and counted.
    pub max_proxied_nodes: usize,
    /// Messages for CAN held until their source's alias is permitted or their destination's
    /// alias is known, over all nodes.
    pub max_held_messages: usize,
    /// Messages other than stream data queued for the CAN side (Replies, Proceeds, Completes,
    /// node traffic); more are dropped and counted.
    pub max_queued_messages: usize,
    /// The longest message, other than stream data, held or queued for CAN, and the longest
    /// addressed message reassembled from CAN frames, in payload bytes.
    pub max_message_len: usize,
    /// Stream data bytes of untracked streams queued for CAN; a Data Send beyond it is dropped
    /// and counted (an untracked stream has no window to bound it).
    pub max_untracked_backlog: usize,
    /// Remote (CAN) alias mappings kept, least recently used evicted first.
    pub alias_cache_size: usize,
    /// Addressed multi-frame CAN messages assembled at once.
    pub reassembly_slots: usize,
    /// How long a multi-frame CAN message may wait for its next frame, and a CAN datagram for
    /// its last frame counted from its first.
    pub reassembly_timeout: Duration,
    /// CAN datagrams (formats 3-5, at most 72 bytes) assembled at once.
    pub datagram_slots: usize,
    /// How long a proxied node's alias check waits before RID (CFT §6.2.1: at least 200 ms).
    pub reserve_wait: Duration,
    /// How long a message for CAN waits for an AME to find its destination's alias before it
    /// is dropped with [`GatewayEvent::Unreachable`](crate::GatewayEvent::Unreachable).
    pub resolve_timeout: Duration,
    /// The longest CAN stream data waits in a merge buffer before it is forwarded as a Data
    /// Send, counted from its first byte. Window boundaries, flushes and Completes forward it
    /// sooner.
    pub merge_delay: Duration,
    /// How long a Complete from CAN that overtook its data (its count is ahead of the bytes
    /// seen) waits for the rest before it is forwarded anyway.
    pub complete_wait: Duration,
    /// A tracked stream with no traffic for this long is forgotten (its source or destination
    /// went away without a word). Keep it above the endpoints' keep-alive interval.
    pub stream_idle_timeout: Duration,
    /// How long what a full-format node sent before it left may take to reach CAN (its last
    /// data and Complete); then the rest is dropped and counted, and its alias released.
    pub departed_grace: Duration,
}

impl Default for GatewayConfig {
    fn default() -> Self {
        GatewayConfig {
            max_streams: 32,
            max_window: 2048,
            max_proxied_nodes: 16,
            max_held_messages: 32,
            max_queued_messages: 64,
            max_message_len: 256,
            max_untracked_backlog: 4096,
            alias_cache_size: 64,
            reassembly_slots: 8,
            reassembly_timeout: Duration::from_secs(3),
            datagram_slots: 4,
            reserve_wait: Duration::from_millis(200),
            resolve_timeout: Duration::from_secs(1),
            merge_delay: Duration::from_millis(50),
            complete_wait: Duration::from_secs(1),
            stream_idle_timeout: Duration::from_secs(120),
            departed_grace: Duration::from_secs(5),
        }
    }
}

impl GatewayConfig {
    /// The most payload bytes the gateway can hold between calls once its full-format output
    /// has been drained: a window per tracked stream, the untracked backlog, and the held and
    /// queued messages. Fixed tables (stream and proxy entries, the alias cache, the
    /// reassembly and datagram slots) are allocated up front and not counted here.
    pub fn memory_bound(&self) -> usize {
        let streams = self.max_streams.saturating_mul(usize::from(self.max_window));
        let messages =
            self.max_held_messages.saturating_add(self.max_queued_messages).saturating_mul(self.max_message_len);
        streams.saturating_add(self.max_untracked_backlog).saturating_add(messages)
    }
}
