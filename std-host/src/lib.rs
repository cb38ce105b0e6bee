//! # mcdenoise
//!
//! The std host around `mcdenoise-core`: thread pools that run the kernels in
//! bands of rows, frame I/O in the input contract, pipelines, metrics and the
//! `mcdenoise` CLI.

pub mod aligned;
pub mod cli;
pub mod error;
pub mod frame;
pub mod methods;
pub mod metrics;
pub mod oracle;
pub mod output;
pub mod par;
pub mod precision;
pub mod report;
pub mod run;

pub use error::{HostError, Result};
pub use frame::{Buffer, Frame, Limits};
pub use mcdenoise_core as core;
