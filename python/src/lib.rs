//! `mcdenoise` for Python: numpy arrays in, a denoised array out. A thin
//! layer over the `mcdenoise` library (the same code as the CLI): arrays
//! become a frame's planes, keyword arguments become the method's settings,
//! errors become `ValueError` or `TypeError` with the library's message.
//! The GIL is released while the kernels run.

use std::path::PathBuf;

use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise::runtime::Ctx;
use mcdenoise::HostError;
use numpy::{IntoPyArray, PyArray3, PyArrayDyn, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The library's error as a Python exception: a bad array or option is a
/// `ValueError` (or `TypeError` for a wrong type), with the same words.
fn err(e: HostError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The buffers a call can pass, with their keyword, planes and the
/// accepted last-axis sizes.
const BUFFERS: [(&str, Buffer); 6] = [
    ("albedo", Buffer::Albedo),
    ("normal", Buffer::Normal),
    ("depth", Buffer::Depth),
    ("position", Buffer::Position),
    ("motion", Buffer::Motion),
    ("second", Buffer::ColorB),
];

/// Planar f32 planes (`planes` of `h x w`) from an `H x W x C` (or, for one
/// plane, `H x W`) float32 or float16 array, read in place through its
/// strides (no copy of the array is made first). Colour may carry a 4th
/// channel (alpha), which is ignored.
fn read_planes(
    obj: &Bound<'_, PyAny>,
    what: &str,
    planes: usize,
    size: Option<(usize, usize)>,
) -> PyResult<(usize, usize, Vec<f32>)> {
    fn fill<T: Copy + numpy::Element>(
        a: &Bound<'_, PyArrayDyn<T>>,
        what: &str,
        planes: usize,
        conv: impl Fn(T) -> f32,
    ) -> PyResult<(usize, usize, Vec<f32>)> {
        let ro = a.readonly();
        let v = ro.as_array();
        let shape = v.shape().to_vec();
        let (h, w, c) = match shape.as_slice() {
            [h, w] => (*h, *w, 1),
            [h, w, c] => (*h, *w, *c),
            _ => {
                return Err(PyValueError::new_err(format!("{what}: expected an H x W x C array, got shape {shape:?}")))
            }
        };
        let ok = c == planes || (what == "color" && c == 4);
        if !ok {
            return Err(PyValueError::new_err(format!(
                "{what}: expected {planes} channel{} in the last axis, got {c}",
                if planes == 1 { "" } else { "s" }
            )));
        }
        let n = w * h;
        let mut out = vec![0.0f32; planes * n];
        if shape.len() == 2 {
            for ((y, x), &val) in v.into_dimensionality::<numpy::ndarray::Ix2>().expect("two axes").indexed_iter() {
                out[y * w + x] = conv(val);
            }
        } else {
            let v3 = v.into_dimensionality::<numpy::ndarray::Ix3>().expect("three axes");
            for ch in 0..planes {
                let plane = &mut out[ch * n..(ch + 1) * n];
                for (y, row) in v3.index_axis(numpy::ndarray::Axis(2), ch).outer_iter().enumerate() {
                    for (x, &val) in row.iter().enumerate() {
                        plane[y * w + x] = conv(val);
                    }
                }
            }
        }
        Ok((w, h, out))
    }
    let r = if let Ok(a) = obj.cast::<PyArrayDyn<f32>>() {
        fill(a, what, planes, |v| v)?
    } else if let Ok(a) = obj.cast::<PyArrayDyn<half::f16>>() {
        fill(a, what, planes, |v| v.to_f32())?
    } else {
        let ty = obj.get_type().name().map(|n| n.to_string()).unwrap_or_default();
        let dtype = obj.getattr("dtype").map(|d| d.to_string()).unwrap_or(ty);
        return Err(PyTypeError::new_err(format!("{what}: expected a numpy float32 or float16 array, got {dtype}")));
    };
    if let Some((w, h)) = size {
        if (r.0, r.1) != (w, h) {
            return Err(PyValueError::new_err(format!(
                "{what}: the array is {}x{} (W x H), the colour is {w}x{h}",
                r.0, r.1
            )));
        }
    }
    Ok(r)
}

/// A frame from keyword arrays (`color` and the optional buffers).
fn frame_of(color: &Bound<'_, PyAny>, buffers: &[(Buffer, &str, Bound<'_, PyAny>)]) -> PyResult<Frame> {
    let (w, h, c) = read_planes(color, "color", 3, None)?;
    if w == 0 || h == 0 {
        return Err(PyValueError::new_err(format!("color: an empty {w}x{h} image")));
    }
    let mut f = Frame::from_color("<arrays>", w, h, c).map_err(err)?;
    for (b, name, obj) in buffers {
        let (_, _, v) = read_planes(obj, name, b.channels(), Some((w, h)))?;
        // Sanitised as the EXR loader does: NaN to 0, ±inf to ±1e20.
        let v: Vec<f32> = v.into_iter().map(mcdenoise::io::frame::sanitize).collect();
        f.set(*b, v).map_err(err)?;
    }
    let c: Vec<f32> =
        f.get(Buffer::Color).expect("set above").iter().map(|&v| mcdenoise::io::frame::sanitize(v)).collect();
    f.set(Buffer::Color, c).map_err(err)?;
    Ok(f)
}

