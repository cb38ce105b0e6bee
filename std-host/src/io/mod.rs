//! Frames in and out: the EXR loader (the input contract), the writers,
//! the contact sheet, and the list of a sequence's files.

use std::path::PathBuf;

use crate::error::{HostError, Result};

pub mod estimate;
pub mod frame;
pub mod names;
pub mod output;
pub mod sheet;

/// Input files: files as given, directories expanded to their `.exr` files in name order.
pub fn list_inputs(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        let meta = std::fs::metadata(p).map_err(|e| HostError::read(p, e))?;
        if meta.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| HostError::read(p, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.is_file() && f.extension().is_some_and(|x| x.eq_ignore_ascii_case("exr")))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(HostError::bad(p, "directory holds no .exr files"));
            }
            out.extend(files);
        } else {
            out.push(p.clone());
        }
    }
    let mut names = std::collections::HashSet::new();
    for f in &out {
        if !names.insert(f.file_name().map(|n| n.to_os_string())) {
            return Err(HostError::bad(f, "two inputs have this file name; their outputs would collide"));
        }
    }
    Ok(out)
}
