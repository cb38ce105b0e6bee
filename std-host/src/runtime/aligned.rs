//! Heap buffers that start on a cache-line boundary.
//!
//! The SIMD kernels load 64-byte vectors (AVX-512) or 32-byte ones (AVX2).
//! A `Vec<f32>` of a frame's size comes from `mmap` and starts 16 bytes past
//! a page boundary, so every full-width AVX-512 load from it straddles two
//! cache lines. Planes of a 1280-wide frame hold whole lines per row, so a
//! buffer that starts on a line keeps every row and every plane on one; on
//! the coarse à-trous levels (taps 16 and 32 columns apart) that alone took
//! a fifth off a step on the reference machine.

use core::fmt;
use core::marker::PhantomData;
use core::ops::{Deref, DerefMut};

use bytemuck::{Pod, Zeroable};

/// One cache line of bytes, aligned as one.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Line([u8; 64]);

// SAFETY: a byte array with no padding (size 64 = align 64); every bit
// pattern is valid and all-zero is a valid value.
unsafe impl Zeroable for Line {}
// SAFETY: as above; `Line` is `Copy`, `repr(C)` and has no padding.
unsafe impl Pod for Line {}

/// `len` values of `T` in a buffer starting on a 64-byte boundary.
pub struct Aligned<T> {
    lines: Vec<Line>,
    len: usize,
    _t: PhantomData<T>,
}

impl<T: Pod> Aligned<T> {
    /// `len` zero values (all bits zero: `0.0` for floats).
    pub fn zeroed(len: usize) -> Self {
        let bytes = len.checked_mul(size_of::<T>()).expect("buffer size overflows usize");
        Aligned { lines: vec![Line([0; 64]); bytes.div_ceil(64)], len, _t: PhantomData }
    }

    /// A copy of `src`.
    pub fn from_slice(src: &[T]) -> Self {
        let mut a = Self::zeroed(src.len());
        a.copy_from_slice(src);
        a
    }
}

impl<T: Pod> Deref for Aligned<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        // A size of T divides 64 for every element type here (1, 2, 4 or 8
        // bytes), so the cast of whole lines never fails.
        &bytemuck::cast_slice::<Line, T>(&self.lines)[..self.len]
    }
}

impl<T: Pod> DerefMut for Aligned<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        &mut bytemuck::cast_slice_mut::<Line, T>(&mut self.lines)[..self.len]
    }
}

impl<T> Clone for Aligned<T> {
    fn clone(&self) -> Self {
        Aligned { lines: self.lines.clone(), len: self.len, _t: PhantomData }
    }
}

impl<T: Pod + fmt::Debug> fmt::Debug for Aligned<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl<T: Pod + PartialEq> PartialEq for Aligned<T> {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl<T: Pod> From<&[T]> for Aligned<T> {
    fn from(src: &[T]) -> Self {
        Self::from_slice(src)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn starts_on_a_line_and_holds_its_values() {
        for len in [0usize, 1, 15, 16, 17, 1000] {
            let src: Vec<f32> = (0..len).map(|i| i as f32 * 0.5 - 3.0).collect();
            let a = Aligned::from_slice(&src);
            assert_eq!(a.len(), len);
            assert_eq!(a.as_ptr() as usize % 64, 0, "len {len}");
            assert_eq!(&a[..], &src[..]);
            let b = a.clone();
            assert_eq!(b.as_ptr() as usize % 64, 0);
            assert_eq!(a, b);
        }
        let mut h = Aligned::<half::f16>::zeroed(33);
        assert!(h.iter().all(|v| v.to_f32() == 0.0));
        h[32] = half::f16::from_f32(2.0);
        assert_eq!(h[32].to_f32(), 2.0);
        assert_eq!(h.as_ptr() as usize % 64, 0);
    }
}
