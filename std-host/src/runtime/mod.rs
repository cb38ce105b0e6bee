//! What the kernels run in: the thread pool and per-band scratch, the
//! precisions, memory accounting, and the removal of temporary files on a
//! signal or a failed allocation. Depends on nothing else in this crate
//! but [`crate::error`].

use mcdenoise_core::Isa;

pub mod aligned;
pub mod cleanup;
pub mod memory;
pub mod par;
pub mod precision;

/// What every kernel call runs with: the pool, the ISA and per-band scratch.
pub struct Ctx {
    /// Threads.
    pub pool: par::Pool,
    /// Instruction set.
    pub isa: Isa,
    /// Per-band scratch, kept across frames.
    pub scratch: par::Scratch,
}

impl Ctx {
    /// `threads` workers on `isa` (checked against this CPU).
    pub fn new(threads: usize, isa: Isa) -> crate::Result<Ctx> {
        isa.check().map_err(|e| crate::HostError::Usage(format!("--isa: {e}")))?;
        Ok(Ctx { pool: par::Pool::new(threads).map_err(crate::HostError::Usage)?, isa, scratch: par::Scratch::new() })
    }
}
