//! Threads: the host splits an output into bands of rows and runs a kernel's
//! `*_rows` form on each band in parallel. The kernels compute every output
//! value from its position alone (the box-sum path uses a fixed tile grid), so
//! the result is bit-identical for any thread count.
//!
//! Scratch is owned by the caller ([`Scratch`], one buffer per band, kept
//! across frames): no allocation per call once warm, and no thread-local heap.

use mcdenoise_core::{Result as CoreResult, ViewMut};
use rayon::prelude::*;

/// A thread pool of a fixed size. Cloning shares the pool (the reader and
/// writer of a pipelined sequence run on the denoiser's threads).
#[derive(Clone)]
pub struct Pool {
    pool: std::sync::Arc<rayon::ThreadPool>,
    threads: usize,
}

impl std::fmt::Debug for Pool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Pool({} threads)", self.threads)
    }
}

/// Per-band scratch buffers, reused across calls.
#[derive(Default, Debug)]
pub struct Scratch {
    bufs: Vec<Vec<f32>>,
}

impl Scratch {
    /// Empty; grows on first use.
    pub fn new() -> Self {
        Scratch::default()
    }
    fn ensure(&mut self, n: usize, len: usize) {
        if self.bufs.len() < n {
            self.bufs.resize_with(n, Vec::new);
        }
        for b in &mut self.bufs[..n] {
            if b.len() < len {
                b.resize(len, 0.0);
            }
        }
    }
}

impl Pool {
    /// A pool of `threads` threads (at least one).
    pub fn new(threads: usize) -> std::result::Result<Pool, String> {
        let threads = threads.max(1);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| format!("cannot start {threads} threads: {e}"))?;
        Ok(Pool { pool: std::sync::Arc::new(pool), threads })
    }

    /// Threads in the pool.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Row bands for `height` rows: one per thread, boundaries on multiples of `align`.
    pub fn band_starts(&self, height: usize, align: usize) -> Vec<usize> {
        let align = align.max(1);
        let per = height.div_ceil(self.threads).div_ceil(align) * align;
        let mut starts = Vec::new();
        let mut y = 0;
        while y < height {
            starts.push(y);
            y += per.max(1);
        }
        starts
    }

    /// Runs `f(band, y0, scratch)` on bands of `dst` in parallel; `y0` is the
    /// band's first row in `dst`. Each band gets `scratch_len` words of scratch.
    pub fn bands<T: Send>(
        &self,
        dst: ViewMut<'_, T>,
        align: usize,
        scratch: &mut Scratch,
        scratch_len: usize,
        f: impl Fn(&mut ViewMut<'_, T>, usize, &mut [f32]) -> CoreResult<()> + Sync,
    ) -> CoreResult<()> {
        let starts = self.band_starts(dst.height(), align);
        scratch.ensure(starts.len(), scratch_len);
        let mut bands = Vec::with_capacity(starts.len());
        let mut rest = dst;
        for (i, &y0) in starts.iter().enumerate() {
            let end = starts.get(i + 1).copied().unwrap_or(y0 + rest.height());
            let (band, tail) = rest.split_rows_at(end - y0);
            bands.push((band, y0));
            rest = tail;
        }
        if bands.len() == 1 {
            let (mut band, y0) = bands.pop().expect("one band");
            return f(&mut band, y0, &mut scratch.bufs[0][..scratch_len]);
        }
        self.pool.install(|| {
            bands
                .into_par_iter()
                .zip(scratch.bufs.par_iter_mut())
                .try_for_each(|((mut band, y0), s)| f(&mut band, y0, &mut s[..scratch_len]))
        })
    }

    /// Runs `f` inside the pool (rayon's parallel iterators then use its threads).
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.pool.install(f)
    }

    /// Cuts every plane of `planes` (all of one length) into runs of `chunk`
    /// elements and calls `f(start, runs)` on each run in parallel, `runs`
    /// holding the same run of every plane. For per-pixel passes over planar
    /// images.
    pub fn planes(&self, planes: Vec<&mut [f32]>, chunk: usize, f: impl Fn(usize, &mut [&mut [f32]]) + Sync + Send) {
        let n = planes.first().map_or(0, |p| p.len());
        assert!(planes.iter().all(|p| p.len() == n), "planes of different lengths");
        let chunk = chunk.max(1);
        let mut iters: Vec<_> = planes.into_iter().map(|p| p.chunks_mut(chunk)).collect();
        let jobs: Vec<(usize, Vec<&mut [f32]>)> = (0..n.div_ceil(chunk))
            .map(|i| (i * chunk, iters.iter_mut().map(|it| it.next().expect("equal lengths")).collect()))
            .collect();
        self.pool.install(|| jobs.into_par_iter().for_each(|(start, mut runs)| f(start, &mut runs)));
    }

    /// `f(i)` for `i in 0..n` on the pool's threads, results in order.
    pub fn map<T: Send>(&self, n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
        self.pool.install(|| (0..n).into_par_iter().map(f).collect())
    }

    /// Like [`Pool::bands`] for a kernel with two outputs of the same height
    /// (split into the same bands).
    pub fn bands2<T: Send, U: Send>(
        &self,
        a: ViewMut<'_, T>,
        b: ViewMut<'_, U>,
        align: usize,
        scratch: &mut Scratch,
        scratch_len: usize,
        f: impl Fn(&mut ViewMut<'_, T>, &mut ViewMut<'_, U>, usize, &mut [f32]) -> CoreResult<()> + Sync,
    ) -> CoreResult<()> {
        assert_eq!(a.height(), b.height(), "bands2 outputs differ in height");
        let starts = self.band_starts(a.height(), align);
        scratch.ensure(starts.len(), scratch_len);
        let mut bands = Vec::with_capacity(starts.len());
        let (mut ra, mut rb) = (a, b);
        for (i, &y0) in starts.iter().enumerate() {
            let end = starts.get(i + 1).copied().unwrap_or(y0 + ra.height());
            let (ba, ta) = ra.split_rows_at(end - y0);
            let (bb, tb) = rb.split_rows_at(end - y0);
            bands.push((ba, bb, y0));
            ra = ta;
            rb = tb;
        }
        self.pool.install(|| {
            bands
                .into_par_iter()
                .zip(scratch.bufs.par_iter_mut())
                .try_for_each(|((mut ba, mut bb, y0), s)| f(&mut ba, &mut bb, y0, &mut s[..scratch_len]))
        })
    }
}
