//! The host's EXR loader on arbitrary bytes (with its size limits): an error
//! or a frame whose buffers have their shapes and hold only finite values,
//! never a panic, never an allocation beyond the limits (run with
//! `-rss_limit_mb`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use mcdenoise::io::frame::{Buffer, Frame, Limits};

fuzz_target!(|data: &[u8]| {
    // Small limits so a hostile header cannot make a legitimate huge image.
    let limits = Limits { max_side: 4096, max_pixels: 1 << 20, max_channels: 64, max_file_bytes: 1 << 24 };
    if let Ok(f) = Frame::load_bytes(data, std::path::Path::new("fuzz.exr"), &limits) {
        assert!(f.width * f.height <= limits.max_pixels);
        for b in Buffer::ALL {
            if let Some(v) = f.get(b) {
                assert_eq!(v.len(), b.channels() * f.width * f.height);
                assert!(v.iter().all(|x| x.is_finite()), "loader must sanitise");
            }
        }
    }
});