/// Method settings from `method`, `precision`, `threads` and the options.
fn settings_of(
    method: &str,
    precision: &str,
    threads: Option<usize>,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<(MethodKind, Settings)> {
    let kind =
        MethodKind::parse(method).map_err(|e| PyValueError::new_err(e.to_string().replace("--method", "method")))?;
    let precision = PrecisionKind::parse(precision)
        .map_err(|e| PyValueError::new_err(e.to_string().replace("--precision", "precision")))?;
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = threads.unwrap_or(all);
    if !(1..=256).contains(&threads) {
        return Err(PyValueError::new_err(format!("threads: expected a whole number from 1 to 256, got {threads}")));
    }
    let mut s = Settings { precision, threads, ..Settings::default() };
    if let Some(opts) = options {
        for (k, v) in opts.iter() {
            let key: String = k.extract()?;
            let real = |lo: f64, hi: f64, text: &str| -> PyResult<f32> {
                let x: f64 = v.extract()?;
                if x.is_finite() && x >= lo && x <= hi && !(text.starts_with("a positive") && x == 0.0) {
                    Ok(x as f32)
                } else {
                    Err(PyValueError::new_err(format!("{key}: expected {text}, got {x}")))
                }
            };
            match key.as_str() {
                "layers" => {
                    let l: usize = v.extract()?;
                    if l != 3 && l != 6 {
                        return Err(PyValueError::new_err(format!("layers: expected 3 or 6, got {l}")));
                    }
                    s.layers = l;
                }
                "weights" => s.weights = Some(PathBuf::from(v.extract::<String>()?)),
                "refine" => s.refine = v.extract()?,
                "fallback" => s.fallback = v.extract()?,
                "phi_color" => s.phi_color = Some(real(0.0, 1e6, "a positive number up to 1e6")?),
                "firefly_clamp" => s.firefly_clamp = Some(real(0.0, 1e6, "a number from 0 (off) up to 1e6")?),
                "ta_clamp" => s.ta_clamp = Some(real(0.0, 1e6, "a number from 0 (off) up to 1e6")?),
                "ta_reject" => s.ta_reject = Some(real(0.0, 1e6, "a number from 0 (off) up to 1e6")?),
                "ta_reject_scales" => {
                    let k: usize = v.extract()?;
                    if !(1..=3).contains(&k) {
                        return Err(PyValueError::new_err(format!(
                            "ta_reject_scales: expected 1 (9x9 means), 2 (and 17x17) or 3 (and 33x33), got {k}"
                        )));
                    }
                    s.ta_reject_scales = Some(k);
                }
                "ta_relight" => s.ta_relight = v.extract()?,
                "pair" => {
                    let name: String = v.extract()?;
                    s.pair = methods::PairUse::from_name(&name).ok_or_else(|| {
                        PyValueError::new_err(format!("pair: expected 'mean' or 'first', got '{name}'"))
                    })?;
                }
                "seed" => s.seed = v.extract()?,
                "cross_lr" => s.cross_lr = real(0.0, 1.0, "a positive number up to 1")?,
                "cross_spatial_only" => s.cross_spatial_only = v.extract()?,
                "load_state" => s.load_state = Some(PathBuf::from(v.extract::<String>()?)),
                "save_state" => s.save_state = Some(PathBuf::from(v.extract::<String>()?)),
                "isa" => {
                    let name: String = v.extract()?;
                    s.isa = mcdenoise_core::Isa::from_name(&name).ok_or_else(|| {
                        PyValueError::new_err(format!("isa: expected scalar, avx2 or avx512, got '{name}'"))
                    })?;
                }
                other => {
                    return Err(PyTypeError::new_err(format!(
                        "unexpected keyword argument '{other}' (options: layers, weights, refine, fallback, \
                         phi_color, firefly_clamp, ta_clamp, ta_reject, ta_reject_scales, ta_relight, pair, seed, cross_lr, cross_spatial_only, load_state, \
                         save_state, isa)"
                    )))
                }
            }
        }
    }
    Ok((kind, s))
}

/// The optional buffers passed by keyword.
fn buffers_of<'py>(
    albedo: Option<Bound<'py, PyAny>>,
    normal: Option<Bound<'py, PyAny>>,
    depth: Option<Bound<'py, PyAny>>,
    position: Option<Bound<'py, PyAny>>,
    motion: Option<Bound<'py, PyAny>>,
    second: Option<Bound<'py, PyAny>>,
) -> Vec<(Buffer, &'static str, Bound<'py, PyAny>)> {
    [albedo, normal, depth, position, motion, second]
        .into_iter()
        .zip(BUFFERS)
        .filter_map(|(o, (name, b))| o.filter(|o| !o.is_none()).map(|o| (b, name, o)))
        .collect()
}

