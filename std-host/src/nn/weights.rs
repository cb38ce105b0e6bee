//! Network weights as safetensors files (the `safetensors` crate).
//!
//! Tensor names, f32, PyTorch's layout (`[cout][cin][kh][kw]`), for conv
//! layer `i` (counting conv layers only, from 0):
//! - a RepVGG block, training form: `layers.{i}.conv5.weight` `[cout, cin, 5, 5]`,
//!   `layers.{i}.conv3.weight` `[cout, cin, 3, 3]`, `layers.{i}.conv1.weight`
//!   `[cout, cin, 1, 1]` (the identity branch, where `cin == cout`, has no
//!   tensor); merged form: `layers.{i}.weight` `[cout, cin, 5, 5]` with the
//!   identity included;
//! - a plain convolution: `layers.{i}.weight` `[cout, cin, k, k]` and, with a
//!   bias, `layers.{i}.bias` `[cout]`.
//!
//! Metadata: `format` (`mcdenoise-<model>`), `version` (`1`), `form`
//! (`branches` or `merged`), `transform` (the name and version of the
//! input transform the network was trained on, which loading checks) and
//! the model's own keys (e.g. `layers`). A
//! checkpoint adds `adam.m`, `adam.v` (one value per parameter, in the
//! order of [`super::Net`]'s flat vector) and the keys `step`, `adam_t`,
//! `rng`.
//!
//! Loading checks everything before anything is used: the file is a
//! safetensors file, its format and model keys match, every tensor the
//! network needs is there with its shape and dtype F32, nothing else is, and
//! every value is finite; an error names the file and the tensor.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use super::Net;
use crate::error::{HostError, Result};
use crate::runtime::cleanup::atomic_write;

/// Which tensor layout a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Form {
    /// RepVGG branches as trained.
    Branches,
    /// One merged kernel per layer.
    Merged,
}

impl Form {
    fn name(self) -> &'static str {
        match self {
            Form::Branches => "branches",
            Form::Merged => "merged",
        }
    }
}

/// One named tensor to write.
pub struct Tensor<'a> {
    /// Its name.
    pub name: String,
    /// Its shape.
    pub shape: Vec<usize>,
    /// Its values.
    pub data: &'a [f32],
}

/// The tensors of `net`'s parameters in `form` (merged weights computed).
pub fn param_tensors(net: &Net, params: &[f32], form: Form) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut out = Vec::new();
    for (i, c) in net.convs.iter().enumerate() {
        let (cin, cout) = (c.cin, c.spec.cout);
        if c.spec.repvgg && form == Form::Branches {
            let mut at = c.offset;
            for &b in c.branches() {
                let n = cout * cin * b * b;
                out.push((format!("layers.{i}.conv{b}.weight"), vec![cout, cin, b, b], params[at..at + n].to_vec()));
                at += n;
            }
        } else {
            let k = c.k();
            let mut m = vec![0.0; cout * cin * k * k];
            net.merge(params, i, &mut m);
            out.push((format!("layers.{i}.weight"), vec![cout, cin, k, k], m));
        }
        if let Some(b) = net.bias(params, i) {
            out.push((format!("layers.{i}.bias"), vec![cout], b.to_vec()));
        }
    }
    out
}

/// Writes a weights file (atomically: a temporary file renamed into place).
pub fn save(path: &Path, tensors: &[Tensor<'_>], meta: &[(&str, String)]) -> Result<()> {
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|t| {
            let bytes: &[u8] = bytemuck::cast_slice(t.data);
            TensorView::new(Dtype::F32, t.shape.clone(), bytes).map(|v| (t.name.clone(), v))
        })
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| HostError::bad(path, format!("cannot describe a tensor: {e}")))?;
    let meta: HashMap<String, String> = meta.iter().map(|(k, v)| (k.to_string(), v.clone())).collect();
    let bytes = safetensors::tensor::serialize(views, Some(meta))
        .map_err(|e| HostError::bad(path, format!("cannot encode: {e}")))?;
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| HostError::write(d, e))?;
    }
    atomic_write(path, |tmp| std::fs::write(tmp, &bytes).map_err(|e| e.to_string()))
}

/// Saves `net`'s parameters in `form` with the model's metadata.
pub fn save_params(
    path: &Path,
    net: &Net,
    params: &[f32],
    form: Form,
    model: &str,
    meta: &[(&str, String)],
) -> Result<()> {
    save_model(path, model, &[("", net, params)], form, meta, &[])
}

