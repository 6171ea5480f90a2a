//! The pool's own memory: each block's arrays and the goal reservoir are anonymous mappings the
//! pool makes, fills, hands back to its loader to fill again, and unmaps when it closes.
//!
//! # Why not `Vec`
//! A block's arrays are megabytes (24 MB a block on humanoidmaze's shape) and a pool cycles
//! through them for as long as it draws. From the allocator, how they behave depends on the
//! allocator's settings, which belong to the process, not to a library: glibc raises its mmap
//! threshold each time such a buffer is freed (up to 32 MB), after which buffers of a block's
//! size come from the heaps of the threads that allocated them and stay there when freed
//! (measured on 10M humanoidmaze-shaped rows: 0.9 GB beyond a 1 GB budget), and `pgser-train`
//! itself keeps everything on its heap (`cli.rs`). Changing those settings from the library
//! (`mallopt`, `malloc_trim`) changed every later allocation of the host process, a JAX or
//! PyTorch trainer's included. Owned mappings behave the same under any allocator and any
//! setting: a block's memory is the mapping, returned to the system when it is unmapped, and
//! recycled while the pool draws, so the kernel zeroes its pages once, not once per block.
//!
//! # Huge pages
//! A batch gathers rows at random from a gigabyte of blocks and from the reservoir: with 4 kB
//! pages nearly every row is a TLB miss. Each mapping of 2 MB or more is advised to transparent
//! huge pages (`madvise(MADV_HUGEPAGE)`), on exactly these mappings, and only the part that will
//! be written ([`Floats::reserve`]), since a huge page is backed whole once touched.

use std::ops::Deref;

use anyhow::{Result, bail};

const HUGE: usize = 2 << 20;

/// A run of values in a mapping of its own: `len` written, room for `cap`. Float32 arrays
/// ([`Floats`]) and an image table's observation bytes ([`Bytes`]).
pub(super) struct Mapped<T: Copy> {
    ptr: *mut T,
    len: usize,
    cap: usize,
}

/// A block's or the reservoir's float32 arrays.
pub(super) type Floats = Mapped<f32>;
/// An image table's observations, `H·W·C` bytes each.
pub(super) type Bytes = Mapped<u8>;

// SAFETY: a `Mapped` owns its mapping alone, as a `Vec<T>` owns its buffer.
unsafe impl<T: Copy + Send> Send for Mapped<T> {}
// SAFETY: shared access only reads.
unsafe impl<T: Copy + Sync> Sync for Mapped<T> {}

impl<T: Copy> Default for Mapped<T> {
    fn default() -> Mapped<T> {
        Mapped { ptr: std::ptr::NonNull::dangling().as_ptr(), len: 0, cap: 0 }
    }
}

impl<T: Copy> Mapped<T> {
    /// `n` zeros (an anonymous mapping is zero until written; zero bytes are 0 for both types).
    pub(super) fn zeros(n: usize) -> Result<Mapped<T>> {
        let mut f = Mapped::default();
        f.reserve(n)?;
        f.len = n;
        Ok(f)
    }

    /// Empties it, keeping its mapping for values to be written again.
    pub(super) fn clear(&mut self) {
        self.len = 0;
    }

    /// Room for `n` values from the start: a new mapping when this one holds fewer (its values
    /// are dropped with the old one; call it on an empty `Mapped`). Huge pages are advised on
    /// the first `n` values' pages.
    pub(super) fn reserve(&mut self, n: usize) -> Result<()> {
        if n <= self.cap {
            return Ok(());
        }
        *self = Mapped::default();
        let Some(bytes) = n.checked_mul(size_of::<T>()) else { bail!("{n} values do not fit in memory") };
        self.ptr = map(bytes)?.cast();
        self.cap = n;
        advise_huge_pages(self.ptr as usize, bytes);
        Ok(())
    }

    /// The values, mutably.
    pub(super) fn as_mut_slice(&mut self) -> &mut [T] {
        if self.cap == 0 {
            return &mut [];
        }
        // SAFETY: the first `len` values lie within the mapping and were written (or are the
        // mapping's zeros); `&mut self` makes this the only reference.
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.len) }
    }

    /// Appends `values` within the room reserved.
    pub(super) fn extend(&mut self, values: &[T]) {
        assert!(self.len + values.len() <= self.cap, "a block's array holds what was reserved for it");
        // SAFETY: the destination lies within the mapping (checked above) and cannot overlap
        // `values`, which is borrowed from elsewhere while `self` is borrowed mutably.
        unsafe { std::ptr::copy_nonoverlapping(values.as_ptr(), self.ptr.add(self.len), values.len()) };
        self.len += values.len();
    }
}