/// An `H x W x 3` float32 array from three planes.
fn to_array<'py>(py: Python<'py>, planes: Vec<f32>, w: usize, h: usize) -> Bound<'py, PyArray3<f32>> {
    let n = w * h;
    let mut hwc = vec![0.0f32; 3 * n];
    for c in 0..3 {
        for (p, v) in planes[c * n..(c + 1) * n].iter().enumerate() {
            hwc[p * 3 + c] = *v;
        }
    }
    numpy::ndarray::Array3::from_shape_vec((h, w, 3), hwc).expect("the shape holds the values").into_pyarray(py)
}

/// A denoiser for a sequence: frames go in in order, the temporal state
/// (temporal accumulation's history, cross-regression's network) is kept
/// between calls.
///
/// Denoiser(method="atrous", precision="f32", threads=None, **options)
///
/// method: none, ta, atrous, sure-atrous, wskp, afn, cross.
/// precision: f32, f16, f16-arith, fixed.
/// threads: worker threads (default: every core).
/// options: layers (WSKP: 3 or 6), weights (a file made by `mcdenoise
/// train`), refine (AFN, default True), fallback (WSKP, AFN and cross,
/// default True), phi_color, firefly_clamp (à-trous), ta_clamp (ta, WSKP, AFN:
/// the accumulation's history clamp), ta_reject (ta, WSKP, AFN: the history
/// rejection's threshold, default 3, 2 for WSKP and AFN; 0 off), ta_reject_scales (its
/// window means: 1 for 9x9, 2 and 17x17, 3 and 33x33; default 1, 3 for WSKP and AFN), ta_relight
/// (ta, WSKP, AFN: relight the history where a light moved, default True), pair ("mean", the default: with a second
/// estimate, none, ta, WSKP and AFN filter the mean of the two; "first":
/// the second is ignored, cross refuses it), seed, cross_lr,
/// cross_spatial_only, load_state, save_state (cross), isa.
#[pyclass(name = "Denoiser", module = "mcdenoise")]
struct PyDenoiser {
    state: std::sync::Mutex<State>,
}

/// A sequence's denoiser and what it keeps (behind the class's lock: a
/// Python object may be shared between threads).
struct State {
    kind: MethodKind,
    settings: Settings,
    den: Option<Box<dyn methods::Denoiser>>,
    ctx: Option<Ctx>,
    timings: Timings,
    frames: u64,
}

impl PyDenoiser {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, State>> {
        self.state.lock().map_err(|_| PyValueError::new_err("the denoiser failed in an earlier call; make a new one"))
    }
}

#[pymethods]
impl PyDenoiser {
    #[new]
    #[pyo3(signature = (method = "atrous", precision = "f32", threads = None, **options))]
    fn new(
        method: &str,
        precision: &str,
        threads: Option<usize>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let (kind, settings) = settings_of(method, precision, threads, options)?;
        let state = State { kind, settings, den: None, ctx: None, timings: Timings::default(), frames: 0 };
        Ok(PyDenoiser { state: std::sync::Mutex::new(state) })
    }

