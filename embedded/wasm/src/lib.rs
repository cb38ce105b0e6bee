//! The embedded operator suite (`mcdenoise-embedded-suite`) as a
//! `wasm32-unknown-unknown` module: the same operator code, static buffers
//! and expected outputs as the Cortex-M4 build. `tests/tests/embedded.rs`
//! builds it and runs every case under wasmi.
//!
//! Exports (all `extern "C"`): `suite_cases() -> u32`; `suite_run(i) -> i32`
//! (0 within tolerance, 1 outside it, 2 a core error, 3 buffers busy, 4 no
//! expected outputs, 5 no such case, 6 scratch constants wrong for this target); then, for the last case run,
//! `suite_values() -> u32`, `suite_max_abs() -> f32`,
//! `suite_worst_ratio() -> f32`, `suite_hash() -> u32`,
//! `suite_static_bytes() -> u32` and `suite_outputs() -> *const f32` (its
//! `suite_values()` outputs, decoded to f32, in linear memory).
//!
//! On other targets it builds as an ordinary (std) library that exports the
//! same functions, so the workspace builds it harmlessly on the host.
#![cfg_attr(target_arch = "wasm32", no_std)]

use mcdenoise_embedded_suite::{run, Failure, NoMeter, Outcome, Slot, CASES, N, SOFTMAX_PLANES};

const MAX_OUT: usize = SOFTMAX_PLANES * N;

struct Last {
    outcome: Option<Outcome>,
    outputs: [f32; MAX_OUT],
}

static LAST: Slot<Last> = Slot::new(Last { outcome: None, outputs: [0.0; MAX_OUT] });

/// Number of cases.
#[no_mangle]
pub extern "C" fn suite_cases() -> u32 {
    CASES.len() as u32
}

/// Runs case `i` and keeps its outcome and outputs; see the crate docs for the codes.
#[no_mangle]
pub extern "C" fn suite_run(i: u32) -> i32 {
    let Some(&case) = CASES.get(i as usize) else { return 5 };
    LAST.with(|last| {
        last.outcome = None;
        let outputs = &mut last.outputs;
        let r = run(case, &mut NoMeter, &mut |j, v| {
            if let Some(o) = outputs.get_mut(j) {
                *o = v;
            }
        });
        match r {
            Ok(o) => {
                last.outcome = Some(o);
                if o.passed() {
                    0
                } else {
                    1
                }
            }
            Err(Failure::Core(_)) => 2,
            Err(Failure::Busy) => 3,
            Err(Failure::NoExpected) => 4,
            Err(Failure::Footprint { .. }) => 6,
        }
    })
    .unwrap_or(3)
}

fn last<R: Default>(f: impl FnOnce(&Outcome) -> R) -> R {
    LAST.with(|l| l.outcome.as_ref().map(f).unwrap_or_default()).unwrap_or_default()
}

/// Outputs of the last case (0 when it failed before comparing).
#[no_mangle]
pub extern "C" fn suite_values() -> u32 {
    last(|o| o.values as u32)
}

/// Largest absolute error of the last case.
#[no_mangle]
pub extern "C" fn suite_max_abs() -> f32 {
    last(|o| o.max_abs)
}

/// Largest tolerance ratio of the last case.
#[no_mangle]
pub extern "C" fn suite_worst_ratio() -> f32 {
    last(|o| o.worst_ratio)
}

/// FNV-1a hash of the last case's outputs.
#[no_mangle]
pub extern "C" fn suite_hash() -> u32 {
    last(|o| o.hash)
}

/// Static buffer bytes of the last case.
#[no_mangle]
pub extern "C" fn suite_static_bytes() -> u32 {
    last(|o| o.static_bytes as u32)
}

/// Where the last case's decoded outputs are.
#[no_mangle]
pub extern "C" fn suite_outputs() -> *const f32 {
    LAST.with(|l| l.outputs.as_ptr()).unwrap_or(core::ptr::null())
}

#[cfg(target_arch = "wasm32")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    core::arch::wasm32::unreachable()
}
