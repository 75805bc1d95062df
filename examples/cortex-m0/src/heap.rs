//! The board's heap: first fit over a list of free blocks kept in address order, a freed
//! block merged with its free neighbours. The same policy as `embedded-alloc`'s LLFF heap in
//! a quarter of its flash (about 0.3 KiB against 0.9 KiB on a Cortex-M0), because it asks
//! less: alignments up to [`GRAIN`] (a Cortex-M0's largest is 8), and the caller's size at
//! free (as `GlobalAlloc::dealloc` gives it), so an allocated block carries no header. A free
//! block's first [`GRAIN`] bytes hold its size and the next free block.
//!
//! No target code: the firmware wraps it in its allocator (`ram`), and a host test
//! (`crates/openlcb-embedded/tests/board_heap.rs`) checks it against a model.

#![allow(unsafe_code)]

use core::alloc::Layout;
use core::ptr;

/// A free block's header, in its own first bytes.
#[repr(C)]
struct Free {
    /// Bytes of the block, this header's among them (a multiple of [`GRAIN`]).
    size: usize,
    /// The next free block, at a higher address (null: none).
    next: *mut Free,
}

/// Every block's address and size are multiples of this: a free block's header (8 bytes on
/// a 32-bit target).
pub(crate) const GRAIN: usize = size_of::<Free>();

/// The heap: its free blocks, and what it lends now and at most.
pub(crate) struct Heap {
    first: *mut Free,
    used: usize,
    peak: usize,
}

// SAFETY: the heap owns the memory its pointers point into; whoever shares it serialises
// the calls (the firmware: in a critical section).
unsafe impl Send for Heap {}

impl Heap {
    /// A heap with no memory: every allocation fails until [`init`](Self::init).
    pub(crate) const fn empty() -> Self {
        Heap { first: ptr::null_mut(), used: 0, peak: 0 }
    }

    /// Gives the heap `len` bytes at `start` (the part of them that is whole grains).
    ///
    /// # Safety
    /// The memory is valid, used by nothing else for the heap's life, and given once.
    pub(crate) unsafe fn init(&mut self, start: *mut u8, len: usize) {
        let skip = start.align_offset(GRAIN);
        let size = len.saturating_sub(skip) / GRAIN * GRAIN;
        if size > 0 {
            // SAFETY: `skip + size <= len` bytes of the caller's memory, aligned to a grain.
            unsafe {
                let block = start.add(skip).cast::<Free>();
                block.write(Free { size, next: ptr::null_mut() });
                self.first = block;
            }
        }
    }

    /// Bytes lent now, in whole grains.
    #[allow(dead_code, reason = "the host test reads it; the firmware reads `peak_address`")]
    pub(crate) fn used(&self) -> usize {
        self.used
    }

    /// The most bytes ever lent at once, in whole grains.
    #[allow(dead_code, reason = "the host test reads it; the firmware reads `peak_address`")]
    pub(crate) fn peak(&self) -> usize {
        self.peak
    }

    /// The address of [`peak`](Self::peak)'s count, for a reader of a copy of the RAM.
    pub(crate) fn peak_address(&self) -> usize {
        (&raw const self.peak) as usize
    }

    /// The bytes a block for `layout` takes: its size, at least one byte, in whole grains.
    fn block_size(layout: Layout) -> usize {
        layout.size().max(1).div_ceil(GRAIN) * GRAIN
    }

    /// A block for `layout` from the start of the first free block that holds it (as LLFF
    /// does: carving from the end instead left the board's heap too fragmented for its
    /// run); null when none does or the alignment is over [`GRAIN`].
    ///
    /// # Safety
    /// After [`init`](Self::init).
    pub(crate) unsafe fn allocate(&mut self, layout: Layout) -> *mut u8 {
        if layout.align() > GRAIN {
            return ptr::null_mut();
        }
        let size = Self::block_size(layout);
        let mut link: *mut *mut Free = &raw mut self.first;
        // SAFETY: every link points at a free block's header inside the heap's memory.
        unsafe {
            while let Some(block) = (*link).as_mut() {
                if block.size >= size {
                    let start = ptr::from_mut(block).cast::<u8>();
                    *link = if block.size == size {
                        block.next
                    } else {
                        let rest = start.add(size).cast::<Free>();
                        rest.write(Free { size: block.size - size, next: block.next });
                        rest
                    };
                    self.used += size;
                    self.peak = self.peak.max(self.used);
                    return start;
                }
                link = &raw mut block.next;
            }
        }
        ptr::null_mut()
    }

    /// Takes back the block at `block`, merged with a free neighbour on either side.
    ///
    /// # Safety
    /// `block` came from [`allocate`](Self::allocate) with the same `layout`, and is not
    /// used again.
    pub(crate) unsafe fn deallocate(&mut self, block: *mut u8, layout: Layout) {
        let mut size = Self::block_size(layout);
        self.used -= size;
        let freed = block.cast::<Free>();
        let mut before: *mut Free = ptr::null_mut();
        let mut link: *mut *mut Free = &raw mut self.first;
        // SAFETY: every link points at a free block's header inside the heap's memory, and
        // `freed`'s `size` bytes are the caller's block, now the heap's again.
        unsafe {
            while !(*link).is_null() && *link < freed {
                before = *link;
                link = &raw mut (*before).next;
            }
            let mut next = *link;
            if !next.is_null() && block.add(size) == next.cast::<u8>() {
                size += (*next).size;
                next = (*next).next;
            }
            if !before.is_null() && before.cast::<u8>().add((*before).size) == block {
                (*before).size += size;
                (*before).next = next;
            } else {
                freed.write(Free { size, next });
                *link = freed;
            }
        }
    }
}
