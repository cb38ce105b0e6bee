//! Borrowed planar tensor views.
//!
//! A view is `channels` planes of `height` rows of `width` elements. Element
//! `(c, y, x)` lives at `c * plane_stride + y * row_stride + x`. Constructors
//! check once that the slice is long enough and that rows and planes do not
//! overlap (`row_stride >= width`, `plane_stride >= (height - 1) * row_stride + width`),
//! which is what makes [`ViewMut::split_rows_at`] sound: the bands it returns
//! touch disjoint memory and can go to different threads.
//!
//! Invariant every constructor establishes and every sub-view keeps: for each
//! `c < channels` and `y < height`, `c * plane_stride + y * row_stride + width`
//! is computed without overflow and is at most the slice's length (also for
//! `width == 0`). A view with no rows (`channels == 0` or `height == 0`) never
//! offsets its pointer, whatever its strides.

use core::marker::PhantomData;

use crate::error::{Error, Result, Shape};

fn required_len(
    what: &'static str,
    channels: usize,
    width: usize,
    height: usize,
    row_stride: usize,
    plane_stride: usize,
) -> Result<usize> {
    // No row exists, so no offset is ever computed (sub-views of an empty view
    // keep its base pointer). A width-0 view still has rows: its strides are
    // checked like any other's, so that every row offset `c * plane_stride +
    // y * row_stride` is computed without overflow and stays inside the slice.
    if channels == 0 || height == 0 {
        return Ok(0);
    }
    if row_stride < width {
        return Err(Error::BadStrides { what });
    }
    let plane_span =
        (height - 1).checked_mul(row_stride).and_then(|v| v.checked_add(width)).ok_or(Error::SizeOverflow { what })?;
    if channels > 1 && plane_stride < plane_span {
        return Err(Error::BadStrides { what });
    }
    (channels - 1).checked_mul(plane_stride).and_then(|v| v.checked_add(plane_span)).ok_or(Error::SizeOverflow { what })
}

/// Packed length of a shape: `channels * width * height`, or an error on overflow.
pub fn packed_len(what: &'static str, shape: Shape) -> Result<usize> {
    shape
        .channels
        .checked_mul(shape.width)
        .and_then(|v| v.checked_mul(shape.height))
        .ok_or(Error::SizeOverflow { what })
}

/// A shared planar view.
pub struct View<'a, T> {
    ptr: *const T,
    shape: Shape,
    row_stride: usize,
    plane_stride: usize,
    frac: i8,
    _m: PhantomData<&'a [T]>,
}

impl<T> Clone for View<'_, T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for View<'_, T> {}
// SAFETY: a View is a shared borrow of `[T]`.
unsafe impl<T: Sync> Send for View<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Sync> Sync for View<'_, T> {}

impl<T> core::fmt::Debug for View<'_, T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "View({})", self.shape)
    }
}

impl<'a, T> View<'a, T> {
    /// Tightly packed planes: `row_stride = width`, `plane_stride = width * height`.
    pub fn new(data: &'a [T], channels: usize, width: usize, height: usize) -> Result<Self> {
        let plane = width.checked_mul(height).ok_or(Error::SizeOverflow { what: "view" })?;
        Self::with_strides(data, channels, width, height, width, plane)
    }

    /// Explicit strides (in elements).
    pub fn with_strides(
        data: &'a [T],
        channels: usize,
        width: usize,
        height: usize,
        row_stride: usize,
        plane_stride: usize,
    ) -> Result<Self> {
        let needed = required_len("view", channels, width, height, row_stride, plane_stride)?;
        if data.len() < needed {
            return Err(Error::BufferTooSmall { what: "view", needed, got: data.len() });
        }
        Ok(View {
            ptr: data.as_ptr(),
            shape: Shape::new(channels, width, height),
            row_stride,
            plane_stride,
            frac: 0,
            _m: PhantomData,
        })
    }

    /// Channels, width and height.
    #[inline]
    pub fn shape(&self) -> Shape {
        self.shape
    }
    /// Number of planes.
    #[inline]
    pub fn channels(&self) -> usize {
        self.shape.channels
    }
    /// Pixels per row.
    #[inline]
    pub fn width(&self) -> usize {
        self.shape.width
    }
    /// Rows per plane.
    #[inline]
    pub fn height(&self) -> usize {
        self.shape.height
    }
    /// Elements between rows.
    #[inline]
    pub fn row_stride(&self) -> usize {
        self.row_stride
    }
    /// Elements between planes.
    #[inline]
    pub fn plane_stride(&self) -> usize {
        self.plane_stride
    }

