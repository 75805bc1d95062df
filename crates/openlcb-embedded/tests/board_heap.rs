//! The Cortex-M0 board's heap (`examples/cortex-m0/src/heap.rs`, which has no target code),
//! checked on the host against a model: each block where first fit over the gaps between live
//! blocks puts it (refused when none holds it), aligned, inside the heap, never overlapping,
//! its bytes kept; the counts true; and everything freed merges back into one block.

#![allow(unsafe_code)]

#[path = "../../../examples/cortex-m0/src/heap.rs"]
mod heap;

use std::alloc::Layout;

use heap::{GRAIN, Heap};
use proptest::prelude::*;

/// Bytes of the test's heap memory.
const ARENA: usize = 4096;

/// A heap over `arena`, and where its memory starts and ends.
fn heap_over(arena: &mut [u64]) -> (Heap, usize, usize) {
    let mut heap = Heap::empty();
    let start = arena.as_mut_ptr().cast::<u8>();
    // SAFETY: the arena outlives the heap in every test, and nothing else uses it.
    unsafe { heap.init(start, size_of_val(arena)) };
    (heap, start as usize, start as usize + size_of_val(arena))
}

/// One step: allocate `size` bytes aligned to `align`, or free the live block `pick` selects.
#[derive(Debug, Clone)]
enum Step {
    Allocate { size: usize, align: usize },
    Free { pick: usize },
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        (1usize..400, prop::sample::select(vec![1usize, 2, 4, 8]))
            .prop_map(|(size, align)| Step::Allocate { size, align }),
        any::<usize>().prop_map(|pick| Step::Free { pick }),
    ]
}

/// A live block: where, its layout, and the byte it was filled with.
struct Live {
    at: *mut u8,
    layout: Layout,
    fill: u8,
}

fn rounded(layout: Layout) -> usize {
    layout.size().max(1).div_ceil(GRAIN) * GRAIN
}

/// Where first fit over the model's free memory puts `size` bytes: the start of the first gap
/// between live blocks (in address order, within `low..high`) that holds them. A heap that
/// merges freed neighbours has exactly these gaps as its free blocks.
fn first_fit(live: &[Live], low: usize, high: usize, size: usize) -> Option<usize> {
    let mut taken: Vec<(usize, usize)> =
        live.iter().map(|b| (b.at as usize, b.at as usize + rounded(b.layout))).collect();
    taken.sort_unstable();
    let mut gap_start = low;
    for (start, end) in taken.into_iter().chain([(high, high)]) {
        if start - gap_start >= size {
            return Some(gap_start);
        }
        gap_start = end;
    }
    None
}

proptest! {
    #[test]
    fn blocks_are_disjoint_kept_and_merged_back(steps in prop::collection::vec(step(), 1..300)) {
        let mut arena = vec![0u64; ARENA / 8];
        let (mut heap, low, high) = heap_over(&mut arena);
        let mut live: Vec<Live> = Vec::new();
        let mut peak = 0;
        for (n, step) in steps.into_iter().enumerate() {
            match step {
                Step::Allocate { size, align } => {
                    let layout = Layout::from_size_align(size, align).unwrap();
                    let expected = first_fit(&live, low, high, rounded(layout));
                    // SAFETY: after init.
                    let at = unsafe { heap.allocate(layout) };
                    // Refused exactly when no gap holds it; otherwise from the first that does.
                    prop_assert_eq!((!at.is_null()).then_some(at as usize), expected);
                    if at.is_null() {
                        continue;
                    }
                    let (start, end) = (at as usize, at as usize + rounded(layout));
                    prop_assert_eq!(start % align, 0);
                    prop_assert!(start >= low && end <= high, "outside the heap");
                    for other in &live {
                        let (o_start, o_end) = (other.at as usize, other.at as usize + rounded(other.layout));
                        prop_assert!(end <= o_start || start >= o_end, "overlaps a live block");
                    }
                    let fill = n as u8;
                    // SAFETY: the block is the test's, `size` bytes.
                    unsafe { at.write_bytes(fill, size) };
                    live.push(Live { at, layout, fill });
                }
                Step::Free { pick } => {
                    if live.is_empty() {
                        continue;
                    }
                    let block = live.swap_remove(pick % live.len());
                    // SAFETY: the block is live, `size` bytes.
                    let bytes = unsafe { std::slice::from_raw_parts(block.at, block.layout.size()) };
                    prop_assert!(bytes.iter().all(|b| *b == block.fill), "a block's bytes changed");
                    // SAFETY: from `allocate`, with its layout, not used again.
                    unsafe { heap.deallocate(block.at, block.layout) };
                }
            }
            let used: usize = live.iter().map(|b| rounded(b.layout)).sum();
            peak = peak.max(used);
            prop_assert_eq!(heap.used(), used);
            prop_assert_eq!(heap.peak(), peak);
            // SAFETY: the address of the heap's own count, read while the heap lives.
            prop_assert_eq!(unsafe { *(heap.peak_address() as *const usize) }, peak);
        }
        for block in live.drain(..) {
            // SAFETY: from `allocate`, with its layout, not used again.
            unsafe { heap.deallocate(block.at, block.layout) };
        }
        // Every block merged back with its neighbours: the whole memory in one allocation.
        let whole = Layout::from_size_align(ARENA, 8).unwrap();
        // SAFETY: after init.
        let at = unsafe { heap.allocate(whole) };
        prop_assert_eq!(at as usize, low);
    }
}

#[test]
fn an_alignment_over_a_grain_is_refused() {
    let mut arena = vec![0u64; ARENA / 8];
    let (mut heap, _, _) = heap_over(&mut arena);
    let layout = Layout::from_size_align(8, 2 * GRAIN).unwrap();
    // SAFETY: after init.
    assert!(unsafe { heap.allocate(layout) }.is_null());
    assert_eq!(heap.used(), 0);
}

#[test]
fn a_heap_without_memory_refuses_everything() {
    let mut heap = Heap::empty();
    // SAFETY: an empty heap holds no memory to lend.
    assert!(unsafe { heap.allocate(Layout::new::<u8>()) }.is_null());
}

#[test]
fn blocks_come_from_the_start_of_the_first_block_that_holds_them() {
    let mut arena = vec![0u64; ARENA / 8];
    let (mut heap, low, _) = heap_over(&mut arena);
    let small = Layout::from_size_align(1, 1).unwrap();
    let pair = Layout::from_size_align(2 * GRAIN, 8).unwrap();
    // SAFETY: after init; each block freed with its own layout.
    unsafe {
        let a = heap.allocate(small);
        assert_eq!(a as usize, low);
        let b = heap.allocate(small);
        assert_eq!(b as usize, low + GRAIN);
        heap.deallocate(a, small);
        // The hole at the bottom is too small for two grains, then first fit takes it.
        let c = heap.allocate(pair);
        assert_eq!(c as usize, low + 2 * GRAIN);
        let d = heap.allocate(small);
        assert_eq!(d as usize, low);
        for (block, layout) in [(b, small), (c, pair), (d, small)] {
            heap.deallocate(block, layout);
        }
        let whole = Layout::from_size_align(ARENA, 8).unwrap();
        assert_eq!(heap.allocate(whole) as usize, low);
    }
}
