//! The runtime's RAM: the heap (with its high-water mark), the stack painted at start-up, and
//! the semihosting console.
//!
//! RAM used = static data (`.data`, `.bss`, `.uninit`, the heap array among them) + the
//! deepest the stack went. The firmware carries no code to measure them: it prints where
//! they are (`print_layout`), and the test reads them in a copy of the RAM taken through
//! QEMU's monitor (the stack's depth is where the paint ends).

use core::alloc::{GlobalAlloc, Layout};
use core::cell::UnsafeCell;
use core::mem::MaybeUninit;

use cortex_m::interrupt;
use cortex_m_semihosting::{debug, hio};

use crate::heap::Heap;

/// Bytes of RAM given to the heap: the run under QEMU peaks at 3 808 B (see the README), and
/// the rest is room for what a run with more datagrams in flight holds (the CAN link's tables
/// and the board's are allocated at their bounds at start-up).
pub const HEAP_SIZE: usize = 4224;

/// The word the stack is painted with (the test looks for it).
const PAINT: u32 = 0x5A5A_A5A5;
/// Words kept unpainted below the stack pointer of `paint_stack` (its own frame).
const PAINT_MARGIN_WORDS: usize = 16;

/// The heap, lent one call at a time in a critical section.
struct BoardHeap(UnsafeCell<Heap>);

// SAFETY: the heap is only reached inside `interrupt::free`, one call at a time.
#[allow(unsafe_code)]
unsafe impl Sync for BoardHeap {}

impl BoardHeap {
    /// Runs `use_heap` on the heap, with interrupts off.
    fn with<R>(&self, use_heap: impl FnOnce(&mut Heap) -> R) -> R {
        // SAFETY: interrupts are off and no call of the heap calls another: the one borrow.
        #[allow(unsafe_code)]
        interrupt::free(|_| use_heap(unsafe { &mut *self.0.get() }))
    }
}

#[global_allocator]
static HEAP: BoardHeap = BoardHeap(UnsafeCell::new(Heap::empty()));

// SAFETY: `Heap` lends disjoint blocks of its memory and takes them back.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for BoardHeap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the heap was given its memory first thing (`init_heap`).
        self.with(|heap| unsafe { heap.allocate(layout) })
    }

    unsafe fn dealloc(&self, block: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract: the block and layout of an `alloc`.
        self.with(|heap| unsafe { heap.deallocate(block, layout) })
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
        HEAP.with(|heap| heap.init((&raw mut HEAP_MEM).cast::<u8>(), HEAP_SIZE))
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

/// Prints where the test finds what the run used in a copy of the RAM (it takes one through
/// QEMU's monitor): `ram layout: S T P`, addresses in decimal: S the end of static data (the
/// painted stack's floor), T the top of the stack, P the heap's high-water mark (a `u32`).
pub fn print_layout() {
    let peak = HEAP.with(|heap| heap.peak_address() as u32);
    print(&[
        b"ram layout: ",
        digits(stack_floor() as u32).as_bytes(),
        b" ",
        digits(stack_top() as u32).as_bytes(),
        b" ",
        digits(peak).as_bytes(),
        b"\n",
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