/// The one writer of this crate's weights files: the networks of a model
/// (each with the prefix of its tensor names: `""`, `"refine."`), in `form`,
/// the metadata every file carries (`format`, `version`, `form`) followed by
/// `meta`, and `extra` tensors (Adam's state in a checkpoint).
pub fn save_model(
    path: &Path,
    model: &str,
    nets: &[(&str, &Net, &[f32])],
    form: Form,
    meta: &[(&str, String)],
    extra: &[Tensor<'_>],
) -> Result<()> {
    let mut owned = Vec::new();
    for &(prefix, net, params) in nets {
        owned.extend(param_tensors(net, params, form).into_iter().map(|(n, s, d)| (format!("{prefix}{n}"), s, d)));
    }
    let mut tensors: Vec<Tensor<'_>> =
        owned.iter().map(|(n, s, d)| Tensor { name: n.clone(), shape: s.clone(), data: d }).collect();
    tensors.extend(extra.iter().map(|t| Tensor { name: t.name.clone(), shape: t.shape.clone(), data: t.data }));
    let mut all =
        vec![("format", format!("mcdenoise-{model}")), ("version", "1".to_string()), ("form", form.name().to_string())];
    all.extend(meta.iter().cloned());
    save(path, &tensors, &all)
}

/// A weights file, read and checked as a safetensors file.
pub struct File {
    bytes: Vec<u8>,
    path: std::path::PathBuf,
}

/// Largest weights file read (a network of this crate is well under a megabyte).
pub const MAX_BYTES: u64 = 256 << 20;

impl File {
    /// Reads a file (at most [`MAX_BYTES`]).
    pub fn read(path: &Path) -> Result<File> {
        use std::io::Read;
        let f = std::fs::File::open(path).map_err(|e| HostError::bad(path, format!("cannot open: {e}")))?;
        let mut bytes = Vec::new();
        f.take(MAX_BYTES + 1).read_to_end(&mut bytes).map_err(|e| HostError::bad(path, format!("cannot read: {e}")))?;
        if bytes.len() as u64 > MAX_BYTES {
            return Err(HostError::bad(
                path,
                format!("larger than {} MiB: not a weights file of this crate", MAX_BYTES >> 20),
            ));
        }
        File::from_bytes(bytes, path)
    }

    /// Checks bytes already in memory.
    pub fn from_bytes(bytes: Vec<u8>, path: &Path) -> Result<File> {
        SafeTensors::deserialize(&bytes).map_err(|e| HostError::bad(path, format!("not a safetensors file ({e})")))?;
        Ok(File { bytes, path: path.to_path_buf() })
    }

    fn st(&self) -> SafeTensors<'_> {
        SafeTensors::deserialize(&self.bytes).expect("checked when read")
    }

    /// A metadata value.
    pub fn meta(&self, key: &str) -> Option<String> {
        let (_, m) = SafeTensors::read_metadata(&self.bytes).ok()?;
        m.metadata().as_ref().and_then(|h| h.get(key).cloned())
    }

    /// The file's path.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Checks a metadata key has the expected value.
    pub fn expect_meta(&self, key: &str, want: &str) -> Result<()> {
        match self.meta(key) {
            Some(v) if v == want => Ok(()),
            Some(v) => Err(HostError::bad(&self.path, format!("metadata {key} is '{v}', expected '{want}'"))),
            None => Err(HostError::bad(&self.path, format!("metadata {key} missing (expected '{want}')"))),
        }
    }

    /// Checks the file was trained on inputs made by the transform `want`
    /// (metadata `transform`, a name with its version): weights trained on
    /// other inputs would run and give wrong pictures, so they are refused.
    pub fn expect_transform(&self, want: &str) -> Result<()> {
        match self.meta("transform") {
            Some(v) if v == want => Ok(()),
            Some(v) => Err(HostError::bad(
                &self.path,
                format!(
                    "trained on inputs made by the transform '{v}', but this build makes them with '{want}'; \
                     retrain the weights with this build's 'mcdenoise train'"
                ),
            )),
            None => Err(HostError::bad(
                &self.path,
                format!(
                    "records no input transform (made by an older build); this build's inputs are '{want}': \
                     retrain the weights with this build's 'mcdenoise train'"
                ),
            )),
        }
    }

    /// The f32 values of tensor `name` with shape `shape`, checked finite.
    pub fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let st = self.st();
        let t = st.tensor(name).map_err(|_| HostError::bad(&self.path, format!("tensor {name} missing")))?;
        if t.dtype() != Dtype::F32 {
            return Err(HostError::bad(&self.path, format!("tensor {name} is {:?}, expected F32", t.dtype())));
        }
        if t.shape() != shape {
            return Err(HostError::bad(
                &self.path,
                format!("tensor {name} has shape {:?}, expected {shape:?}", t.shape()),
            ));
        }
        let v: Vec<f32> = t.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(HostError::bad(&self.path, format!("tensor {name} holds a non-finite value at index {i}")));
        }
        Ok(v)
    }

    /// The tensor names.
    pub fn names(&self) -> Vec<String> {
        self.st().names().into_iter().map(String::from).collect()
    }

    /// `net`'s parameters from the tensors named with `prefix` (a second
    /// network in the same file, e.g. `refine.layers.0.weight`), branches form.
    pub fn params_prefixed(&self, net: &Net, prefix: &str) -> Result<Vec<f32>> {
        let mut p = vec![0.0f32; net.params];
        for (i, c) in net.convs.iter().enumerate() {
            let (cin, cout) = (c.cin, c.spec.cout);
            let mut at = c.offset;
            if c.spec.repvgg {
                for &b in c.branches() {
                    let v = self.tensor(&format!("{prefix}layers.{i}.conv{b}.weight"), &[cout, cin, b, b])?;
                    p[at..at + v.len()].copy_from_slice(&v);
                    at += v.len();
                }
            } else {
                let k = c.k();
                let v = self.tensor(&format!("{prefix}layers.{i}.weight"), &[cout, cin, k, k])?;
                p[at..at + v.len()].copy_from_slice(&v);
            }
            if c.spec.bias {
                let v = self.tensor(&format!("{prefix}layers.{i}.bias"), &[cout])?;
                p[c.offset + c.count - cout..c.offset + c.count].copy_from_slice(&v);
            }
        }
        Ok(p)
    }

    /// `net`'s parameters from the file (either form), after checking the
    /// format and that no tensor is left unused besides `allowed_extra`.
    pub fn params(&self, net: &Net, model: &str, allowed_extra: &[&str]) -> Result<Vec<f32>> {
        self.expect_meta("format", &format!("mcdenoise-{model}"))?;
        let form = match self.meta("form").as_deref() {
            Some("branches") => Form::Branches,
            Some("merged") => Form::Merged,
            Some(v) => {
                return Err(HostError::bad(&self.path, format!("metadata form is '{v}', expected branches or merged")))
            }
            None => return Err(HostError::bad(&self.path, "metadata form missing (expected branches or merged)")),
        };
        let mut p = vec![0.0f32; net.params];
        let mut used: Vec<String> = Vec::new();
        for (i, c) in net.convs.iter().enumerate() {
            let (cin, cout) = (c.cin, c.spec.cout);
            if c.spec.repvgg && form == Form::Branches {
                let mut at = c.offset;
                for &b in c.branches() {
                    let name = format!("layers.{i}.conv{b}.weight");
                    let v = self.tensor(&name, &[cout, cin, b, b])?;
                    p[at..at + v.len()].copy_from_slice(&v);
                    at += v.len();
                    used.push(name);
                }
            } else {
                let k = c.k();
                let name = format!("layers.{i}.weight");
                let mut v = self.tensor(&name, &[cout, cin, k, k])?;
                if c.identity() {
                    // The merged kernel includes the identity branch the
                    // parameters add back.
                    for o in 0..cout {
                        v[((o * cin + o) * k + k / 2) * k + k / 2] -= 1.0;
                    }
                }
                // Into the largest branch; the others stay 0.
                p[c.offset..c.offset + v.len()].copy_from_slice(&v);
                used.push(name);
            }
            if c.spec.bias {
                let name = format!("layers.{i}.bias");
                let v = self.tensor(&name, &[cout])?;
                p[c.offset + c.count - cout..c.offset + c.count].copy_from_slice(&v);
                used.push(name);
            }
        }
        for n in self.names() {
            if !used.contains(&n) && !allowed_extra.contains(&n.as_str()) {
                return Err(HostError::bad(&self.path, format!("tensor {n} is not part of this network")));
            }
        }
        Ok(p)
    }
}
