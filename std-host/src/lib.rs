//! # mcdenoise
//!
//! The std host around `mcdenoise-core`: thread pools that run the kernels in
//! bands of rows, frame I/O in the input contract, pipelines, metrics and the
//! `mcdenoise` CLI.

#![warn(missing_docs)]

pub mod afn;
pub mod aligned;
pub mod cleanup;
pub mod cross;
pub mod error;
pub mod frame;
pub mod memory;
pub mod methods;
pub mod metrics;
pub mod nn;
pub mod output;
pub mod par;
pub mod precision;
pub mod run;
pub mod sheet;
pub mod train;
pub mod weights;
pub mod wskp;

// Not the library's API: the command line, the f64 oracle, the operator
// registry and the precision report serve this workspace's binary, tests,
// benches and fuzz targets, and may change with them.
#[doc(hidden)]
pub mod cli;
#[doc(hidden)]
pub mod oracle;
#[doc(hidden)]
pub mod registry;
#[doc(hidden)]
pub mod report;

pub use error::{HostError, Result};
pub use frame::{Buffer, Frame, Limits};
pub use mcdenoise_core as core;
