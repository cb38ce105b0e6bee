//! The test and bench kit of mcdenoise (not part of the library's API):
//! the exact f64 oracle every operator is checked against ([`oracle`]), the
//! registry of core operators with their inputs, tolerances and oracles
//! ([`registry`]), and the time-against-error report behind `mcdenoise
//! precision` ([`report`]). Used by the tests, the benches, the fuzz
//! targets and the CLI.

#![warn(missing_docs)]

pub mod oracle;
pub mod registry;
pub mod report;
