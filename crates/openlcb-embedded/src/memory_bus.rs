//! [`MemoryBus`]: an in-memory CAN bus whose [`MemoryPort`]s implement
//! [`embedded_can::nb::Can`], for tests and for firmware that runs several nodes on one chip.
//!
//! A transmitted frame is copied at once into the receive FIFO of every other port (a node
//! does not hear itself, as with a CAN controller that does not echo). The bus is lossless: a
//! port whose frame would not fit in some other port's FIFO gets `WouldBlock`, which is how a
//! slow receiver pushes back on the sender. FIFOs are fixed arrays: nothing is allocated.
//! The bus is not `Sync`; share it by reference on one core.

use core::cell::RefCell;

use embedded_can::Frame;
use embedded_can::nb::Can;

/// A bounded FIFO of frames in a fixed array.
#[derive(Debug)]
struct Fifo<F, const DEPTH: usize> {
    slots: [Option<F>; DEPTH],
    head: usize,
    len: usize,
}

impl<F, const DEPTH: usize> Fifo<F, DEPTH> {
    fn new() -> Self {
        Fifo { slots: core::array::from_fn(|_| None), head: 0, len: 0 }
    }

    fn is_full(&self) -> bool {
        self.len >= DEPTH
    }

    fn push(&mut self, frame: F) {
        if let Some(slot) = self.slots.get_mut((self.head + self.len) % DEPTH.max(1)) {
            *slot = Some(frame);
            self.len += 1;
        }
    }

    fn pop(&mut self) -> Option<F> {
        if self.len == 0 {
            return None;
        }
        let frame = self.slots.get_mut(self.head).and_then(Option::take);
        self.head = (self.head + 1) % DEPTH.max(1);
        self.len -= 1;
        frame
    }
}

/// Counters of a [`MemoryBus`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct BusStats {
    /// Frames put on the bus.
    pub frames: u64,
    /// Data bytes carried.
    pub data_bytes: u64,
    /// Transmissions refused because a receiver's FIFO was full.
    pub would_block: u64,
    /// The most frames any receive FIFO held at once.
    pub max_queued: usize,
}

#[derive(Debug)]
struct State<F, const PORTS: usize, const DEPTH: usize> {
    fifos: [Fifo<F, DEPTH>; PORTS],
    taken: [bool; PORTS],
    stats: BusStats,
}

/// `PORTS` nodes on one bus, each with a receive FIFO of `DEPTH` frames of type `F`.
#[derive(Debug)]
pub struct MemoryBus<F, const PORTS: usize, const DEPTH: usize> {
    state: RefCell<State<F, PORTS, DEPTH>>,
}

impl<F: Frame + Clone, const PORTS: usize, const DEPTH: usize> Default for MemoryBus<F, PORTS, DEPTH> {
    fn default() -> Self {
        Self::new()
    }
}

impl<F: Frame + Clone, const PORTS: usize, const DEPTH: usize> MemoryBus<F, PORTS, DEPTH> {
    /// An idle bus.
    pub fn new() -> Self {
        MemoryBus {
            state: RefCell::new(State {
                fifos: core::array::from_fn(|_| Fifo::new()),
                taken: [false; PORTS],
                stats: BusStats::default(),
            }),
        }
    }

    /// Port `index` (`0..PORTS`), or `None` if out of range or already taken.
    pub fn port(&self, index: usize) -> Option<MemoryPort<'_, F, PORTS, DEPTH>> {
        let mut state = self.state.try_borrow_mut().ok()?;
        let taken = state.taken.get_mut(index)?;
        if *taken {
            return None;
        }
        *taken = true;
        Some(MemoryPort { bus: self, index })
    }

    /// Counters.
    pub fn stats(&self) -> BusStats {
        self.state.try_borrow().map(|s| s.stats).unwrap_or_default()
    }

    /// Frames waiting in any receive FIFO.
    pub fn queued(&self) -> usize {
        self.state.try_borrow().map(|s| s.fifos.iter().map(|f| f.len).sum()).unwrap_or(0)
    }
}

/// The bus refused a call because it was re-entered (never happens on one thread without
/// callbacks; reported rather than panicking).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusBusy;

impl embedded_can::Error for BusBusy {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

/// One node's connection to a [`MemoryBus`].
#[derive(Debug)]
pub struct MemoryPort<'a, F, const PORTS: usize, const DEPTH: usize> {
    bus: &'a MemoryBus<F, PORTS, DEPTH>,
    index: usize,
}

impl<F, const PORTS: usize, const DEPTH: usize> MemoryPort<'_, F, PORTS, DEPTH> {
    /// This port's index on the bus.
    pub fn index(&self) -> usize {
        self.index
    }
}

impl<F: Frame + Clone, const PORTS: usize, const DEPTH: usize> Can for MemoryPort<'_, F, PORTS, DEPTH> {
    type Frame = F;
    type Error = BusBusy;

    /// Copies `frame` to every other port, or `WouldBlock` if one of them is full. Never
    /// replaces a pending frame.
    fn transmit(&mut self, frame: &F) -> nb::Result<Option<F>, BusBusy> {
        let mut state = self.bus.state.try_borrow_mut().map_err(|_| nb::Error::Other(BusBusy))?;
        let state = &mut *state;
        let others = || (0..PORTS).filter(|&i| i != self.index);
        if others().any(|i| state.fifos.get(i).is_some_and(Fifo::is_full)) {
            state.stats.would_block = state.stats.would_block.saturating_add(1);
            return Err(nb::Error::WouldBlock);
        }
        for i in others() {
            if let Some(fifo) = state.fifos.get_mut(i) {
                fifo.push(frame.clone());
                state.stats.max_queued = state.stats.max_queued.max(fifo.len);
            }
        }
        state.stats.frames = state.stats.frames.saturating_add(1);
        state.stats.data_bytes = state.stats.data_bytes.saturating_add(frame.data().len() as u64);
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<F, BusBusy> {
        let mut state = self.bus.state.try_borrow_mut().map_err(|_| nb::Error::Other(BusBusy))?;
        state.fifos.get_mut(self.index).and_then(Fifo::pop).ok_or(nb::Error::WouldBlock)
    }
}
