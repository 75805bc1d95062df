//! A CAN bus segment: exact bit time per frame (stuff bits included), arbitration by
//! identifier when the bus frees, bounded transmit queues per controller.

use std::collections::VecDeque;

use openlcb_can::CanFrame;
use openlcb_can::embedded_can::Frame as _;

/// Bits of an extended data frame that are never stuffed: CRC delimiter, ACK slot and
/// delimiter, end of frame, intermission.
const UNSTUFFED_TAIL_BITS: u32 = 1 + 2 + 7 + 3;
/// An error frame: error flag, delimiter, intermission.
const ERROR_FRAME_BITS: u32 = 6 + 8 + 3;

/// The bits a frame occupies on the wire: SOF to CRC with the stuff bits that its actual
/// contents need, then the 13 fixed tail bits. An extended frame without stuffing is
/// 67 + 8 x data bytes bits.
pub fn frame_bits(frame: &CanFrame) -> u32 {
    // SOF to the end of the data, at most 1 + 32 + 3 + 4 + 64 = 104 bits.
    let mut bits = BitString::default();
    bits.push(0, 1); // SOF
    let id = frame.raw_id();
    if frame.is_extended() {
        bits.push(u128::from(id >> 18), 11);
        bits.push(0b11, 2); // SRR, IDE
        bits.push(u128::from(id & 0x3_FFFF), 18);
        bits.push(u128::from(frame.is_remote_frame()), 1);
        bits.push(0, 2); // r1, r0
    } else {
        bits.push(u128::from(id), 11);
        bits.push(u128::from(frame.is_remote_frame()), 1);
        bits.push(0, 2); // IDE, r0
    }
    bits.push(frame.dlc() as u128, 4);
    if !frame.is_remote_frame() {
        for byte in frame.payload() {
            bits.push(u128::from(*byte), 8);
        }
    }
    let crc = crc15(&bits);
    let mut stuffing = Stuffing::default();
    stuffing.feed(&bits);
    let mut crc_bits = BitString::default();
    crc_bits.push(u128::from(crc), 15);
    stuffing.feed(&crc_bits);
    bits.len + 15 + stuffing.stuffed + UNSTUFFED_TAIL_BITS
}

/// Up to 128 bits, most significant first.
#[derive(Default)]
struct BitString {
    value: u128,
    len: u32,
}

impl BitString {
    fn push(&mut self, value: u128, width: u32) {
        self.value = (self.value << width) | (value & ((1u128 << width) - 1));
        self.len += width;
    }

    /// The bits in order: a leading partial chunk, then whole bytes.
    fn chunks(&self) -> impl Iterator<Item = (u8, u32)> + '_ {
        let head = self.len % 8;
        let head_chunk = (head > 0).then(|| ((self.value >> (self.len - head)) as u8, head));
        let bytes = (0..self.len / 8).rev().map(move |i| ((self.value >> (8 * i)) as u8, 8));
        head_chunk.into_iter().chain(bytes)
    }
}

/// CAN CRC-15, polynomial 0x4599 (ISO 11898-1), a byte at a time.
fn crc15(bits: &BitString) -> u16 {
    static TABLE: std::sync::OnceLock<[u16; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        core::array::from_fn(|byte| {
            let mut crc = (byte as u16) << 7;
            for _ in 0..8 {
                crc = if crc & 0x4000 != 0 { ((crc << 1) ^ 0x4599) & 0x7FFF } else { (crc << 1) & 0x7FFF };
            }
            crc
        })
    });
    let mut crc = 0u16;
    for (chunk, width) in bits.chunks() {
        if width == 8 {
            crc = ((crc << 8) & 0x7FFF) ^ table[usize::from(((crc >> 7) as u8) ^ chunk)];
        } else {
            for i in (0..width).rev() {
                let feedback = u16::from((chunk >> i) & 1) ^ (crc >> 14);
                crc = ((crc << 1) & 0x7FFF) ^ (0x4599 * feedback);
            }
        }
    }
    crc
}