    /// Fractional bits of a fixed-point tensor (value = stored / 2^frac);
    /// 0 unless set, and ignored by the floating-point precisions.
    #[inline]
    pub fn frac(&self) -> i8 {
        self.frac
    }

    /// The same view with its fixed-point format set.
    #[inline]
    pub fn with_frac(mut self, frac: i8) -> Self {
        self.frac = frac;
        self
    }

    /// Row `y` of plane `c`.
    ///
    /// # Panics
    /// When `c` or `y` is out of range, like slice indexing (operators check
    /// shapes before they index, so caller input never gets here).
    #[inline]
    pub fn row(&self, c: usize, y: usize) -> &'a [T] {
        assert!(c < self.shape.channels && y < self.shape.height);
        // SAFETY: in range, and the constructor checked the slice covers every row.
        unsafe {
            core::slice::from_raw_parts(self.ptr.add(c * self.plane_stride + y * self.row_stride), self.shape.width)
        }
    }

    /// Raw pointer to element `(c, y, 0)`; its provenance covers the whole view,
    /// so SIMD code may step from one plane to the next.
    #[inline]
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn ptr(&self, c: usize, y: usize) -> *const T {
        debug_assert!(c < self.shape.channels && y < self.shape.height);
        self.ptr.wrapping_add(c * self.plane_stride + y * self.row_stride)
    }

    /// Element `(c, y, x)`.
    ///
    /// # Panics
    /// When `(c, y, x)` is out of range, like slice indexing.
    #[inline]
    pub fn at(&self, c: usize, y: usize, x: usize) -> T
    where
        T: Copy,
    {
        self.row(c, y)[x]
    }

    /// Planes `c0 .. c0 + n` as their own view.
    pub fn channels_range(&self, c0: usize, n: usize) -> Result<View<'a, T>> {
        if c0.checked_add(n).is_none_or(|e| e > self.shape.channels) {
            return Err(Error::BadParameter { what: "channel range", expected: "within the view" });
        }
        Ok(View {
            // SAFETY: when the sub-view has rows (n > 0, height > 0), plane c0 < channels
            // has rows too and the invariant puts its offset inside the slice, without
            // overflow. Otherwise the pointer is not moved.
            ptr: if n == 0 || self.shape.height == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(c0 * self.plane_stride) }
            },
            shape: Shape::new(n, self.shape.width, self.shape.height),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        })
    }

    /// Plane `c` as a one-channel view.
    pub fn channel(&self, c: usize) -> Result<View<'a, T>> {
        self.channels_range(c, 1)
    }

    /// Rows `y0 .. y0 + n` of every plane.
    pub fn rows(&self, y0: usize, n: usize) -> Result<View<'a, T>> {
        if y0.checked_add(n).is_none_or(|e| e > self.shape.height) {
            return Err(Error::BadParameter { what: "row range", expected: "within the view" });
        }
        Ok(View {
            // SAFETY: when the sub-view has rows (n > 0, channels > 0), row y0 < height of
            // plane 0 exists and the invariant puts its offset inside the slice, without
            // overflow. Otherwise the pointer is not moved.
            ptr: if n == 0 || self.shape.channels == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(y0 * self.row_stride) }
            },
            shape: Shape::new(self.shape.channels, self.shape.width, n),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        })
    }
}

/// An exclusive planar view.
pub struct ViewMut<'a, T> {
    ptr: *mut T,
    shape: Shape,
    row_stride: usize,
    plane_stride: usize,
    frac: i8,
    _m: PhantomData<&'a mut [T]>,
}

// SAFETY: a ViewMut is an exclusive borrow of `[T]`.
unsafe impl<T: Send> Send for ViewMut<'_, T> {}
// SAFETY: shared access only hands out `&T`.
unsafe impl<T: Sync> Sync for ViewMut<'_, T> {}

impl<T> core::fmt::Debug for ViewMut<'_, T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "ViewMut({})", self.shape)
    }
}

impl<'a, T> ViewMut<'a, T> {
    /// Tightly packed planes.
    pub fn new(data: &'a mut [T], channels: usize, width: usize, height: usize) -> Result<Self> {
        let plane = width.checked_mul(height).ok_or(Error::SizeOverflow { what: "view" })?;
        Self::with_strides(data, channels, width, height, width, plane)
    }

