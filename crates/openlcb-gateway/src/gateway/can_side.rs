//! Aliases on behalf of full-format nodes (login, defence, resolution) and the CAN output.

use alloc::collections::VecDeque;

use openlcb_can::{CanFrame, CanHeader, Fragments, FrameKind, LoginEvent, NodeAlias, ReassemblyError, ReassemblyKey};
use openlcb_stream::{Instant, Message, Mti, NodeId};

use super::{
    ALIAS_RETRIES, CanBound, EVENT_BOUND, Gateway, InFlight, Readiness, Ready, Waiting, bump, raw_frame_bound,
};
use crate::proxy::Proxy;
use crate::{GatewayEvent, Side, StreamEnd, StreamKey};

impl Gateway {
    // ----- aliases -----

    /// The proxied node holding the permitted `alias`.
    pub(super) fn proxied_node(&self, alias: NodeAlias) -> Option<NodeId> {
        self.proxies.iter().find(|p| p.permitted_alias() == Some(alias)).map(|p| p.node)
    }

    /// Finds or starts the proxy of `node`, evicting the least recently used idle one if the
    /// table is full. False if no entry could be had.
    pub(super) fn ensure_proxy(&mut self, now: Instant, node: NodeId) -> bool {
        if let Some(proxy) = self.proxies.iter_mut().find(|p| p.node == node) {
            // Messages of a node that left may still come in after its departure (they were
            // on their way): they go out with the rest of its traffic, the proxy stays leaving.
            proxy.last_used = now;
            return true;
        }
        if self.proxies.len() >= self.config.max_proxied_nodes {
            let idle = self
                .proxies
                .iter()
                .enumerate()
                .filter(|(_, p)| self.proxy_is_idle(p))
                .min_by_key(|(_, p)| p.last_used)
                .map(|(index, _)| index);
            let Some(index) = idle else { return false };
            self.release_proxy(index);
        }
        // Held messages for it were for a full-format node: they reached it on its own side.
        let local = self.drop_waiting(|message| message.destination == Some(node));
        self.stats.stayed_local = self.stats.stayed_local.saturating_add(local as u64);
        self.proxies.push(Proxy::new(now, node, self.config.reserve_wait));
        let index = self.proxies.len() - 1;
        self.avoid_taken_alias(index);
        true
    }

    /// Forgets the proxy at `index`, with an AMR for the alias it held (CFT §6.2.5). Its
    /// Node ID may then log in from the CAN side.
    fn release_proxy(&mut self, index: usize) -> Option<NodeAlias> {
        let proxy = self.proxies.swap_remove(index);
        let alias = proxy.permitted_alias()?;
        let amr = CanFrame::from_header(&CanHeader::control(FrameKind::AliasMapReset, alias), &proxy.node.to_bytes());
        self.queue_raw(amr);
        Some(alias)
    }

    /// A full-format node is gone. Its streams as destination end; what it sent still goes to
    /// CAN (its streams as source go on to their Complete), for at most
    /// [`GatewayConfig::departed_grace`](crate::GatewayConfig::departed_grace). Then its proxy
    /// alias is released ([`release_departed`](Self::release_departed)).
    pub(super) fn full_node_left(&mut self, now: Instant, node: NodeId) {
        let Some(proxy) = self.proxies.iter_mut().find(|p| p.node == node) else { return };
        proxy.left_at.get_or_insert(now);
        let mut index = 0;
        while let Some(stream) = self.streams.get(index) {
            if stream.key.destination == node {
                self.end_stream(index, StreamEnd::NodeGone);
            } else {
                index += 1;
            }
        }
        self.release_departed(now);
    }

