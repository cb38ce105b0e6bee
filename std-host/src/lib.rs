//! # mcdenoise
//!
//! The std host around `mcdenoise-core`: frames in and out, the runtime the
//! kernels run in (threads, scratch, precision, memory), the network engine,
//! the denoising methods and their training, and metrics. The `mcdenoise`
//! command line is the `mcdenoise-cli` crate, built on this one.
//!
//! Layers, each depending only on those above it:
//! - [`runtime`]: the thread pool and per-band scratch ([`runtime::Ctx`]),
//!   precisions, memory accounting, temporary-file cleanup;
//! - [`io`]: the EXR loader of the input contract, the writers, the memory
//!   estimate of a frame from its header;
//! - [`nn`]: network graphs, training (backward passes, Adam, losses),
//!   streamed inference, quantisation, safetensors weights;
//! - [`methods`]: the denoisers over one shared [`methods::features`]
//!   module (demodulation, emitters, tone curve, normals, depth);
//! - [`pipeline`] (a sequence through a method), [`train`] (`mcdenoise
//!   train`), [`metrics`].
//!
//! `docs/architecture.md` draws it and says where to add a method, an
//! operator or a network.

#![warn(missing_docs)]

pub mod error;
pub mod io;
pub mod methods;
pub mod metrics;
pub mod nn;
pub mod pipeline;
pub mod runtime;
pub mod train;

pub use error::{HostError, Result};
pub use io::frame::{Buffer, Frame, Limits};
pub use mcdenoise_core as core;
