//! # mcdenoise
//!
//! The std host around `mcdenoise-core`: thread pools that run the kernels in
//! bands of rows, frame I/O, pipelines, metrics and the `mcdenoise` CLI.

pub mod par;

pub use mcdenoise_core as core;