    /// Explicit strides (in elements).
    pub fn with_strides(
        data: &'a mut [T],
        channels: usize,
        width: usize,
        height: usize,
        row_stride: usize,
        plane_stride: usize,
    ) -> Result<Self> {
        let needed = required_len("output view", channels, width, height, row_stride, plane_stride)?;
        if data.len() < needed {
            return Err(Error::BufferTooSmall { what: "output view", needed, got: data.len() });
        }
        Ok(ViewMut {
            ptr: data.as_mut_ptr(),
            shape: Shape::new(channels, width, height),
            row_stride,
            plane_stride,
            frac: 0,
            _m: PhantomData,
        })
    }

    /// Channels, width and height.
    #[inline]
    pub fn shape(&self) -> Shape {
        self.shape
    }
    /// Number of planes.
    #[inline]
    pub fn channels(&self) -> usize {
        self.shape.channels
    }
    /// Pixels per row.
    #[inline]
    pub fn width(&self) -> usize {
        self.shape.width
    }
    /// Rows per plane.
    #[inline]
    pub fn height(&self) -> usize {
        self.shape.height
    }

    /// Fractional bits of a fixed-point tensor (see [`View::frac`]).
    #[inline]
    pub fn frac(&self) -> i8 {
        self.frac
    }

    /// The same view with its fixed-point format set.
    #[inline]
    pub fn with_frac(mut self, frac: i8) -> Self {
        self.frac = frac;
        self
    }