impl<T: Copy> Deref for Mapped<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        if self.cap == 0 {
            return &[];
        }
        // SAFETY: as in `as_mut_slice`, shared.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
}

impl<T: Copy> Drop for Mapped<T> {
    fn drop(&mut self) {
        if self.cap > 0 {
            unmap(self.ptr.cast(), self.cap * size_of::<T>());
        }
    }
}

/// Image bytes are appended within the room reserved, as floats are.
impl crate::trajectory::read::ByteSink for Bytes {
    fn push_bytes(&mut self, values: &[u8]) {
        self.extend(values);
    }
}

/// Values are appended within the room reserved: a block's arrays are sized before it is read.
impl crate::trajectory::read::Sink for Floats {
    fn len(&self) -> usize {
        self.len
    }
    fn push_slice(&mut self, values: &[f32]) {
        self.extend(values);
    }
    fn push_each(&mut self, values: impl Iterator<Item = f32>) {
        for v in values {
            assert!(self.len < self.cap, "a block's array holds what was reserved for it");
            // SAFETY: within the mapping, checked above.
            unsafe { self.ptr.add(self.len).write(v) };
            self.len += 1;
        }
    }
    fn tail(&self, from: usize) -> &[f32] {
        &self[from..]
    }
}

#[cfg(unix)]
fn map(bytes: usize) -> Result<*mut u8> {
    // SAFETY: an anonymous private mapping of `bytes`, owned by the caller from here on.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            bytes,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
            -1,
            0,
        )
    };
    if p == libc::MAP_FAILED {
        bail!(
            "cannot map {} for the pool's blocks: {}",
            crate::progress::bytes(bytes as u64),
            std::io::Error::last_os_error()
        );
    }
    Ok(p.cast())
}

#[cfg(unix)]
fn unmap(p: *mut u8, bytes: usize) {
    // SAFETY: `p` is a mapping of `bytes` that `map` made and nothing refers to any more.
    unsafe {
        libc::munmap(p.cast(), bytes);
    }
}

#[cfg(not(unix))]
fn map(bytes: usize) -> Result<*mut u8> {
    let layout = std::alloc::Layout::from_size_align(bytes, 64)?;
    // SAFETY: a non-zero size (reserve is called with n > cap ≥ 0, and n > 0).
    let p = unsafe { std::alloc::alloc_zeroed(layout) };
    if p.is_null() {
        bail!("cannot allocate {} for the pool's blocks", crate::progress::bytes(bytes as u64));
    }
    Ok(p)
}

#[cfg(not(unix))]
fn unmap(p: *mut u8, bytes: usize) {
    // SAFETY: allocated by `map` with this layout.
    unsafe { std::alloc::dealloc(p.cast(), std::alloc::Layout::from_size_align(bytes, 64).expect("as mapped")) }
}

/// Advises the huge pages that lie wholly within `start..start + bytes` (Linux's default THP
/// mode honours it; elsewhere it does nothing).
pub(crate) fn advise_huge_pages(start: usize, bytes: usize) {
    #[cfg(target_os = "linux")]
    {
        let (from, to) = (start.next_multiple_of(HUGE), (start + bytes) / HUGE * HUGE);
        if to > from {
            // SAFETY: the range lies within a mapping of ours and is page-aligned;
            // MADV_HUGEPAGE only changes how the kernel backs those pages, never their contents.
            unsafe {
                libc::madvise(from as *mut libc::c_void, to - from, libc::MADV_HUGEPAGE);
            }
        }
    }
    let _ = (start, bytes, HUGE);
}

#[cfg(test)]
mod tests {
    use super::Floats;
    use crate::trajectory::read::Sink;

    #[test]
    fn values_written_are_read_back_and_a_larger_reserve_maps_anew() {
        let mut f = Floats::default();
        assert!(f.is_empty());
        f.reserve(5).unwrap();
        f.push_slice(&[1.0, 2.0]);
        f.push_each([3.0f32, 4.0].into_iter());
        assert_eq!(&f[..], &[1.0, 2.0, 3.0, 4.0]);
        f.clear();
        f.reserve(3).unwrap();
        assert_eq!(f.len(), 0);
        f.reserve(1 << 20).unwrap();
        f.push_slice(&vec![7.0; 1 << 20]);
        assert!(f.iter().all(|&v| v == 7.0));
        let z = Floats::zeros(1000).unwrap();
        assert_eq!(z.len(), 1000);
        assert!(z.iter().all(|&v| v == 0.0));
    }

    #[test]
    #[should_panic(expected = "holds what was reserved")]
    fn writing_past_the_reserve_panics_rather_than_writing_outside() {
        let mut f = Floats::default();
        f.reserve(2).unwrap();
        f.push_slice(&[1.0, 2.0, 3.0]);
    }
}