    /// Releases the proxies of departed nodes whose traffic has all gone out, or whose grace
    /// ran out at `now`: their streams end, what is left of theirs (and held for an alias)
    /// is dropped (and counted), and an AMR releases the alias, so that the Node ID may log
    /// in on the CAN side.
    pub(super) fn release_departed(&mut self, now: Instant) {
        let grace = self.config.departed_grace;
        let mut index = 0;
        while let Some(proxy) = self.proxies.get(index) {
            let due = proxy.left_at.is_some_and(|left| left + grace <= now || !self.still_sending(proxy));
            if !due {
                index += 1;
                continue;
            }
            let node = proxy.node;
            let alias = proxy.any_alias();
            self.end_streams_of(node, StreamEnd::NodeGone);
            if let Some(alias) = alias {
                self.drop_ready(|source, _| source == alias);
            }
            let dropped = self.drop_waiting(|message| message.source == node);
            self.count_lost(dropped);
            let alias = self.release_proxy(index);
            self.event(GatewayEvent::ProxyReleased { node, alias });
        }
    }

    /// When the grace of a departed node runs out, if one is waiting.
    pub(super) fn departed_deadline(&self) -> Option<Instant> {
        self.proxies.iter().filter_map(|p| p.left_at).min().map(|left| left + self.config.departed_grace)
    }

    /// Drops the held messages that `matches`; returns how many.
    fn drop_waiting(&mut self, matches: impl Fn(&Message) -> bool) -> usize {
        let (held, kept): (VecDeque<_>, _) =
            core::mem::take(&mut self.waiting).into_iter().partition(|w| matches(&w.item.message));
        self.waiting = kept;
        for waiting in &held {
            self.discard(&waiting.item);
        }
        held.len()
    }

    /// No stream and nothing queued involves the proxy's node or alias.
    pub(super) fn proxy_is_idle(&self, proxy: &Proxy) -> bool {
        let node = proxy.node;
        let to_it = self.streams.iter().any(|s| s.key.destination == node);
        let waiting = self.waiting.iter().any(|w| w.item.message.source == node);
        !(to_it || waiting || self.still_sending(proxy))
    }

    /// The proxy's node still has traffic going out to CAN: a stream of which it is the
    /// source, or messages of it ready or being framed. (For a departed node, messages still
    /// held for an alias do not count: they may wait a whole resolve timeout, and its Node ID
    /// may be back on CAN before that.)
    fn still_sending(&self, proxy: &Proxy) -> bool {
        let alias = proxy.any_alias();
        let source = self.streams.iter().any(|s| s.key.source == proxy.node);
        let queued = self.control.iter().chain(self.data.iter()).any(|r| Some(r.source) == alias);
        let sending = self.current_control.iter().chain(self.current_data.iter()).any(|c| Some(c.source) == alias);
        source || queued || sending
    }

    /// While the proxy's tentative alias is known to be taken (by another proxy or a CAN
    /// node in the cache), makes its login move on to the next alias of its generator.
    pub(super) fn avoid_taken_alias(&mut self, index: usize) {
        for _ in 0..ALIAS_RETRIES {
            let Some(alias) = self.proxies.get(index).and_then(Proxy::checking_alias) else { return };
            let by_proxy = self.proxies.iter().enumerate().any(|(i, p)| i != index && p.any_alias() == Some(alias));
            if !by_proxy && self.cache.peek_node(alias).is_none() {
                return;
            }
            // The login treats any frame from its tentative alias as a conflict.
            let now = self.now;
            if let Some(proxy) = self.proxies.get_mut(index) {
                proxy.login.handle_header(now, &CanHeader::control(FrameKind::ReserveId, alias), &[]);
                while proxy.login.poll_event().is_some() {}
            }
        }
    }

    pub(super) fn drain_login_events(&mut self, now: Instant) {
        for index in 0..self.proxies.len() {
            while let Some(event) = self.proxies.get_mut(index).and_then(|p| p.login.poll_event()) {
                let Some(node) = self.proxies.get(index).map(|p| p.node) else { break };
                match event {
                    LoginEvent::Permitted { alias } => {
                        if let Some(proxy) = self.proxies.get_mut(index) {
                            proxy.announced = Some(alias);
                        }
                        self.event(GatewayEvent::ProxyPermitted { node, alias });
                        self.retry_waiting(now);
                    }
                    LoginEvent::Lost { alias } => {
                        self.proxy_alias_gone(node, alias);
                        self.event(GatewayEvent::ProxyAliasLost { node, alias });
                        self.avoid_taken_alias(index);
                    }
                    LoginEvent::DuplicateNodeId { other } => {
                        // The proxy leaves the CAN side: AMR, then nothing more (CFT §6.2.5).
                        if let Some(proxy) = self.proxies.get_mut(index) {
                            proxy.login.release();
                        }
                        self.end_streams_of(node, StreamEnd::NodeGone);
                        if let Some(alias) = self.proxies.get(index).and_then(|p| p.announced) {
                            self.drop_ready(|source, _| source == alias);
                        }
                        self.retry_waiting(now);
                        self.event(GatewayEvent::DuplicateNodeId { node, other });
                    }
                    LoginEvent::Conflict { .. } => self.avoid_taken_alias(index),
                    _ => {}
                }
            }
        }
    }

