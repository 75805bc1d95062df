//! The runtime every firmware of this package shares, so that the flash budget compares like
//! with like: cortex-m-rt's reset and vector table, an `embedded-alloc` heap, a panic handler
//! and a HardFault handler that end the run with a failure status through semihosting, and
//! opaque input and output for the size firmwares (volatile memory the optimiser cannot see
//! through, so nothing under measurement is folded away).
//!
//! Only unsafe code here: handing the heap its memory, and the volatile accesses.

#![no_std]

use core::mem::MaybeUninit;
use core::panic::PanicInfo;

use cortex_m_rt::{ExceptionFrame, exception};
use cortex_m_semihosting::{debug, hio};
use embedded_alloc::LlffHeap;

/// Bytes of RAM given to the heap (of the lm3s6965's 64 KiB; the rest is static data and stack).
pub const HEAP_SIZE: usize = 40 * 1024;

/// The global allocator. `HEAP.used()` is what the transfer reports.
#[global_allocator]
pub static HEAP: LlffHeap = LlffHeap::empty();

/// Gives the heap its memory. Call once, first thing in `main`.
pub fn init_heap() {
    static mut HEAP_MEM: [MaybeUninit<u8>; HEAP_SIZE] = [MaybeUninit::uninit(); HEAP_SIZE];
    // SAFETY: called once at start-up, before any allocation; HEAP_MEM is used by nothing else.
    #[allow(unsafe_code)]
    unsafe {
        HEAP.init(&raw mut HEAP_MEM as usize, HEAP_SIZE)
    }
}

/// Writes `text` to the host's stdout (no formatting machinery).
pub fn write(text: &str) {
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_all(text.as_bytes());
    }
}

