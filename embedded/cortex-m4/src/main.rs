//! The embedded operator suite on a Cortex-M4F: QEMU's MPS2 AN386 board
//! (`cargo run --release` in this directory; see `.cargo/config.toml`).
//!
//! Runs every case of `mcdenoise-embedded-suite` (five core operators on a
//! 32x32 tile, f32 and fixed point, static buffers), checks each against the
//! checked-in f64-oracle outputs, and prints per case: instructions executed
//! by the core call (QEMU's instruction counter read through the board's
//! timer), the stack it used (high-water mark of a painted window), the
//! case's static buffers, the largest error, and the largest square tile whose
//! buffers and stack fit in 64 KiB and in 256 KiB. Exits through semihosting
//! with failure when any case is out of tolerance or fails, so QEMU's exit
//! status fails CI.
#![no_std]
#![no_main]

use core::arch::asm;
use core::ptr::{addr_of, read_volatile, write_volatile};

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use mcdenoise_embedded_suite::{self as suite, Meter, CASES, H, W};

/// The board's CMSDK APB timer 0: control, current value, reload. A 32-bit
/// down-counter clocked at the 25 MHz system clock; with `-icount shift=0`
/// QEMU's virtual time advances 1 ns per instruction, so one tick is 40
/// instructions (checked at start-up against a loop of known length).
const TIMER0_CTRL: *mut u32 = 0x4000_0000 as *mut u32;
const TIMER0_VALUE: *mut u32 = 0x4000_0004 as *mut u32;
const TIMER0_RELOAD: *mut u32 = 0x4000_0008 as *mut u32;

/// What the stack window is painted with.
const PAINT: u32 = 0xA5C3_5A3C;
/// Bytes of stack painted below the caller's stack pointer.
const WINDOW: usize = 64 * 1024;

/// Budgets of the tile-size table.
const BUDGETS: [usize; 2] = [64 * 1024, 256 * 1024];

extern "C" {
    // From cortex-m-rt's link.x.
    static __stext: u32;
    static __etext: u32;
    static __srodata: u32;
    static __erodata: u32;
    static __sdata: u32;
    static __edata: u32;
    static __sbss: u32;
    static __ebss: u32;
    static __sheap: u32;
}

fn timer_start() {
    // SAFETY: the MPS2 timer's registers (memory-mapped I/O on this board).
    unsafe {
        write_volatile(TIMER0_CTRL, 0);
        write_volatile(TIMER0_RELOAD, u32::MAX);
        write_volatile(TIMER0_VALUE, u32::MAX);
        write_volatile(TIMER0_CTRL, 1);
    }
}

#[inline(always)]
fn timer_now() -> u32 {
    // SAFETY: as above.
    unsafe { read_volatile(TIMER0_VALUE) }
}

#[inline(always)]
fn stack_pointer() -> usize {
    let sp: usize;
    // SAFETY: reads a register.
    unsafe { asm!("mov {}, sp", out(reg) sp, options(nomem, nostack, preserves_flags)) };
    sp
}

/// `2 n` instructions: `subs` and `bne`, `n` times.
#[inline(never)]
fn spin(n: u32) {
    // SAFETY: a register-only loop.
    unsafe { asm!("1:", "subs {0}, {0}, #1", "bne 1b", inout(reg) n => _, options(nomem, nostack)) };
}

/// Ticks of a loop of 2,000,000 instructions.
fn calibrate() -> u32 {
    let t0 = timer_now();
    spin(1_000_000);
    t0.wrapping_sub(timer_now())
}

/// Calls `f` from a frame of its own, so that everything the operator puts
/// on the stack lies below the painted window's top.
#[inline(never)]
fn call<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// Counts the ticks and the stack of one core call.
#[derive(Default)]
struct M4Meter {
    ticks: u32,
    stack: usize,
    window_exhausted: bool,
}