    /// A proxy lost `alias`: what was queued from it is dropped, its streams are over.
    pub(super) fn proxy_alias_gone(&mut self, node: NodeId, alias: NodeAlias) {
        self.end_streams_of(node, StreamEnd::NodeGone);
        self.drop_ready(|source, _| source == alias);
    }

    /// A CAN datagram addressed to a proxy alias could not be reassembled: counted, and
    /// answered with Datagram Rejected from that proxy alias to the sender (DG §7.3.2), if
    /// the alias is still held.
    pub(super) fn datagram_failed(&mut self, key: ReassemblyKey, error: ReassemblyError) {
        self.stats.datagram_errors.record(error);
        if self.proxied_node(key.destination).is_none() {
            return;
        }
        let code = error.datagram_code().0.to_be_bytes();
        let rejected = Fragments::new(Mti::DATAGRAM_REJECTED, key.destination, Some(key.source), code)
            .ok()
            .and_then(|mut f| f.next());
        self.queue_raw(rejected);
    }

    /// A CAN node released its alias (AMR): forget it, drop what was queued for it, end its
    /// streams.
    pub(super) fn can_node_left(&mut self, alias: NodeAlias) {
        self.reassembly.forget_source(alias);
        self.datagrams.forget_source(alias);
        if let Some(node) = self.cache.remove_alias(alias) {
            self.end_streams_of(node, StreamEnd::NodeGone);
        }
        self.drop_ready(|_, destination| destination == Some(alias));
    }

    /// Drops queued messages (and the message being sent) whose aliases match.
    pub(super) fn drop_ready(&mut self, matches: impl Fn(NodeAlias, Option<NodeAlias>) -> bool) {
        let mut dropped = 0;
        for data in [false, true] {
            let queue = core::mem::take(if data { &mut self.data } else { &mut self.control });
            let mut kept = VecDeque::with_capacity(queue.len());
            for ready in queue {
                if matches(ready.source, ready.destination) {
                    self.discard(&ready.item);
                    dropped += 1;
                } else {
                    kept.push_back(ready);
                }
            }
            *(if data { &mut self.data } else { &mut self.control }) = kept;
        }
        if self.current_control.as_ref().is_some_and(|c| matches(c.source, c.destination)) {
            self.current_control = None;
            dropped += 1;
        }
        if self.current_data.as_ref().is_some_and(|d| matches(d.source, d.destination)) {
            self.cut_current_data();
            dropped += 1;
        }
        self.count_lost(dropped);
    }

    /// Stops sending the data message in progress and undoes the accounting of what is left.
    pub(super) fn cut_current_data(&mut self) {
        if let Some(in_flight) = self.current_data.take() {
            match in_flight.stream {
                Some(key) => {
                    if let Some(stream) = self.streams.iter_mut().find(|s| s.key == key) {
                        stream.queued = stream.queued.saturating_sub(in_flight.bytes_left);
                    }
                }
                None => self.untracked_backlog = self.untracked_backlog.saturating_sub(in_flight.bytes_left),
            }
            self.stats.data_bytes_dropped = self.stats.data_bytes_dropped.saturating_add(in_flight.bytes_left as u64);
        }
    }

    pub(super) fn count_lost(&mut self, n: usize) {
        self.stats.lost_with_alias = self.stats.lost_with_alias.saturating_add(n as u64);
    }