/// Ends the run: QEMU exits with status 0 on success, 1 on failure.
pub fn exit(success: bool) -> ! {
    debug::exit(if success { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    // Without a debugger attached, `exit` returns: stop here.
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(_info: &PanicInfo<'_>) -> ! {
    write("FAIL: panicked\n");
    exit(false)
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    write("FAIL: HardFault\n");
    exit(false)
}

#[exception]
unsafe fn DefaultHandler(_irq: i16) {
    write("FAIL: unexpected exception\n");
    exit(false)
}

/// Opaque input and output for the size firmwares: a fake mailbox in RAM that only volatile
/// accesses touch, so the optimiser must keep every path that depends on it.
pub mod opaque {
    use core::ptr::{addr_of, addr_of_mut, read_volatile, write_volatile};

    static mut INPUT: [u8; 16] = [0; 16];
    static mut OUTPUT: u32 = 0;

    /// A value the optimiser cannot predict.
    pub fn input() -> u32 {
        // SAFETY: a plain read of a static only volatile accesses touch; single core.
        #[allow(unsafe_code)]
        unsafe {
            read_volatile(addr_of!(INPUT).cast::<u32>())
        }
    }

    /// Fills `buf` with bytes the optimiser cannot predict.
    pub fn input_bytes(buf: &mut [u8]) {
        for (i, byte) in buf.iter_mut().enumerate() {
            // SAFETY: as in `input`; the index stays inside the array.
            #[allow(unsafe_code)]
            unsafe {
                *byte = read_volatile(addr_of!(INPUT).cast::<u8>().add(i % 16));
            }
        }
    }

    /// Consumes `value` so that whatever computed it is kept.
    pub fn output(value: u32) {
        // SAFETY: a plain write of a static only volatile accesses touch; single core.
        #[allow(unsafe_code)]
        unsafe {
            write_volatile(addr_of_mut!(OUTPUT), value)
        }
    }
}

/// What the size firmwares run: the baseline's allocator work, then every input, command and
/// output of the part under measurement, each driven by opaque input so that both stream
/// roles and every path stay in the binary.
pub mod exercise {
    extern crate alloc;

    use alloc::vec::Vec;

    use embedded_can::nb::Can;
    use openlcb_can::{CanConfig, CanFrame, CanLink, LinkEvent};
    use openlcb_stream::wire::{ErrorCode, ReplyCode};
    use openlcb_stream::{
        AcceptPolicy, Config, Event, Instant, MessageRef, Mti, NodeId, OpenOptions, PeerChange, StreamEndpoint,
    };

    use openlcb_node::{DatagramAnswer, MemoryServer, Node, NodeConfig, NodeEvent, OkFlags, RamSpace};

    use crate::opaque::{input, input_bytes, output};

    /// The body of every size firmware: gives the heap its memory, builds the state under
    /// measurement with `setup`, then forever does the baseline's work and one `turn` on it.
    pub fn run<S>(setup: impl FnOnce() -> S, mut turn: impl FnMut(&mut S)) -> ! {
        crate::init_heap();
        let mut state = setup();
        let mut buf = Vec::new();
        loop {
            baseline_turn(&mut buf);
            turn(&mut state);
        }
    }

    /// The baseline's work: allocate, grow, fill, copy, move and free a buffer of opaque
    /// size. Copying and moving link the compiler runtime's `memcpy` and `memmove` (and
    /// `resize` its `memset`), which every firmware has: the increments are the OpenLCB
    /// code's own.
    fn baseline_turn(buf: &mut Vec<u8>) {
        buf.resize(input() as usize & 0xFFF, 0);
        input_bytes(buf);
        let half = buf.len() / 2;
        let (front, back) = buf.split_at_mut(half);
        if let Some(back) = back.get_mut(..front.len()) {
            back.copy_from_slice(front);
        }
        buf.copy_within(input() as usize % (half + 1).., 0);
        output(buf.iter().map(|b| u32::from(*b)).sum());
        // The same on word-aligned memory, of opaque length (the runtime's aligned variants:
        // `__aeabi_memcpy8`, `__aeabi_memmove8`, `__aeabi_memclr8`).
        let mut words = [0u64; 16];
        let n = input() as usize % words.len();
        if let Some(part) = words.get_mut(..n) {
            part.fill(u64::from(input()));
        }
        let (low, high) = words.split_at_mut(8);
        let m = n % 8;
        if let (Some(to), Some(from)) = (low.get_mut(..m), high.get(..m)) {
            to.copy_from_slice(from);
        }
        if let Some(part) = low.get_mut(n / 2..) {
            part.fill(0);
        }
        words.copy_within(n / 4..n, 0);
        let mut cleared = [0u32; 16];
        if let Some(part) = cleared.get_mut(..n) {
            part.fill(0);
        }
        output(words.iter().map(|w| *w as u32).sum::<u32>() + cleared.iter().sum::<u32>());
        buf.fill(0);
        if input() == 0 {
            *buf = Vec::new();
        }
    }

    fn node_id() -> NodeId {
        NodeId::new(u64::from(input()) << 16 | u64::from(input() & 0xFFFF)).unwrap_or(NodeId::MAX)
    }

    fn now() -> Instant {
        Instant::from_micros(u64::from(input()))
    }

    /// A peer change chosen by input: `peer` lost, or renamed to an opaque Node ID.
    fn peer_change(peer: NodeId, word: u16) -> PeerChange {
        if word & 1 == 0 { PeerChange::Lost(peer) } else { PeerChange::Renamed { from: peer, to: node_id() } }
    }

    /// An endpoint for an opaque Node ID, with the accept policy chosen by input.
    pub fn endpoint() -> StreamEndpoint {
        let mut config = Config::default();
        if input() & 1 == 1 {
            config.accept_policy = AcceptPolicy::Ask;
        }
        config.early_proceed = input() & 2 == 2;
        StreamEndpoint::new(node_id(), config)
    }

    /// A link for an opaque Node ID.
    pub fn link() -> CanLink {
        CanLink::new(now(), node_id(), CanConfig::default())
    }

    /// One opaque command of either role on any stream of `$streams` (a `StreamEndpoint`, or
    /// a node's `Streams` view: the command names are the same), or one of the `$arm`s.
    macro_rules! stream_turn {
        ($streams:ident, $now:ident, $op:ident, $peer:ident, $word:ident, $data:ident; $($arm:pat => $body:expr,)*) => {{
            let $now = now();
            let $op = input();
            let mut payload = [0u8; 64];
            input_bytes(&mut payload);
            let len = ($op >> 8) as usize % payload.len();
            let $data = payload.get(..len).unwrap_or(&[]);
            let handle = $streams.handles().nth(($op >> 4) as usize & 3);
            let $peer = node_id();
            let $word = ($op >> 16) as u16;
            match ($op & 0xF, handle) {
                $($arm => $body,)*
                (2, _) => output($streams.open($now, OpenOptions::new($peer, $word)).is_ok().into()),
                (3, Some(h)) => output($streams.write($now, h, $data).unwrap_or(0) as u32),
                (4, Some(h)) => output($streams.flush($now, h).is_ok().into()),
                (5, Some(h)) => output($streams.finish($now, h).is_ok().into()),
                (6, Some(h)) => output($streams.accept($now, h, Some($word)).is_ok().into()),
                (7, Some(h)) => output($streams.reject($now, h, ReplyCode($word)).is_ok().into()),
                (8, Some(h)) => output($streams.read($now, h, &mut payload).unwrap_or(0) as u32),
                (9, Some(h)) => output($streams.abort($now, h, ErrorCode($word)).is_ok().into()),
                (10, Some(h)) => output($streams.credit(h).unwrap_or(0)),
                _ => {}
            }
        }};
    }

    /// One opaque input or command into the endpoint: a received message, a timeout, or any
    /// command of either role on any of its streams.
    pub fn endpoint_turn(endpoint: &mut StreamEndpoint) {
        stream_turn!(endpoint, now, op, peer, word, data;
            (0, _) => {
                let destination = (op & 0x10 != 0).then(|| endpoint.node_id());
                endpoint.handle_message(now, MessageRef { mti: Mti(word), source: peer, destination, payload: data });
            },
            (1, _) => endpoint.handle_timeout(now),
            (11, _) => endpoint.peer_changed(peer_change(peer, word)),
            (12, _) => endpoint.link_lost(),
        )
    }

    /// Drains the endpoint's events and timeout into the opaque output (its transmits go to
    /// the caller: a link, or the output).
    pub fn endpoint_outputs(endpoint: &mut StreamEndpoint) {
        while let Some(event) = endpoint.poll_event() {
            output(match event {
                Event::IncomingRequest { info, .. } => u32::from(info.window),
                Event::Opened { info, .. } => 1 + u32::from(info.window),
                Event::Rejected { code, .. } => u32::from(code.0),
                Event::Readable { .. } => 3,
                Event::Writable { .. } => 4,
                Event::Finished { total, .. } => total as u32,
                Event::Terminated { .. } => 6,
                Event::TimedOut { .. } => 7,
                _ => 8,
            });
        }
        output(endpoint.poll_timeout().map_or(0, |t| t.as_micros() as u32));
    }

    /// Drains the endpoint's transmits into the opaque output.
    pub fn endpoint_transmits(endpoint: &mut StreamEndpoint) {
        while let Some(message) = endpoint.poll_transmit() {
            output(u32::from(message.mti.0) + message.payload.len() as u32);
        }
    }

    fn opaque_frame() -> Option<CanFrame> {
        let mut data = [0u8; 8];
        input_bytes(&mut data);
        let len = input() as usize % 9;
        CanFrame::extended(input(), data.get(..len).unwrap_or(&[]))
    }

    /// One opaque frame or timeout into the link, whose peer changes and messages go to the
    /// endpoint; the link's events go to the endpoint, the endpoint's transmits to the link,
    /// the link's frames to the output.
    pub fn link_turn(link: &mut CanLink, endpoint: &mut StreamEndpoint) {
        let now = now();
        if input() & 1 == 1 {
            link.handle_timeout(now, endpoint);
            endpoint.handle_timeout(now);
        } else if let Some(frame) = opaque_frame() {
            link.handle_frame(now, &frame, endpoint);
        }
        while let Some(event) = link.poll_event() {
            if let LinkEvent::AliasLost { .. } = event {
                endpoint.link_lost();
            }
        }
        while link.can_send() {
            let Some(message) = endpoint.poll_transmit() else { break };
            output(link.send(now, message).is_ok().into());
        }
        while let Some(frame) = link.poll_transmit() {
            output(frame.raw_id());
        }
        output(link.poll_timeout().map_or(0, |t| t.as_micros() as u32));
    }

    /// A node for an opaque Node ID: streams (the accept policy chosen by input), datagrams,
    /// SNIP, and a Memory Configuration server with a 256-byte RAM space 0xFD.
    pub fn node() -> Node {
        let mut config = NodeConfig::default();
        if input() & 1 == 1 {
            config.stream.accept_policy = AcceptPolicy::Ask;
        }
        Node::new(node_id(), config).with_memory_server(MemoryServer::new().with_space(0xFD, RamSpace::new(256)))
    }

    /// [`node`], and a DCC train (Traction Control, Train Search) at an opaque address.
    #[cfg(feature = "traction")]
    pub fn train_node() -> Node {
        let mut config = NodeConfig::default();
        config.train = Some(openlcb_node::traction::TrainConfig::dcc(input() % 10_240));
        Node::new(node_id(), config).with_memory_server(MemoryServer::new().with_space(0xFD, RamSpace::new(256)))
    }

    /// [`node_turn`], and the train's state read back.
    #[cfg(feature = "traction")]
    pub fn train_turn(node: &mut Node) {
        node_turn(node);
        output(node.train().map_or(0, |t| u32::from(t.commanded_speed.to_bits())));
    }

    /// One opaque input or command into the node: a received message (every MTI reaches one
    /// of its protocols), a timeout, a transport event, a datagram sent or answered, a SNIP
    /// request, or a stream command on its endpoint.
    pub fn node_turn(node: &mut Node) {
        let now = now();
        let op = input();
        let mut payload = [0u8; 72];
        input_bytes(&mut payload);
        let len = (op >> 8) as usize % payload.len();
        let data = payload.get(..len).unwrap_or(&[]);
        let peer = node_id();
        let word = (op >> 16) as u16;
        match op & 0xF {
            0 => {
                let destination = (op & 0x10 != 0).then(|| node.node_id());
                node.handle_message(now, MessageRef { mti: Mti(word), source: peer, destination, payload: data });
            }
            1 => node.handle_timeout(now),
            2 => output(node.send_datagram(now, peer, data).is_ok().into()),
            3 => output(node.answer_datagram(peer, DatagramAnswer::Ok(OkFlags::default())).is_ok().into()),
            4 => output(node.answer_datagram(peer, DatagramAnswer::Rejected(ErrorCode(word))).is_ok().into()),
            5 => output(node.request_snip(now, peer).is_ok().into()),
            6 => node.peer_changed(peer_change(peer, word)),
            7 => node.link_lost(),
            _ => {
                let mut streams = node.streams_mut();
                stream_turn!(streams, now, op, peer, word, data;)
            }
        }
        while let Some(message) = node.poll_transmit() {
            output(u32::from(message.mti.0) + message.payload.len() as u32);
        }
        while let Some(event) = node.poll_event() {
            output(match event {
                NodeEvent::DatagramReceived { datagram, .. } => datagram.as_slice().len() as u32,
                NodeEvent::SnipReceived { info, .. } => info.model.len() as u32,
                NodeEvent::Stream(Event::Readable { .. }) => 3,
                _ => 8,
            });
        }
        output(node.poll_timeout().map_or(0, |t| t.as_micros() as u32));
    }

    /// A CAN peripheral whose receive FIFO and transmit mailboxes are opaque memory.
    pub struct OpaqueCan;

    impl Can for OpaqueCan {
        type Frame = CanFrame;
        type Error = embedded_can::ErrorKind;

        fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, Self::Error> {
            match input() & 3 {
                0 => Err(nb::Error::WouldBlock),
                1 => Err(nb::Error::Other(embedded_can::ErrorKind::Other)),
                _ => {
                    output(frame.raw_id());
                    Ok(opaque_frame().filter(|_| input() & 4 == 4))
                }
            }
        }

        fn receive(&mut self) -> nb::Result<CanFrame, Self::Error> {
            match input() & 3 {
                0 => Err(nb::Error::WouldBlock),
                1 => Err(nb::Error::Other(embedded_can::ErrorKind::Overrun)),
                _ => opaque_frame().ok_or(nb::Error::WouldBlock),
            }
        }
    }
}