/// Counts the stuff bits a transmitter inserts: after five equal bits, one of the other
/// value, which starts a new run. Bytes go through a table of (run state, byte) -> (run
/// state, stuff bits).
#[derive(Default)]
struct Stuffing {
    /// 0: nothing sent yet; otherwise run length 1..=4 and the run's bit.
    state: u8,
    stuffed: u32,
}

impl Stuffing {
    const STATES: usize = 9;

    /// One bit from `state`: the next state and whether a stuff bit follows.
    fn step(state: u8, bit: u8) -> (u8, bool) {
        let (run_bit, run_len) = if state == 0 { (2, 0) } else { ((state - 1) / 4, (state - 1) % 4 + 1) };
        let (run_bit, run_len) = if bit == run_bit { (bit, run_len + 1) } else { (bit, 1) };
        if run_len == 5 {
            // The stuff bit is the complement and a run of one.
            (1 + (1 - run_bit) * 4, true)
        } else {
            (1 + run_bit * 4 + (run_len - 1), false)
        }
    }

    fn feed(&mut self, bits: &BitString) {
        static TABLE: std::sync::OnceLock<[[(u8, u8); 256]; Stuffing::STATES]> = std::sync::OnceLock::new();
        let table = TABLE.get_or_init(|| {
            core::array::from_fn(|state| {
                core::array::from_fn(|byte| {
                    let (mut s, mut n) = (state as u8, 0u8);
                    for i in (0..8).rev() {
                        let (next, stuff) = Stuffing::step(s, (byte >> i) as u8 & 1);
                        s = next;
                        n += u8::from(stuff);
                    }
                    (s, n)
                })
            })
        });
        for (chunk, width) in bits.chunks() {
            if width == 8 {
                let (next, n) = table[usize::from(self.state)][usize::from(chunk)];
                self.state = next;
                self.stuffed += u32::from(n);
            } else {
                for i in (0..width).rev() {
                    let (next, stuff) = Stuffing::step(self.state, (chunk >> i) & 1);
                    self.state = next;
                    self.stuffed += u32::from(stuff);
                }
            }
        }
    }
}

/// The order in which frames win arbitration: lower wins. A standard frame beats an
/// extended one with the same first 11 bits (its RTR/IDE bits are dominant where the
/// extended frame's SRR/IDE are recessive).
pub fn arbitration_key(frame: &CanFrame) -> u64 {
    let id = u64::from(frame.raw_id());
    let remote = u64::from(frame.is_remote_frame());
    if frame.is_extended() {
        (id >> 18) << 22 | 0b11 << 20 | (id & 0x3_FFFF) << 1 | remote
    } else {
        id << 22 | remote << 21
    }
}

/// A frame on its way through the bus, and what became of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Every other controller received it.
    Delivered,
    /// A bit error: receivers dropped it, an error frame followed, the sender retries.
    Corrupted,
}

/// A frame occupying the bus.
#[derive(Debug, Clone, Copy)]
pub struct OnWire {
    /// The controller sending it.
    pub port: usize,
    /// The frame.
    pub frame: CanFrame,
    /// Nanoseconds on the bus clock when it started.
    pub start_ns: u64,
    /// When the bus frees again.
    pub end_ns: u64,
    /// The frame's bits, stuff bits included (error frame not included).
    pub bits: u32,
    /// What happens at `end_ns`.
    pub delivery: Delivery,
}

/// Counters of one bus.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Frames that completed and were delivered.
    pub frames: u64,
    /// Bits of those frames, stuff bits included.
    pub bits: u64,
    /// Stuff bits among them.
    pub stuff_bits: u64,
    /// Nanoseconds the bus was busy (frames, corrupted frames and error frames).
    pub busy_ns: u64,
    /// Frames destroyed by a bit error (and retransmitted by their controller).
    pub corrupted: u64,
    /// Frames refused because a controller's transmit queue was full.
    pub queue_refusals: u64,
}