    /// denoise(color, albedo=None, normal=None, depth=None, position=None, motion=None, second=None) -> numpy.ndarray
    ///
    /// Denoises the next frame of the sequence. Arrays are H x W x C,
    /// float32 or float16 (C-contiguous or strided): color H x W x 3 (or 4,
    /// alpha ignored) linear HDR radiance; albedo, normal (world space,
    /// [-1, 1]) and position (world space) H x W x 3; depth H x W (or
    /// H x W x 1, 0 where nothing is hit); motion H x W x 2 in pixels,
    /// previous = current + motion; second H x W x 3, a second independent
    /// estimate of color (atrous, sure-atrous, cross). A method builds only
    /// the stages the buffers of the first frame allow. Returns the
    /// denoised colour, H x W x 3 float32.
    #[pyo3(signature = (color, albedo = None, normal = None, depth = None, position = None, motion = None, second = None))]
    #[allow(clippy::too_many_arguments)]
    fn denoise<'py>(
        &self,
        py: Python<'py>,
        color: Bound<'py, PyAny>,
        albedo: Option<Bound<'py, PyAny>>,
        normal: Option<Bound<'py, PyAny>>,
        depth: Option<Bound<'py, PyAny>>,
        position: Option<Bound<'py, PyAny>>,
        motion: Option<Bound<'py, PyAny>>,
        second: Option<Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        py.check_signals()?;
        let mut frame = frame_of(&color, &buffers_of(albedo, normal, depth, position, motion, second))?;
        let (w, h) = (frame.width, frame.height);
        let mut guard = self.lock()?;
        let st = &mut *guard;
        methods::apply_pair(st.kind, st.settings.pair, &mut frame);
        if st.den.is_none() {
            st.den = Some(methods::create(st.kind, &st.settings, &frame).map_err(err)?);
            st.ctx = Some(methods::context(&st.settings).map_err(err)?);
        }
        let den = st.den.as_mut().expect("built above");
        let ctx = st.ctx.as_mut().expect("built above");
        let t = &mut st.timings;
        let out = py.detach(|| den.denoise(&frame, ctx, t)).map_err(err)?;
        st.frames += 1;
        drop(guard);
        let arr = to_array(py, out, w, h);
        py.check_signals()?;
        Ok(arr)
    }

    /// Forgets the sequence: the next frame starts a new one (no history;
    /// cross starts again from its initial weights).
    fn reset(&self) -> PyResult<()> {
        let mut st = self.lock()?;
        st.den = None;
        st.frames = 0;
        Ok(())
    }

    /// save_state(path): writes cross-regression's network and Adam's
    /// state (a safetensors file) to path.
    fn save_state(&self, path: PathBuf) -> PyResult<()> {
        match &self.lock()?.den {
            Some(d) => d.save_state(&path).map_err(err),
            None => Err(PyValueError::new_err("save_state: no frame denoised yet")),
        }
    }

    /// load_state(path): the next frame starts a new sequence from the
    /// state saved in path (cross-regression).
    fn load_state(&self, path: PathBuf) -> PyResult<()> {
        let mut st = self.lock()?;
        if st.kind != MethodKind::Cross {
            return Err(PyValueError::new_err(format!(
                "load_state: {} keeps no state (only cross does)",
                st.kind.name()
            )));
        }
        if !path.is_file() {
            return Err(PyValueError::new_err(format!("{}: no such file", path.display())));
        }
        st.settings.load_state = Some(path);
        st.den = None;
        st.frames = 0;
        Ok(())
    }

    /// The one-line plan of the stages built (after the first frame).
    #[getter]
    fn plan(&self) -> PyResult<Option<String>> {
        Ok(self.lock()?.den.as_ref().map(|d| d.plan().line(d.name())))
    }

    /// Frames denoised since the start or the last reset.
    #[getter]
    fn frames(&self) -> PyResult<u64> {
        Ok(self.lock()?.frames)
    }

    /// Milliseconds spent in each stage's kernels, summed over the frames.
    fn timings(&self) -> PyResult<Vec<(String, f64)>> {
        Ok(self.lock()?.timings.stages().iter().map(|(n, d, _)| (n.to_string(), d.as_secs_f64() * 1e3)).collect())
    }

    fn __repr__(&self) -> PyResult<String> {
        let st = self.lock()?;
        Ok(format!(
            "Denoiser(method={:?}, precision={:?}, threads={}, frames={})",
            st.kind.name(),
            st.settings.precision.name(),
            st.settings.threads,
            st.frames
        ))
    }
}

