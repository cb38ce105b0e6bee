//! Backward pass of the per-pixel kernel apply (f32): with
//! `out_c(p) = sum_j K_j(p) r_c(p + o_j)` and the output's gradient `g`,
//! - `dK_j(p) = sum_c g_c(p) r_c(p + o_j)` (0 where `p + o_j` is outside),
//! - `dr_c(q) = sum_j K_j(q - o_j) g_c(q - o_j)` over the taps whose pixel
//!   `q - o_j` is inside the image.
//!
//! Both are gathers, so a band of output rows `y0 ..` is computed from the
//! whole inputs with no accumulation across bands. The same loops are
//! compiled for every ISA (vectorised by the compiler across pixels): the
//! same bits on each.

use crate::error::{check_shape, Result, Shape};
use crate::unfold::{check_band, MAX_KERNEL};
use crate::view::{View, ViewMut};
use crate::{check_kernel_size, Isa};

/// The gradients of [`super::apply`] for rows `y0 ..` of `d_kernel` (`k*k`
/// planes) and `d_src` (the source's channels), either of which may be
/// omitted: `kernel`, `src` and `g` whole.
///
/// # Errors
/// [`Error::IsaUnsupported`](crate::Error::IsaUnsupported) when this CPU lacks `isa`;
/// [`Error::ShapeMismatch`](crate::Error::ShapeMismatch) or
/// [`Error::BadParameter`](crate::Error::BadParameter) when an argument's shape, band of rows or
/// parameter is not as described above.
#[allow(clippy::too_many_arguments)]
pub fn apply_grad(
    isa: Isa,
    k: usize,
    kernel: &View<'_, f32>,
    src: &View<'_, f32>,
    g: &View<'_, f32>,
    d_kernel: Option<&mut ViewMut<'_, f32>>,
    d_src: Option<&mut ViewMut<'_, f32>>,
    y0: usize,
) -> Result<()> {
    let isa = isa.check()?;
    check_kernel_size("unfold kernel size", k, MAX_KERNEL)?;
    let s = src.shape();
    check_shape("unfold kernel map", Shape::new(k * k, s.width, s.height), kernel.shape())?;
    check_shape("unfold output gradient", s, g.shape())?;
    if let Some(dk) = &d_kernel {
        check_band("unfold kernel gradient", Shape::new(k * k, s.width, s.height), dk.shape(), y0)?;
    }
    if let Some(ds) = &d_src {
        check_band("unfold source gradient", s, ds.shape(), y0)?;
    }
    let (w, h) = (s.width, s.height);
    let r = k / 2;
    versions!(isa, || {
        if let Some(dk) = d_kernel {
            for j in 0..k * k {
                let (dy, dx) = ((j / k) as isize - r as isize, (j % k) as isize - r as isize);
                for row in 0..dk.height() {
                    let y = y0 + row;
                    let o = dk.row_mut(j, row);
                    o.fill(0.0);
                    let yy = y as isize + dy;
                    if yy < 0 || yy >= h as isize {
                        continue;
                    }
                    // Columns whose tap x + dx is inside.
                    let lo = (-dx).max(0) as usize;
                    let hi = ((w as isize - dx).min(w as isize)).max(0) as usize;
                    for c in 0..s.channels {
                        let (gr, sr) = (g.row(c, y), src.row(c, yy as usize));
                        for x in lo..hi.max(lo) {
                            o[x] += gr[x] * sr[(x as isize + dx) as usize];
                        }
                    }
                }
            }
        }
        if let Some(ds) = d_src {
            for c in 0..s.channels {
                for row in 0..ds.height() {
                    let y = y0 + row;
                    let o = ds.row_mut(c, row);
                    o.fill(0.0);
                    for j in 0..k * k {
                        let (dy, dx) = ((j / k) as isize - r as isize, (j % k) as isize - r as isize);
                        // The pixel p = q - o_j whose tap j lands on q.
                        let py = y as isize - dy;
                        if py < 0 || py >= h as isize {
                            continue;
                        }
                        let (kr, gr) = (kernel.row(j, py as usize), g.row(c, py as usize));
                        let lo = dx.max(0) as usize;
                        let hi = ((w as isize + dx).min(w as isize)).max(0) as usize;
                        for x in lo..hi.max(lo) {
                            let px = (x as isize - dx) as usize;
                            o[x] += kr[px] * gr[px];
                        }
                    }
                }
            }
        }
    });
    Ok(())
}