/// One bus segment with a controller per attached node.
#[derive(Debug)]
pub struct CanBus {
    bitrate: u32,
    queues: Vec<VecDeque<CanFrame>>,
    queue_limit: usize,
    on_wire: Option<OnWire>,
    free_at_ns: u64,
    stats: BusStats,
}

impl CanBus {
    /// A bus at `bitrate` bits per second whose controllers queue at most `queue_limit`
    /// frames each.
    pub fn new(bitrate: u32, queue_limit: usize) -> Self {
        CanBus {
            bitrate: bitrate.max(1),
            queues: Vec::new(),
            queue_limit: queue_limit.max(1),
            on_wire: None,
            free_at_ns: 0,
            stats: BusStats::default(),
        }
    }

    /// Attaches a controller; returns its port number.
    pub fn attach(&mut self) -> usize {
        self.queues.push(VecDeque::with_capacity(self.queue_limit));
        self.queues.len() - 1
    }

    /// Bits per second.
    pub fn bitrate(&self) -> u32 {
        self.bitrate
    }

    /// Nanoseconds that `bits` take.
    pub fn bits_to_ns(&self, bits: u64) -> u64 {
        bits * 1_000_000_000 / u64::from(self.bitrate)
    }

    /// Counters.
    pub fn stats(&self) -> BusStats {
        self.stats
    }

    /// Room left in a controller's transmit queue.
    pub fn room(&self, port: usize) -> usize {
        self.queues.get(port).map_or(0, |q| self.queue_limit.saturating_sub(q.len()))
    }

    /// Queues a frame for transmission; `false` (and counted) if the queue is full.
    pub fn submit(&mut self, port: usize, frame: CanFrame) -> bool {
        match self.queues.get_mut(port) {
            Some(q) if q.len() < self.queue_limit => {
                q.push_back(frame);
                true
            }
            _ => {
                self.stats.queue_refusals += 1;
                false
            }
        }
    }

    /// Drops every queued frame of a controller (its node reset or went silent).
    pub fn clear(&mut self, port: usize) {
        if let Some(q) = self.queues.get_mut(port) {
            q.clear();
        }
    }

    /// The frame on the wire, if any.
    pub fn on_wire(&self) -> Option<&OnWire> {
        self.on_wire.as_ref()
    }

    /// When something happens next on this bus: the frame on the wire ends, or (bus idle,
    /// frames waiting) arbitration can start.
    pub fn next_event_ns(&self, now_ns: u64) -> Option<u64> {
        match &self.on_wire {
            Some(w) => Some(w.end_ns),
            None if self.queues.iter().any(|q| !q.is_empty()) => Some(now_ns.max(self.free_at_ns)),
            None => None,
        }
    }

    /// Starts the next frame if the bus is free at `now_ns`: the queue heads arbitrate, the
    /// lowest key wins. `corrupt` decides (for fault injection) whether a bit error hits it.
    pub fn start(&mut self, now_ns: u64, corrupt: impl FnOnce(&CanFrame) -> bool) -> Option<&OnWire> {
        if self.on_wire.is_some() || now_ns < self.free_at_ns {
            return None;
        }
        let port =
            (0..self.queues.len()).filter_map(|p| Some((arbitration_key(self.queues.get(p)?.front()?), p))).min()?.1;
        let frame = *self.queues.get(port)?.front()?;
        let frame_bits = frame_bits(&frame);
        let bits = u64::from(frame_bits);
        let corrupted = corrupt(&frame);
        // A bit error is seen somewhere in the frame; model it as the whole frame plus an
        // error frame, a conservative bound on the time it wastes.
        let wire_bits = if corrupted { bits + u64::from(ERROR_FRAME_BITS) } else { bits };
        let end_ns = now_ns + self.bits_to_ns(wire_bits);
        self.on_wire = Some(OnWire {
            port,
            frame,
            start_ns: now_ns,
            end_ns,
            bits: frame_bits,
            delivery: if corrupted { Delivery::Corrupted } else { Delivery::Delivered },
        });
        self.on_wire.as_ref()
    }

