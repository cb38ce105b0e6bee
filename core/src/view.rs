//! Borrowed planar tensor views.
//!
//! A view is `channels` planes of `height` rows of `width` elements. Element
//! `(c, y, x)` lives at `c * plane_stride + y * row_stride + x`. Constructors
//! check once that the slice is long enough and that rows and planes do not
//! overlap (`row_stride >= width`, `plane_stride >= (height - 1) * row_stride + width`),
//! which is what makes [`ViewMut::split_rows_at`] sound: the bands it returns
//! touch disjoint memory and can go to different threads.

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
    if channels == 0 || width == 0 || height == 0 {
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
            // SAFETY: c0 <= channels, so the offset stays inside the checked allocation
            // (or one past it when n == 0, which is never dereferenced).
            ptr: if n == 0 { self.ptr } else { unsafe { self.ptr.add(c0 * self.plane_stride) } },
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
            // SAFETY: as in channels_range.
            ptr: if n == 0 { self.ptr } else { unsafe { self.ptr.add(y0 * self.row_stride) } },
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
            ptr: if rest == 0 || self.shape.channels == 0 || self.shape.width == 0 {
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
            ptr: if rest == 0 || self.shape.width == 0 || self.shape.height == 0 {
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

    /// Rows `y0 .. y0 + n` of every plane as a shorter-lived exclusive view.
    ///
    /// # Panics
    /// When the rows are out of range, like slice indexing.
    pub fn rows_mut(&mut self, y0: usize, n: usize) -> ViewMut<'_, T> {
        assert!(y0.checked_add(n).is_some_and(|e| e <= self.shape.height));
        ViewMut {
            ptr: if n == 0 { self.ptr } else { self.ptr.wrapping_add(y0 * self.row_stride) },
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
            ptr: if n == 0 { self.ptr } else { unsafe { self.ptr.add(c0 * self.plane_stride) } },
            shape: Shape::new(n, self.shape.width, self.shape.height),
            row_stride: self.row_stride,
            plane_stride: self.plane_stride,
            frac: self.frac,
            _m: PhantomData,
        })
    }
}
