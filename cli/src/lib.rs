//! The `mcdenoise` command line over the `mcdenoise` library: argument
//! parsing ([`cli`], clap) and the commands ([`commands`]). A library too,
//! so that the fuzz targets and tests reach the parser.

#![warn(missing_docs)]

pub mod cli;
pub mod commands;