    /// Ends the frame on the wire if it is due at `now_ns`, returning it. A delivered frame
    /// leaves its controller's queue; a corrupted one stays at the head to be retried.
    pub fn finish(&mut self, now_ns: u64) -> Option<OnWire> {
        let wire = self.on_wire.filter(|w| w.end_ns <= now_ns)?;
        self.on_wire = None;
        self.free_at_ns = wire.end_ns;
        self.stats.busy_ns += wire.end_ns - wire.start_ns;
        match wire.delivery {
            Delivery::Delivered => {
                if let Some(q) = self.queues.get_mut(wire.port) {
                    q.pop_front();
                }
                let bits = wire.bits;
                self.stats.frames += 1;
                self.stats.bits += u64::from(bits);
                self.stats.stuff_bits += u64::from(bits - unstuffed_bits(&wire.frame));
            }
            Delivery::Corrupted => self.stats.corrupted += 1,
        }
        Some(wire)
    }
}

/// The bits of a frame before stuffing (what `frame_bits` would give with no stuff bits).
pub fn unstuffed_bits(frame: &CanFrame) -> u32 {
    let header = if frame.is_extended() { 1 + 11 + 1 + 1 + 18 + 1 + 2 } else { 1 + 11 + 1 + 2 };
    let data = if frame.is_remote_frame() { 0 } else { 8 * frame.payload().len() as u32 };
    header + 4 + data + 15 + UNSTUFFED_TAIL_BITS
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ext(id: u32, data: &[u8]) -> CanFrame {
        CanFrame::extended(id, data).unwrap()
    }

    #[test]
    fn extended_frame_is_67_plus_8n_before_stuffing() {
        for n in 0..=8 {
            assert_eq!(unstuffed_bits(&ext(0x1F45_6123, &[0; 8][..n])), 67 + 8 * n as u32);
        }
    }

    #[test]
    fn stuff_bits_follow_the_contents() {
        // Alternating bits need almost no stuffing; long runs need a stuff bit every 4 bits.
        let sparse = frame_bits(&ext(0x0AAA_AAAA, &[0x55; 8]));
        let dense = frame_bits(&ext(0x1FFF_FFFF, &[0xFF; 8]));
        let zeros = frame_bits(&ext(0, &[0; 8]));
        assert!(sparse < 67 + 64 + 8, "{sparse}");
        assert!(dense > 67 + 64 + 15, "{dense}");
        assert!(zeros > 67 + 64 + 15, "{zeros}");
        // The worst case of an 8-byte extended frame is 160 bits (29 stuff bits).
        for id in [0u32, 0x1FFF_FFFF, 0x1F45_6123, 0x1000_0000] {
            for byte in [0u8, 0xFF, 0x0F, 0xF0, 0x55, 0x33] {
                let bits = frame_bits(&ext(id, &[byte; 8]));
                assert!((131..=160).contains(&bits), "{id:#x} {byte:#x}: {bits}");
            }
        }
    }

    #[test]
    fn stuffing_of_known_runs() {
        let stuff = |value: u128, width: u32| {
            let mut bits = BitString::default();
            bits.push(value, width);
            let mut s = Stuffing::default();
            s.feed(&bits);
            s.stuffed
        };
        assert_eq!(stuff(0, 10), 2, "00000 s 0000 s0: two stuff bits in ten zeros");
        assert_eq!(stuff(0, 4), 0);
        assert_eq!(stuff(0b10_1010_1010, 10), 0);
        assert_eq!(stuff(0b1_1111_0000, 9), 2, "11111 s=0 joins the zeros: 0 0000 -> 5 zeros, s");
        assert_eq!(stuff(u128::MAX >> 8, 120), 24, "a stuff bit (a zero) after every 5 ones");
    }

    /// A bit-at-a-time reference: the tables must agree with it for any content.
    fn reference_bits(frame: &CanFrame) -> u32 {
        let mut seq: Vec<u8> = Vec::new();
        let mut push = |v: u64, w: u32| (0..w).rev().for_each(|i| seq.push(((v >> i) & 1) as u8));
        let id = u64::from(frame.raw_id());
        push(0, 1);
        push(id >> 18, 11);
        push(0b11, 2);
        push(id & 0x3_FFFF, 18);
        push(0, 3);
        push(frame.payload().len() as u64, 4);
        frame.payload().iter().for_each(|b| push(u64::from(*b), 8));
        let mut crc = 0u16;
        for bit in &seq {
            let next = u16::from(*bit) ^ (crc >> 14);
            crc = (crc << 1) & 0x7FFF;
            if next == 1 {
                crc ^= 0x4599;
            }
        }
        (0..15).rev().for_each(|i| seq.push(((crc >> i) & 1) as u8));
        let (mut stuffed, mut last, mut run) = (0, 2u8, 0);
        for bit in seq.iter().copied() {
            if bit == last {
                run += 1
            } else {
                (last, run) = (bit, 1)
            }
            if run == 5 {
                stuffed += 1;
                (last, run) = (1 - bit, 1);
            }
        }
        seq.len() as u32 + stuffed + 13
    }

    #[test]
    fn tables_agree_with_the_bit_at_a_time_reference() {
        let mut rng = crate::Rng::new(3);
        for _ in 0..2000 {
            let id = (rng.next_u64() as u32) & 0x1FFF_FFFF;
            let len = rng.below(9) as usize;
            let data: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
            let frame = ext(id, &data);
            assert_eq!(frame_bits(&frame), reference_bits(&frame), "{frame:?}");
        }
        // The CRC of a known frame: all-zero identifier and no data gives CRC 0 and
        // then stuffing decides the length.
        assert_eq!(frame_bits(&ext(0, &[])), reference_bits(&ext(0, &[])));
    }

    #[test]
    fn lowest_identifier_wins_arbitration() {
        let mut bus = CanBus::new(125_000, 4);
        let a = bus.attach();
        let b = bus.attach();
        bus.submit(a, ext(0x1F45_6123, &[7, 1, 2, 3]));
        bus.submit(b, ext(0x198A_8456, &[1, 2]));
        let first = *bus.start(0, |_| false).unwrap();
        assert_eq!(first.port, b, "priority 2 Complete beats stream data");
        assert_eq!(bus.start(0, |_| false).map(|w| w.port), None, "busy");
        let done = bus.finish(first.end_ns).unwrap();
        assert_eq!(done.delivery, Delivery::Delivered);
        assert_eq!(bus.start(done.end_ns, |_| false).unwrap().port, a);
        // 125 kbit/s: 8 us a bit.
        assert_eq!(first.end_ns - first.start_ns, u64::from(frame_bits(&first.frame)) * 8_000);
    }

    #[test]
    fn corrupted_frame_is_retried() {
        let mut bus = CanBus::new(125_000, 4);
        let a = bus.attach();
        bus.submit(a, ext(0x1F45_6123, &[7]));
        let wire = *bus.start(0, |_| true).unwrap();
        assert_eq!(bus.finish(wire.end_ns).unwrap().delivery, Delivery::Corrupted);
        let again = *bus.start(wire.end_ns, |_| false).unwrap();
        assert_eq!(again.frame, wire.frame);
        assert_eq!(bus.stats().corrupted, 1);
    }

    #[test]
    fn full_queue_refuses() {
        let mut bus = CanBus::new(125_000, 1);
        let a = bus.attach();
        assert!(bus.submit(a, ext(1, &[])));
        assert!(!bus.submit(a, ext(2, &[])));
        assert_eq!((bus.room(a), bus.stats().queue_refusals), (0, 1));
    }

    #[test]
    fn standard_frame_beats_extended_with_same_base() {
        let s = CanFrame::standard(0x123, &[]).unwrap();
        let e = ext(0x123 << 18, &[]);
        assert!(arbitration_key(&s) < arbitration_key(&e));
    }
}
