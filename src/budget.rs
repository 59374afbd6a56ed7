//! The peak-memory budget: methods whose intermediate storage grows with their options (the
//! fragment lists of `multilayer` and `splat --layers`, the depth layers of `multiview`, the tile
//! lists of `splat`) estimate it before allocating and refuse, naming the option to lower,
//! when it would exceed the budget, instead of exhausting the machine.
//!
//! The budget is [`DEFAULT_BUDGET_BYTES`] unless the environment variable
//! `DEFOCUS_MEMORY_BUDGET_GIB` gives another number of GiB (the command line's
//! `--memory-budget`).

use crate::{Error, Result};

/// The default budget: 16 GiB, two thirds of the 24 GiB machines this project runs on.
pub const DEFAULT_BUDGET_BYTES: u64 = 16 << 30;

/// The budget in bytes.
pub fn budget_bytes() -> u64 {
    std::env::var("DEFOCUS_MEMORY_BUDGET_GIB")
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|g| g.is_finite() && *g > 0.0)
        .map(|g| (g * (1u64 << 30) as f64) as u64)
        .unwrap_or(DEFAULT_BUDGET_BYTES)
}

/// Fails when `bytes` exceed the budget, saying what needs them and what to lower.
pub fn check(bytes: u64, what: &str, lower: &str) -> Result<()> {
    let budget = budget_bytes();
    if bytes > budget {
        return Err(Error::invalid(
            "memory",
            format!(
                "{what} needs about {:.1} GiB, more than the budget of {:.1} GiB: lower {lower} (or raise --memory-budget)",
                bytes as f64 / (1u64 << 30) as f64,
                budget as f64 / (1u64 << 30) as f64
            ),
        ));
    }
    Ok(())
}
