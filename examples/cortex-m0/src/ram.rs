//! The runtime's RAM: the heap (with its high-water mark), the stack painted at start-up and
//! measured before a reboot, and the semihosting console.
//!
//! RAM used = static data (`.data`, `.bss`, `.uninit`, the heap array among them) + the
//! deepest the stack went, while the node was built or after. `report` prints them, and the
//! heap's peak, on the console.

use core::alloc::{GlobalAlloc, Layout};
use core::cell::Cell;
use core::mem::MaybeUninit;

use cortex_m::interrupt::{self, Mutex};
use cortex_m_semihosting::{debug, hio};
use embedded_alloc::LlffHeap;

/// Bytes of RAM given to the heap: the run under QEMU peaks at 3 860 B (see the README), and
/// the rest is room for what a run with more datagrams in flight holds (the CAN link's tables
/// and the board's are allocated at their bounds at start-up).
pub const HEAP_SIZE: usize = 4224;

/// The word the stack is painted with.
const PAINT: u32 = 0x5A5A_A5A5;
/// Words kept unpainted below the stack pointer of `paint_stack` (its own frame).
const PAINT_MARGIN_WORDS: usize = 16;

/// The heap, counting the most it ever held.
struct PeakHeap {
    heap: LlffHeap,
    peak: Mutex<Cell<usize>>,
}

#[global_allocator]
static HEAP: PeakHeap = PeakHeap { heap: LlffHeap::empty(), peak: Mutex::new(Cell::new(0)) };

// SAFETY: forwards to `LlffHeap`, which is a correct allocator; only counts besides.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for PeakHeap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract, passed on.
        let block = unsafe { self.heap.alloc(layout) };
        let used = self.heap.used();
        interrupt::free(|cs| {
            let peak = self.peak.borrow(cs);
            peak.set(peak.get().max(used));
        });
        block
    }

    unsafe fn dealloc(&self, block: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract, passed on.
        unsafe { self.heap.dealloc(block, layout) }
    }
}

/// Builds `make`'s value straight into `slot` (static RAM, from `cortex_m::singleton!`) and
/// lends it for the rest of the run. Not inlined: whatever `make` needs on the stack is given
/// back on return, and a value of a KiB is never copied through the caller's frame.
#[inline(never)]
pub fn place<T>(slot: &'static mut MaybeUninit<T>, make: impl FnOnce() -> T) -> &'static mut T {
    slot.write(make())
}

/// Gives the heap its memory. Call once, first thing after `paint_stack`.
pub fn init_heap() {
    static mut HEAP_MEM: [MaybeUninit<u8>; HEAP_SIZE] = [MaybeUninit::uninit(); HEAP_SIZE];
    // SAFETY: called once at start-up, before any allocation; HEAP_MEM is used by nothing else.
    #[allow(unsafe_code)]
    unsafe {
        HEAP.heap.init(&raw mut HEAP_MEM as usize, HEAP_SIZE)
    }
}

unsafe extern "C" {
    /// The end of static data: the stack may grow down to here (cortex-m-rt's linker script).
    static __sheap: u32;
    /// The top of RAM, where the stack starts.
    static _stack_start: u32;
}

fn stack_floor() -> *mut u32 {
    (&raw const __sheap).cast_mut()
}

fn stack_top() -> usize {
    (&raw const _stack_start) as usize
}

/// The deepest the stack went while the node was being built (`started`).
static STARTUP_STACK: Mutex<Cell<usize>> = Mutex::new(Cell::new(0));

/// The node is built: keeps how deep the stack went so far and paints the free RAM again, so
/// that the report tells the start-up's depth from the running node's.
pub fn started() {
    let depth = stack_used();
    interrupt::free(|cs| STARTUP_STACK.borrow(cs).set(depth));
    paint_stack();
}

/// Paints the free RAM between static data and the stack pointer.
pub fn paint_stack() {
    let sp = cortex_m::register::msp::read() as usize;
    let mut word = stack_floor();
    while (word as usize) < sp - 4 * PAINT_MARGIN_WORDS {
        // SAFETY: between the end of static data and below the live stack: RAM no one uses.
        #[allow(unsafe_code)]
        unsafe {
            word.write_volatile(PAINT);
            word = word.add(1);
        }
    }
}

/// The deepest the stack has gone: bytes from its top down to the lowest word no longer
/// holding the paint.
fn stack_used() -> usize {
    let mut word = stack_floor();
    // SAFETY: reads of the painted region, inside RAM.
    #[allow(unsafe_code)]
    while (word as usize) < stack_top() && unsafe { word.read_volatile() } == PAINT {
        word = unsafe { word.add(1) };
    }
    stack_top() - word as usize
}

/// Prints `ram: static S B + stack K B (start-up K1 B, running K2 B) = T B; heap used U B,
/// peak H B of SIZE B`, K the deeper of K1 and K2.
pub fn report() {
    let statics = stack_floor() as usize - 0x2000_0000;
    let startup = interrupt::free(|cs| STARTUP_STACK.borrow(cs).get());
    let running = stack_used();
    let stack = startup.max(running);
    let peak = interrupt::free(|cs| HEAP.peak.borrow(cs).get());
    print(&[
        b"ram: static ",
        digits(statics as u32).as_bytes(),
        b" B + stack ",
        digits(stack as u32).as_bytes(),
        b" B (start-up ",
        digits(startup as u32).as_bytes(),
        b" B, running ",
        digits(running as u32).as_bytes(),
        b" B) = ",
        digits((statics + stack) as u32).as_bytes(),
        b" B; heap used ",
        digits(HEAP.heap.used() as u32).as_bytes(),
        b" B, peak ",
        digits(peak as u32).as_bytes(),
        b" B of ",
        digits(HEAP_SIZE as u32).as_bytes(),
        b" B\n",
    ]);
}

/// A number in decimal, without the formatting machinery.
pub struct Digits {
    text: [u8; 10],
    start: usize,
}

impl Digits {
    /// The text, in ASCII.
    pub fn as_bytes(&self) -> &[u8] {
        &self.text[self.start..]
    }
}

/// `value` in decimal, by subtracting powers of ten (a Cortex-M0 has no divide instruction).
pub fn digits(mut value: u32) -> Digits {
    let mut out = Digits { text: [b'0'; 10], start: 9 };
    const POWERS: [u32; 10] = [1_000_000_000, 100_000_000, 10_000_000, 1_000_000, 100_000, 10_000, 1_000, 100, 10, 1];
    for (i, (slot, power)) in out.text.iter_mut().zip(POWERS).enumerate() {
        while value >= power {
            value -= power;
            *slot += 1;
        }
        if *slot != b'0' && out.start > i {
            out.start = i;
        }
    }
    out
}

/// Writes the pieces (ASCII) to the host's stdout.
pub fn print(pieces: &[&[u8]]) {
    if let Ok(mut out) = hio::hstdout() {
        for piece in pieces {
            let _ = out.write_all(piece);
        }
    }
}

/// QEMU exits with status 1.
pub fn exit_failure() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}
