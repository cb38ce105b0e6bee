//! The weights loader on arbitrary bytes: a safetensors file or not, it
//! returns the parameters or an error, never panics, and never reads more
//! than the file holds.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mcdenoise::nn::weights::File;

fuzz_target!(|data: &[u8]| {
    let net = mcdenoise::methods::wskp::net(3).expect("the 3-layer network");
    if let Ok(f) = File::from_bytes(data.to_vec(), std::path::Path::new("fuzz.safetensors")) {
        let _ = f.meta("layers");
        let _ = f.names();
        if let Ok(p) = f.params(&net, "wskp", &["adam.m", "adam.v"]) {
            assert_eq!(p.len(), net.params);
            assert!(p.iter().all(|v| v.is_finite()));
        }
    }
});
