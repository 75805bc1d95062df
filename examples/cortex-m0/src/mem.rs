//! Small `memcpy`, `memmove` and `memset` (and the ARM EABI names the compiler calls) in place
//! of `compiler_builtins`' word-at-a-time ones, which take about 2.4 KiB of a Cortex-M0's
//! flash between them. Byte at a time: the board's copies are a CAN frame's 8 bytes, a
//! datagram's 72, at most its configuration's 216. The loops use volatile accesses so that the
//! compiler cannot turn them back into calls of themselves, and none calls another by its C
//! name (the compiler would take that for the library call it names).
//!
//! The linker takes these before the library's: the library's definitions are weak.

#![allow(unsafe_code)]

/// Copies `n` bytes from `src` to `dest`, front to back (also right for `dest` below `src`).
///
/// # Safety
/// Both ranges valid for `n` bytes.
unsafe fn copy_forward(dest: *mut u8, src: *const u8, n: usize) {
    for i in 0..n {
        // SAFETY: the caller's contract: both ranges hold `n` bytes.
        unsafe { dest.add(i).write_volatile(src.add(i).read_volatile()) }
    }
}

/// Copies `n` bytes from `src` to `dest`, back to front (right for `dest` above `src`).
///
/// # Safety
/// Both ranges valid for `n` bytes.
unsafe fn copy_backward(dest: *mut u8, src: *const u8, n: usize) {
    for i in (0..n).rev() {
        // SAFETY: the caller's contract: both ranges hold `n` bytes.
        unsafe { dest.add(i).write_volatile(src.add(i).read_volatile()) }
    }
}

/// Copies `n` bytes from `src` to `dest` in the direction that keeps an overlap right.
///
/// # Safety
/// Both ranges valid for `n` bytes.
unsafe fn copy_either_way(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: passed on.
    unsafe { if (dest as usize) <= (src as usize) { copy_forward(dest, src, n) } else { copy_backward(dest, src, n) } }
}

/// Fills `n` bytes at `dest` with `byte`.
///
/// # Safety
/// The range valid for `n` bytes.
unsafe fn fill(dest: *mut u8, byte: u8, n: usize) {
    for i in 0..n {
        // SAFETY: the caller's contract: the range holds `n` bytes.
        unsafe { dest.add(i).write_volatile(byte) }
    }
}

/// C's `memcpy`.
///
/// # Safety
/// As C's: both ranges valid for `n` bytes, not overlapping.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcpy(dest: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: passed on.
    unsafe { copy_forward(dest, src, n) };
    dest
}

/// C's `memmove`.
///
/// # Safety
/// As C's: both ranges valid for `n` bytes; they may overlap.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memmove(dest: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: passed on; the direction keeps an overlap right.
    unsafe { if (dest as usize) <= (src as usize) { copy_forward(dest, src, n) } else { copy_backward(dest, src, n) } }
    dest
}

/// C's `memset`.
///
/// # Safety
/// As C's: the range valid for `n` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memset(dest: *mut u8, byte: i32, n: usize) -> *mut u8 {
    // SAFETY: passed on.
    unsafe { fill(dest, byte as u8, n) };
    dest
}

/// Defines the ARM EABI names (`__aeabi_memcpy4` and so on: the same work, arguments in
/// their order) over the functions above.
macro_rules! eabi {
    ($($copy:ident)*; $($moves:ident)*; $($set:ident)*; $($clear:ident)*) => {
        $(
            /// The ARM EABI's copy.
            ///
            /// # Safety
            /// As `memcpy`'s.
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn $copy(dest: *mut u8, src: *const u8, n: usize) {
                // SAFETY: passed on.
                unsafe { copy_forward(dest, src, n) }
            }
        )*
        $(
            /// The ARM EABI's move.
            ///
            /// # Safety
            /// As `memmove`'s.
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn $moves(dest: *mut u8, src: *const u8, n: usize) {
                // SAFETY: passed on.
                unsafe { copy_either_way(dest, src, n) }
            }
        )*
        $(
            /// The ARM EABI's fill (length before the byte).
            ///
            /// # Safety
            /// As `memset`'s.
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn $set(dest: *mut u8, n: usize, byte: i32) {
                // SAFETY: passed on.
                unsafe { fill(dest, byte as u8, n) }
            }
        )*
        $(
            /// The ARM EABI's fill with zeros.
            ///
            /// # Safety
            /// As `memset`'s.
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn $clear(dest: *mut u8, n: usize) {
                // SAFETY: passed on.
                unsafe { fill(dest, 0, n) }
            }
        )*
    };
}

eabi!(
    __aeabi_memcpy __aeabi_memcpy4 __aeabi_memcpy8;
    __aeabi_memmove __aeabi_memmove4 __aeabi_memmove8;
    __aeabi_memset __aeabi_memset4 __aeabi_memset8;
    __aeabi_memclr __aeabi_memclr4 __aeabi_memclr8
);