    /// Records `alias` <-> `node` for a CAN node and sends on what waited for it.
    pub(super) fn learn(&mut self, now: Instant, alias: NodeAlias, node: NodeId) {
        if self.proxies.iter().any(|p| p.node == node) {
            return;
        }
        self.cache.insert(alias, node);
        self.retry_waiting(now);
    }

    // ----- CAN side out -----

    pub(super) fn send_toward(&mut self, now: Instant, side: Side, message: Message) {
        match side {
            Side::Full => self.emit_full(message),
            Side::Can => self.route_to_can(now, CanBound::control(message)),
        }
    }

    pub(super) fn emit_full(&mut self, message: Message) {
        self.to_full.push_back(message);
    }

    pub(super) fn readiness(&self, item: &CanBound) -> Readiness {
        let Some(proxy) = self.proxies.iter().find(|p| p.node == item.message.source) else {
            return Readiness::Undeliverable;
        };
        if proxy.is_stopped() {
            return Readiness::Undeliverable;
        }
        let Some(source) = proxy.permitted_alias() else { return Readiness::AwaitSource };
        match item.message.destination.filter(|_| item.message.mti.is_addressed()) {
            None => Readiness::Ready(source, None),
            Some(node) => match self.cache.peek_alias(node) {
                Some(alias) => Readiness::Ready(source, Some(alias)),
                None => Readiness::AwaitDestination { source, node },
            },
        }
    }

    /// Queues a message for CAN, or holds it until its aliases are known.
    pub(super) fn route_to_can(&mut self, now: Instant, item: CanBound) {
        match self.readiness(&item) {
            Readiness::Ready(source, destination) => self.queue_ready(Ready { item, source, destination }),
            Readiness::Undeliverable => {
                self.discard(&item);
                self.count_lost(1);
            }
            Readiness::AwaitSource | Readiness::AwaitDestination { .. } => {
                if self.waiting.len() >= self.config.max_held_messages {
                    self.discard(&item);
                    return bump(&mut self.stats.queue_overflows);
                }
                self.waiting.push_back(Waiting { item, deadline: None });
                self.send_enquiries(now);
            }
        }
    }

    pub(super) fn queue_ready(&mut self, ready: Ready) {
        if ready.item.data_of.is_some() && ready.item.data_len() > 0 {
            self.data.push_back(ready);
        } else if self.control.len() < self.config.max_queued_messages {
            self.control.push_back(ready);
        } else {
            bump(&mut self.stats.queue_overflows);
        }
    }

    /// Undoes the accounting of a message for CAN that will never be sent.
    pub(super) fn discard(&mut self, item: &CanBound) {
        let len = item.data_len();
        match item.data_of {
            Some(Some(key)) => {
                if let Some(stream) = self.streams.iter_mut().find(|s| s.key == key) {
                    stream.queued = stream.queued.saturating_sub(len);
                }
                self.stats.data_bytes_dropped = self.stats.data_bytes_dropped.saturating_add(len as u64);
            }
            Some(None) => self.untracked_backlog = self.untracked_backlog.saturating_sub(len),
            None => {}
        }
    }

    /// Moves held messages whose aliases are now known to the queues, in arrival order.
    pub(super) fn retry_waiting(&mut self, now: Instant) {
        let mut index = 0;
        while let Some(waiting) = self.waiting.get(index) {
            match self.readiness(&waiting.item) {
                Readiness::Ready(source, destination) => {
                    if let Some(waiting) = self.waiting.remove(index) {
                        self.queue_ready(Ready { item: waiting.item, source, destination });
                    }
                }
                Readiness::Undeliverable => {
                    if let Some(waiting) = self.waiting.remove(index) {
                        self.discard(&waiting.item);
                        self.count_lost(1);
                    }
                }
                _ => index += 1,
            }
        }
        self.send_enquiries(now);
    }

