//! The binary's allocator: the system's, with every block of [`HUGE_FROM`] bytes or more
//! advised for transparent huge pages (Linux `madvise(MADV_HUGEPAGE)`, which the kernel's
//! default `madvise` mode waits for). A 12 MP DNG read whole is 24 MB of fresh pages: in 4 KiB
//! pages about 6 000 faults, each zeroing its page, a quarter of `noisecal synth`'s CPU time
//! with the rest of the process's large blocks. In 2 MiB pages a dozen. What is allocated and
//! written is the same; only the page size changes. Elsewhere than Linux it is the system's.

use std::alloc::{GlobalAlloc, Layout, System};

/// Blocks at least this large are advised (several huge pages: a smaller block would round up
/// to a whole huge page's memory for little).
const HUGE_FROM: usize = 4 << 20;

/// [`System`], with large blocks advised for huge pages.
pub struct HugePages;

// SAFETY: every call is `System`'s with the same arguments; `advise` only gives the kernel advice
// on whole pages within the block `System` returned, which changes neither their contents nor
// the block's ownership.
unsafe impl GlobalAlloc for HugePages {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract is `System.alloc`'s.
        let p = unsafe { System.alloc(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract is `System.alloc_zeroed`'s.
        let p = unsafe { System.alloc_zeroed(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is `System.dealloc`'s.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller's contract is `System.realloc`'s.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        advise(p, new_size);
        p
    }
}

/// Advises the whole huge pages within the block of `len` bytes at `p` (none: a null block, or
/// one below [`HUGE_FROM`]).
fn advise(p: *mut u8, len: usize) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        if p.is_null() || len < HUGE_FROM {
            return;
        }
        let start = (p as usize).next_multiple_of(HUGE);
        let end = (p as usize + len) / HUGE * HUGE;
        if end > start {
            // SAFETY: `start .. end` lies within the block just allocated; the advice moves no
            // byte, and a refusal (a kernel without huge pages) leaves the pages as they were.
            unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (p, len);
}
