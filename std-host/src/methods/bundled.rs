//! The trained weights a learned method uses: a file given with
//! `--weights`, or the weights bundled in this crate (`std-host/weights/`,
//! made by `mcdenoise train` with the commands in docs/training.md).

use std::path::Path;

use crate::error::{HostError, Result};
use crate::nn::weights::File;

/// The 3- and 6-layer ImportanceNets, trained by `tools/train-all.sh` (docs/training.md).
const WSKP3: &[u8] = include_bytes!("../../weights/wskp3.safetensors");
const WSKP6: &[u8] = include_bytes!("../../weights/wskp6.safetensors");
/// AFN's kernel predictor and refinement network, trained the same way.
const AFN: &[u8] = include_bytes!("../../weights/afn.safetensors");

/// WSKP's weights for `layers` layers.
pub fn wskp(path: Option<&Path>, layers: usize) -> Result<File> {
    if let Some(p) = path {
        return File::read(p);
    }
    let bundled: Option<&'static [u8]> = match layers {
        3 => Some(WSKP3),
        6 => Some(WSKP6),
        _ => None,
    };
    match bundled {
        Some(b) => File::from_bytes(b.to_vec(), Path::new(&format!("<bundled wskp{layers}>"))),
        None => Err(HostError::Usage(format!(
            "wskp: no bundled weights for {layers} layers in this build; pass --weights FILE (made by 'mcdenoise train --method wskp')"
        ))),
    }
}

/// AFN's weights (both networks in one file).
pub fn afn(path: Option<&Path>) -> Result<File> {
    if let Some(p) = path {
        return File::read(p);
    }
    File::from_bytes(AFN.to_vec(), Path::new("<bundled afn>"))
}
