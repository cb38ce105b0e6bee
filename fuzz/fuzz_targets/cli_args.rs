//! The CLI's argument parser on arbitrary arguments (split at NUL bytes):
//! a command or a usage error naming the argument, never a panic.
#![no_main]

use std::ffi::OsString;
use std::os::unix::ffi::OsStringExt;

use libfuzzer_sys::fuzz_target;
use mcdenoise_cli::cli;

fuzz_target!(|data: &[u8]| {
    let args: Vec<OsString> = data.split(|&b| b == 0).map(|a| OsString::from_vec(a.to_vec())).collect();
    match cli::parse(args) {
        Ok(_) => {}
        Err(e) => assert!(!e.to_string().is_empty()),
    }
});