/// denoise(color, albedo=None, normal=None, depth=None, position=None, motion=None, second=None,
///         method="atrous", precision="f32", threads=None, **options) -> numpy.ndarray
///
/// Denoises one frame. Arrays are H x W x C numpy arrays, float32 or
/// float16, C-contiguous or strided:
///   color     H x W x 3 (or 4, alpha ignored): noisy linear HDR radiance (required)
///   albedo    H x W x 3: surface albedo
///   normal    H x W x 3: world-space shading normal in [-1, 1]
///   depth     H x W (or H x W x 1): depth, 0 where nothing is hit
///   position  H x W x 3: world-space position
///   motion    H x W x 2: motion in pixels, previous = current + motion
///   second    H x W x 3: a second independent estimate of color
/// A method builds only the stages the buffers allow (no albedo: no
/// demodulation); one that cannot run without a buffer says which.
///
/// method:    none, ta, atrous (default), sure-atrous, wskp, afn, cross
/// precision: f32 (default), f16, f16-arith, fixed
/// threads:   worker threads (default: every core)
/// options:   layers (WSKP: 3 or 6, default 6), weights (a file made by
///            `mcdenoise train`; default: the bundled weights), refine (AFN,
///            default True), fallback (WSKP, AFN and cross, default True), phi_color and firefly_clamp (à-trous),
///            ta_clamp (ta, WSKP, AFN: the history clamp), ta_reject (ta,
///            WSKP, AFN: the history rejection, default 3, 2 for WSKP and AFN; 0 off),
///            ta_reject_scales (its window means: 1, 2 or 3 sizes; default 1, 3 for WSKP and AFN),
///            ta_relight (relight the history where a light moved; default True), pair ("mean" or
///            "first": what a second estimate is used for), seed,
///            cross_lr and cross_spatial_only (cross), isa (scalar, avx2,
///            avx512)
/// Returns the denoised colour, H x W x 3 float32. Errors: ValueError
/// (a bad array or option, the CLI's message), TypeError (a wrong type).
/// For a sequence, use Denoiser, which keeps the temporal state.
#[pyfunction]
#[pyo3(signature = (color, albedo = None, normal = None, depth = None, position = None, motion = None, second = None,
                    method = "atrous", precision = "f32", threads = None, **options))]
#[allow(clippy::too_many_arguments)]
fn denoise<'py>(
    py: Python<'py>,
    color: Bound<'py, PyAny>,
    albedo: Option<Bound<'py, PyAny>>,
    normal: Option<Bound<'py, PyAny>>,
    depth: Option<Bound<'py, PyAny>>,
    position: Option<Bound<'py, PyAny>>,
    motion: Option<Bound<'py, PyAny>>,
    second: Option<Bound<'py, PyAny>>,
    method: &str,
    precision: &str,
    threads: Option<usize>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let d = PyDenoiser::new(method, precision, threads, options)?;
    d.denoise(py, color, albedo, normal, depth, position, motion, second)
}

/// read_exr(path) -> dict: the buffers the EXR loader finds in a frame file
/// (the CLI's input contract, Blender's and other renderers' names): keys
/// color, second, albedo, normal, depth, position, motion, each an H x W x C
/// float32 array (depth H x W).
#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let f = py.detach(|| Frame::load(&path, &mcdenoise::io::frame::Limits::default())).map_err(err)?;
    let d = PyDict::new(py);
    let (w, h) = (f.width, f.height);
    let n = w * h;
    for (name, b) in [("color", Buffer::Color)].into_iter().chain(BUFFERS) {
        let Some(v) = f.get(b) else { continue };
        let c = b.channels();
        let mut hwc = vec![0.0f32; c * n];
        for ch in 0..c {
            for p in 0..n {
                hwc[p * c + ch] = v[ch * n + p];
            }
        }
        if c == 1 {
            let a = numpy::ndarray::Array2::from_shape_vec((h, w), hwc).expect("shape").into_pyarray(py);
            d.set_item(name, a)?;
        } else {
            let a = numpy::ndarray::Array3::from_shape_vec((h, w, c), hwc).expect("shape").into_pyarray(py);
            d.set_item(name, a)?;
        }
    }
    Ok(d)
}

/// The extension module `mcdenoise._mcdenoise` (imported by `mcdenoise`).
#[pymodule]
fn _mcdenoise(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(denoise, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_class::<PyDenoiser>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("METHODS", MethodKind::ALL.iter().map(|k| k.name()).collect::<Vec<_>>())?;
    Ok(())
}