impl Meter for M4Meter {
    #[inline(always)]
    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> R {
        let top = stack_pointer() & !3;
        let heap = addr_of!(__sheap) as usize;
        let floor = top.saturating_sub(WINDOW).max(heap);
        // Paint the free stack below this frame (no calls in between: the
        // loop runs in registers; ARM has no red zone).
        let mut p = floor;
        while p < top {
            // SAFETY: between the end of the statics and the stack pointer: unused RAM.
            unsafe { write_volatile(p as *mut u32, PAINT) };
            p += 4;
        }
        let t0 = timer_now();
        let r = call(f);
        let t1 = timer_now();
        self.ticks = t0.wrapping_sub(t1);
        let mut p = floor;
        // SAFETY: as above.
        while p < top && unsafe { read_volatile(p as *const u32) } == PAINT {
            p += 4;
        }
        self.stack = top - p;
        self.window_exhausted = p == floor;
        r
    }
}

fn span(a: *const u32, b: *const u32) -> usize {
    b as usize - a as usize
}

#[entry]
fn main() -> ! {
    timer_start();
    let cal = calibrate();
    // Instructions per tick, as a ratio: 2,000,000 / cal.
    let instructions = |ticks: u32| (ticks as u64 * 2_000_000 + cal as u64 / 2) / cal.max(1) as u64;
    hprintln!(
        "mcdenoise embedded suite: {} cases on a {}x{} tile, Cortex-M4 (QEMU mps2-an386), scalar path, {}",
        CASES.len(),
        W,
        H,
        if cfg!(target_abi = "eabihf") { "f32 on the FPU" } else { "f32 in software (no FPU)" }
    );
    hprintln!(
        "instruction counter: a 2,000,000-instruction loop reads {} timer ticks ({} instructions per tick)",
        cal,
        2_000_000 / cal.max(1)
    );
    hprintln!(
        "{:<10} {:<5} {:>12} {:>8} {:>9} {:>10} {:>7} {:>9} {:>6} {:>6}",
        "operator",
        "prec",
        "instructions",
        "stack B",
        "static B",
        "max |err|",
        "ratio",
        "hash",
        "64KiB",
        "256KiB"
    );
    let mut failed = 0;
    for case in CASES {
        let mut m = M4Meter::default();
        let (op, prec) = (case.op.name(), case.prec.name());
        match suite::run(case, &mut m, &mut |_, _| {}) {
            Ok(o) => {
                let [t64, t256] = BUDGETS.map(|b| suite::largest_tile(case.op, case.prec, m.stack, b));
                let ok = o.passed() && !m.window_exhausted;
                hprintln!(
                    "{:<10} {:<5} {:>12} {:>8} {:>9} {:>10.3e} {:>7.3}  {:08x} {:>6} {:>6}{}",
                    op,
                    prec,
                    instructions(m.ticks),
                    m.stack,
                    o.static_bytes,
                    o.max_abs,
                    o.worst_ratio,
                    o.hash,
                    t64,
                    t256,
                    if ok { "" } else { "  FAILED" }
                );
                if !o.passed() {
                    hprintln!("  output {} is out of tolerance (ratio {})", o.worst_index, o.worst_ratio);
                }
                if m.window_exhausted {
                    hprintln!("  the stack went below the {}-byte painted window", WINDOW);
                }
                failed += usize::from(!ok);
            }
            Err(e) => {
                hprintln!("{:<10} {:<5} FAILED: {}", op, prec, e);
                failed += 1;
            }
        }
    }
    let (text, rodata, data, bss) = (
        span(addr_of!(__stext), addr_of!(__etext)),
        span(addr_of!(__srodata), addr_of!(__erodata)),
        span(addr_of!(__sdata), addr_of!(__edata)),
        span(addr_of!(__sbss), addr_of!(__ebss)),
    );
    hprintln!(
        "image: .text {} B, .rodata {} B (expected outputs included), .data {} B, .bss {} B",
        text,
        rodata,
        data,
        bss
    );
    hprintln!("64KiB / 256KiB: the largest square tile whose buffers, scratch and measured stack fit");
    if failed > 0 {
        hprintln!("FAILED: {} of {} cases", failed, CASES.len());
        debug::exit(debug::EXIT_FAILURE);
    } else {
        hprintln!("ok: {} cases within tolerance of the f64 oracle", CASES.len());
        debug::exit(debug::EXIT_SUCCESS);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    hprintln!("hard fault at pc {:#010x}", ef.pc());
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