    /// Sends an AME for each destination that held messages wait for and that has none out.
    pub(super) fn send_enquiries(&mut self, now: Instant) {
        let deadline = now + self.config.resolve_timeout;
        for index in 0..self.waiting.len() {
            let Some(waiting) = self.waiting.get(index) else { break };
            if waiting.deadline.is_some() {
                continue;
            }
            let Readiness::AwaitDestination { source, node } = self.readiness(&waiting.item) else { continue };
            for other in self.waiting.iter_mut().filter(|w| w.item.message.destination == Some(node)) {
                other.deadline = other.deadline.or(Some(deadline));
            }
            let enquiry =
                CanFrame::from_header(&CanHeader::control(FrameKind::AliasMapEnquiry, source), &node.to_bytes());
            self.queue_raw(enquiry);
        }
    }

    /// Drops the messages whose destination could not be found in time.
    pub(super) fn expire_resolutions(&mut self, now: Instant) {
        while let Some(node) =
            self.waiting.iter().find(|w| w.deadline.is_some_and(|d| d <= now)).and_then(|w| w.item.message.destination)
        {
            let mut dropped = 0;
            let mut index = 0;
            while let Some(waiting) = self.waiting.get(index) {
                if waiting.item.message.destination == Some(node) {
                    if let Some(waiting) = self.waiting.remove(index) {
                        self.discard(&waiting.item);
                        dropped += 1;
                    }
                } else {
                    index += 1;
                }
            }
            self.stats.unresolved_dropped = self.stats.unresolved_dropped.saturating_add(dropped as u64);
            self.event(GatewayEvent::Unreachable { node, dropped });
        }
    }

    pub(super) fn queue_raw(&mut self, frame: Option<CanFrame>) {
        match frame {
            Some(frame) if self.raw_frames.len() < raw_frame_bound(&self.config) => self.raw_frames.push_back(frame),
            _ => bump(&mut self.stats.queue_overflows),
        }
    }

    pub(super) fn next_can_frame(&mut self) -> Option<CanFrame> {
        if let Some(frame) = self.proxies.iter_mut().find_map(|p| p.login.poll_transmit()) {
            return Some(frame);
        }
        if let Some(frame) = self.raw_frames.pop_front() {
            return Some(frame);
        }
        loop {
            if let Some(frame) = self.current_control.as_mut().and_then(|c| c.fragments.next()) {
                return Some(frame);
            }
            self.current_control = None;
            let Some(ready) = self.control.pop_front() else { break };
            match InFlight::start(ready) {
                Ok(in_flight) => self.current_control = Some(in_flight),
                Err(_) => bump(&mut self.stats.not_forwardable),
            }
        }
        loop {
            if let Some(in_flight) = self.current_data.as_mut()
                && let Some(frame) = in_flight.fragments.next()
            {
                let len = frame.payload().len().saturating_sub(1);
                in_flight.bytes_left = in_flight.bytes_left.saturating_sub(len);
                let stream = in_flight.stream;
                self.data_frame_sent(stream, len);
                return Some(frame);
            }
            self.current_data = None;
            let Some(ready) = self.data.pop_front() else {
                // Everything is out: the AMR of a departed node whose traffic went with it.
                self.release_departed(self.now);
                return self.raw_frames.pop_front();
            };
            let item_len = ready.item.data_len();
            let stream = ready.item.data_of.flatten();
            match InFlight::start(ready) {
                Ok(in_flight) => self.current_data = Some(in_flight),
                Err(_) => {
                    bump(&mut self.stats.not_forwardable);
                    self.data_frame_sent(stream, item_len);
                }
            }
        }
    }

    /// A data frame of `stream` carrying `len` payload bytes left: the buffer shrinks, and
    /// what waited for it to drain may go.
    pub(super) fn data_frame_sent(&mut self, stream: Option<StreamKey>, len: usize) {
        let Some(key) = stream else {
            self.untracked_backlog = self.untracked_backlog.saturating_sub(len);
            return;
        };
        let Some(index) = self.streams.iter().position(|s| s.key == key) else { return };
        let Some(stream) = self.streams.get_mut(index) else { return };
        stream.queued = stream.queued.saturating_sub(len);
        if stream.queued == 0 {
            let now = self.now;
            self.settle(now, index);
        }
    }

    pub(super) fn event(&mut self, event: GatewayEvent) {
        if self.events.len() < EVENT_BOUND {
            self.events.push_back(event);
        }
    }
}