    /// A shared view of the same memory.
    #[inline]
    pub fn as_view(&self) -> View<'_, T> {
        View {
            ptr: self.ptr,
            shape: self.shape,
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        }
    }

    /// A shorter-lived exclusive view of the same memory.
    #[inline]
    pub fn reborrow(&mut self) -> ViewMut<'_, T> {
        ViewMut {
            ptr: self.ptr,
            shape: self.shape,
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        }
    }

    /// Row `y` of plane `c`, shared.
    ///
    /// # Panics
    /// When `c` or `y` is out of range, like slice indexing.
    #[inline]
    pub fn row(&self, c: usize, y: usize) -> &[T] {
        assert!(c < self.shape.channels && y < self.shape.height);
        // SAFETY: in range; checked by the constructor.
        unsafe {
            core::slice::from_raw_parts(self.ptr.add(c * self.plane_stride + y * self.row_stride), self.shape.width)
        }
    }

    /// Raw pointer to element `(c, y, 0)`; provenance covers the whole view.
    #[inline]
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn ptr_mut(&mut self, c: usize, y: usize) -> *mut T {
        debug_assert!(c < self.shape.channels && y < self.shape.height);
        self.ptr.wrapping_add(c * self.plane_stride + y * self.row_stride)
    }

    /// Row `y` of plane `c`, exclusive.
    ///
    /// # Panics
    /// When `c` or `y` is out of range, like slice indexing.
    #[inline]
    pub fn row_mut(&mut self, c: usize, y: usize) -> &mut [T] {
        assert!(c < self.shape.channels && y < self.shape.height);
        // SAFETY: in range; rows never overlap (checked), and `&mut self` is exclusive.
        unsafe {
            core::slice::from_raw_parts_mut(self.ptr.add(c * self.plane_stride + y * self.row_stride), self.shape.width)
        }
    }

    /// Row `y` of planes `0 .. N` at once, each exclusive (the planes are
    /// disjoint, checked at construction).
    ///
    /// # Panics
    /// When `N` exceeds the channels or `y` the rows, like slice indexing.
    #[inline]
    pub fn plane_rows_mut<const N: usize>(&mut self, y: usize) -> [&mut [T]; N] {
        assert!(N <= self.shape.channels && y < self.shape.height);
        let (ptr, ps, rs, w) = (self.ptr, self.plane_stride, self.row_stride, self.shape.width);
        // SAFETY: in range; distinct planes' rows never overlap (checked),
        // and `&mut self` is exclusive for the lifetime of the result.
        core::array::from_fn(|c| unsafe { core::slice::from_raw_parts_mut(ptr.add(c * ps + y * rs), w) })
    }

    /// Sets every element to `v`.
    pub fn fill(&mut self, v: T)
    where
        T: Copy,
    {
        for c in 0..self.shape.channels {
            for y in 0..self.shape.height {
                self.row_mut(c, y).fill(v);
            }
        }
    }

    /// Splits into rows `0..y` and `y..height` of every plane. The two views
    /// touch disjoint memory. `y` is clamped to the height.
    pub fn split_rows_at(self, y: usize) -> (ViewMut<'a, T>, ViewMut<'a, T>) {
        let y = y.min(self.shape.height);
        let top = ViewMut {
            ptr: self.ptr,
            shape: Shape::new(self.shape.channels, self.shape.width, y),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        };
        let rest = self.shape.height - y;
        let bottom = ViewMut {
            // SAFETY: y <= height; when rest > 0 the offset points at row y of plane 0,
            // inside the allocation. When rest == 0 nothing is ever dereferenced.
            ptr: if rest == 0 || self.shape.channels == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(y * self.row_stride) }
            },
            shape: Shape::new(self.shape.channels, self.shape.width, rest),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        };
        (top, bottom)
    }

    /// Splits into planes `0..c` and `c..channels`. The two views touch
    /// disjoint memory (planes never overlap, checked at construction). `c`
    /// is clamped to the channels.
    pub fn split_channels_at(self, c: usize) -> (ViewMut<'a, T>, ViewMut<'a, T>) {
        let c = c.min(self.shape.channels);
        let first = ViewMut {
            ptr: self.ptr,
            shape: Shape::new(c, self.shape.width, self.shape.height),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        };
        let rest = self.shape.channels - c;
        let second = ViewMut {
            // SAFETY: c <= channels; when rest > 0 the offset points at plane c,
            // inside the allocation. Otherwise nothing is ever dereferenced.
            ptr: if rest == 0 || self.shape.height == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(c * self.plane_stride) }
            },
            shape: Shape::new(rest, self.shape.width, self.shape.height),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        };
        (first, second)
    }

    /// Rows `y0 .. y0 + n` of every plane as a shorter-lived exclusive view,
    /// or an error when they are not within the view (like [`View::rows`]).
    pub fn rows_mut(&mut self, y0: usize, n: usize) -> Result<ViewMut<'_, T>> {
        if y0.checked_add(n).is_none_or(|e| e > self.shape.height) {
            return Err(Error::BadParameter { what: "row range", expected: "within the view" });
        }
        Ok(self.rows_mut_clamped(y0, n))
    }

    /// [`ViewMut::rows_mut`] for a range the caller has checked; a range past
    /// the view is clamped to it (like [`ViewMut::split_rows_at`]), never UB.
    #[inline]
    pub(crate) fn rows_mut_clamped(&mut self, y0: usize, n: usize) -> ViewMut<'_, T> {
        debug_assert!(y0.checked_add(n).is_some_and(|e| e <= self.shape.height));
        let y0 = y0.min(self.shape.height);
        let n = n.min(self.shape.height - y0);
        ViewMut {
            // SAFETY: as in View::rows (y0 < height when n > 0).
            ptr: if n == 0 || self.shape.channels == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(y0 * self.row_stride) }
            },
            shape: Shape::new(self.shape.channels, self.shape.width, n),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        }
    }

    /// Planes `c0 .. c0 + n` as their own exclusive view.
    pub fn channels_range_mut(&mut self, c0: usize, n: usize) -> Result<ViewMut<'_, T>> {
        if c0.checked_add(n).is_none_or(|e| e > self.shape.channels) {
            return Err(Error::BadParameter { what: "channel range", expected: "within the view" });
        }
        Ok(ViewMut {
            // SAFETY: as in View::channels_range.
            ptr: if n == 0 || self.shape.height == 0 {
                self.ptr
            } else {
                unsafe { self.ptr.add(c0 * self.plane_stride) }
            },
            shape: Shape::new(n, self.shape.width, self.shape.height),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STRIDES: [usize; 9] = [0, 1, 2, 3, 5, 1 << 40, 1 << 50, usize::MAX / 2, usize::MAX];

    /// Every row of `v` lies inside `base[..len]` (by address).
    fn rows_inside<T>(v: &View<'_, T>, base: *const T, len: usize) {
        let lo = base as usize;
        let hi = lo + len * core::mem::size_of::<T>();
        for c in 0..v.channels() {
            for y in 0..v.height() {
                let r = v.row(c, y);
                let a = r.as_ptr() as usize;
                assert!(a >= lo && a + core::mem::size_of_val(r) <= hi, "row ({c}, {y}) of {v:?} outside the slice");
            }
        }
        assert!(v.ptr as usize >= lo && v.ptr as usize <= hi, "{v:?} points outside the slice");
    }

    #[test]
    fn empty_views_with_huge_strides_are_refused_or_never_offset() {
        // Width 0: rows exist, so their strides are checked like any other view's.
        assert_eq!(
            View::<f32>::with_strides(&[], 2, 0, 2, 1 << 40, 1 << 50).unwrap_err(),
            Error::BufferTooSmall { what: "view", needed: (1 << 50) + (1 << 40), got: 0 }
        );
        assert!(matches!(
            View::<f32>::with_strides(&[], 3, 0, 2, usize::MAX / 2, usize::MAX / 2),
            Err(Error::SizeOverflow { .. })
        ));
        assert!(matches!(ViewMut::<f32>::with_strides(&mut [], 2, 0, 2, 1, 0), Err(Error::BadStrides { .. })));
        // No rows at all: accepted whatever the strides, and no sub-view moves the pointer.
        let data = [0.0f32; 4];
        let v = View::with_strides(&data, 0, 4, usize::MAX, usize::MAX, usize::MAX).unwrap();
        let r = v.rows(usize::MAX - 1, 1).unwrap();
        assert_eq!(r.ptr, data.as_ptr());
        let v = View::with_strides(&data, usize::MAX, 4, 0, usize::MAX, usize::MAX).unwrap();
        assert_eq!(v.channels_range(usize::MAX - 1, 1).unwrap().ptr, data.as_ptr());
        let mut m = [0.0f32; 4];
        let base = m.as_mut_ptr();
        let mut w = ViewMut::with_strides(&mut m, 0, 4, usize::MAX, usize::MAX, usize::MAX).unwrap();
        assert_eq!(w.rows_mut(usize::MAX - 1, 1).unwrap().ptr, base);
        assert!(w.rows_mut(usize::MAX, 1).is_err());
        let (_, bottom) = w.split_rows_at(usize::MAX - 3);
        assert_eq!(bottom.ptr, base);
        let mut w = ViewMut::with_strides(&mut m, usize::MAX, 4, 0, usize::MAX, usize::MAX).unwrap();
        assert_eq!(w.channels_range_mut(usize::MAX - 1, 1).unwrap().ptr, base);
        let (_, second) = w.split_channels_at(5);
        assert_eq!(second.ptr, base);
    }

    #[test]
    fn rows_mut_is_checked_like_rows() {
        let mut m = [0.0f32; 12];
        let mut w = ViewMut::new(&mut m, 2, 3, 2).unwrap();
        assert!(w.rows_mut(1, 2).is_err());
        assert!(w.rows_mut(usize::MAX, 2).is_err());
        assert!(w.as_view().rows(1, 2).is_err());
        let mut band = w.rows_mut(1, 1).unwrap();
        band.row_mut(1, 0)[2] = 7.0;
        assert_eq!(m[11], 7.0);
    }

    /// Every view the public constructors accept, and every sub-view of it,
    /// has all its rows (also the empty rows of width 0) inside the slice:
    /// small extents against tiny and huge strides.
    #[test]
    fn every_constructible_view_stays_inside_its_slice() {
        let data = [0u16; 64];
        let base = data.as_ptr();
        let mut accepted = 0;
        for channels in 0..4 {
            for width in 0..4 {
                for height in 0..4 {
                    for &rs in &STRIDES {
                        for &ps in &STRIDES {
                            let Ok(v) = View::with_strides(&data, channels, width, height, rs, ps) else { continue };
                            accepted += 1;
                            rows_inside(&v, base, data.len());
                            for c0 in 0..=channels {
                                for n in 0..=channels - c0 {
                                    rows_inside(&v.channels_range(c0, n).unwrap(), base, data.len());
                                }
                            }
                            for y0 in 0..=height {
                                for n in 0..=height - y0 {
                                    let r = v.rows(y0, n).unwrap();
                                    rows_inside(&r, base, data.len());
                                    for c0 in 0..=channels {
                                        rows_inside(&r.channels_range(c0, channels - c0).unwrap(), base, data.len());
                                    }
                                }
                            }
                            let mut m = [0u16; 64];
                            let mbase = m.as_ptr();
                            let mut w = ViewMut::with_strides(&mut m, channels, width, height, rs, ps).unwrap();
                            for y0 in 0..=height {
                                rows_inside(&w.rows_mut(y0, height - y0).unwrap().as_view(), mbase, 64);
                            }
                            w.fill(1);
                            let (a, b) = w.split_rows_at(1);
                            rows_inside(&a.as_view(), mbase, 64);
                            rows_inside(&b.as_view(), mbase, 64);
                            let (a, b) = b.split_channels_at(1);
                            rows_inside(&a.as_view(), mbase, 64);
                            rows_inside(&b.as_view(), mbase, 64);
                        }
                    }
                }
            }
        }
        assert!(accepted > 1000, "{accepted}");
    }
}
