//! The one error type of the kernel crate.
//!
//! Every operator checks the shapes of its arguments once, up front, and
//! returns one of these instead of panicking. The variants carry `&'static str`
//! names of the offending argument so that the host can print a clear line.

use core::fmt;

use crate::isa::Isa;

/// Channels, width and height of a planar tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Shape {
    /// Number of planes.
    pub channels: usize,
    /// Pixels per row.
    pub width: usize,
    /// Rows per plane.
    pub height: usize,
}

impl Shape {
    /// A shape from its three extents.
    pub const fn new(channels: usize, width: usize, height: usize) -> Self {
        Shape { channels, width, height }
    }
}

impl fmt::Display for Shape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}ch {}x{}", self.channels, self.width, self.height)
    }
}

/// What went wrong in a kernel call. Nothing in this crate panics on caller
/// input; it returns one of these.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Error {
    /// A buffer is shorter than the shape it is declared with needs.
    BufferTooSmall {
        /// Which argument.
        what: &'static str,
        /// Elements the shape needs.
        needed: usize,
        /// Elements the slice has.
        got: usize,
    },
    /// Strides that would make rows or planes overlap.
    BadStrides {
        /// Which argument.
        what: &'static str,
    },
    /// A size computation overflowed `usize`.
    SizeOverflow {
        /// Which argument.
        what: &'static str,
    },
    /// Two tensors that must agree in shape do not.
    ShapeMismatch {
        /// Which argument.
        what: &'static str,
        /// The shape the operator needs.
        expected: Shape,
        /// The shape it was given.
        got: Shape,
    },
    /// A parameter outside its documented range.
    BadParameter {
        /// Which parameter.
        what: &'static str,
        /// Its allowed range, in words.
        expected: &'static str,
    },
    /// The scratch slice is shorter than `*_scratch_len` asked for.
    ScratchTooSmall {
        /// Words needed.
        needed: usize,
        /// Words given.
        got: usize,
    },
    /// The instruction set was forced but this CPU does not have it.
    IsaUnsupported {
        /// The instruction set asked for.
        isa: Isa,
    },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::BufferTooSmall { what, needed, got } => {
                write!(f, "{what}: buffer holds {got} elements, its shape needs {needed}")
            }
            Error::BadStrides { what } => write!(f, "{what}: strides make rows or planes overlap"),
            Error::SizeOverflow { what } => write!(f, "{what}: size overflows the address space"),
            Error::ShapeMismatch { what, expected, got } => {
                write!(f, "{what}: expected {expected}, got {got}")
            }
            Error::BadParameter { what, expected } => write!(f, "{what}: expected {expected}"),
            Error::ScratchTooSmall { needed, got } => {
                write!(f, "scratch: {got} words given, {needed} needed")
            }
            Error::IsaUnsupported { isa } => {
                write!(f, "instruction set {} is not supported by this CPU", isa.name())
            }
        }
    }
}

/// Result with this crate's error.
pub type Result<T> = core::result::Result<T, Error>;

/// Returns `ScratchTooSmall` unless `got >= needed`.
pub(crate) fn check_scratch(needed: usize, got: usize) -> Result<()> {
    if got < needed {
        Err(Error::ScratchTooSmall { needed, got })
    } else {
        Ok(())
    }
}

/// Checks that a tensor has the expected shape.
pub(crate) fn check_shape(what: &'static str, expected: Shape, got: Shape) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::ShapeMismatch { what, expected, got })
    }
}
