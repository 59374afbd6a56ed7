//! The peak-memory budget: methods whose intermediate storage grows with their options (the
//! fragment lists of `multilayer` and `splat --layers`, the depth layers of `multiview`, the tile
//! lists of `splat`) estimate it before allocating and refuse, naming the option to lower,
//! when it would exceed the budget, instead of exhausting the machine.
//!
//! The budget is [`DEFAULT_BUDGET_BYTES`] unless the environment variable [`BUDGET_VARIABLE`]
//! (`DEFOCUS_MEMORY_BUDGET_GIB`) gives another number of GiB (the command line's
//! `--memory-budget` sets it). A value that is not a number of GiB above 0 and at most
//! [`MAX_BUDGET_GIB`] is an error naming the variable, never a silent default.

use crate::error::shown;
use crate::{Error, Result};

/// The default budget: 16 GiB, two thirds of the 24 GiB machines this project runs on.
pub const DEFAULT_BUDGET_BYTES: u64 = 16 << 30;

/// The environment variable that sets the budget, in GiB.
pub const BUDGET_VARIABLE: &str = "DEFOCUS_MEMORY_BUDGET_GIB";

/// The largest budget, in GiB: far above any machine, and far below an overflow of bytes.
pub const MAX_BUDGET_GIB: f64 = 1e6;

/// A budget in GiB as bytes, when it is a number above 0 and at most [`MAX_BUDGET_GIB`].
pub fn gib_to_bytes(gib: f64) -> Option<u64> {
    (gib.is_finite() && gib > 0.0 && gib <= MAX_BUDGET_GIB)
        .then_some((gib * (1u64 << 30) as f64) as u64)
}

/// The budget in bytes: [`BUDGET_VARIABLE`]'s, or the default when it is not set. A value
/// that is not a number of GiB above 0 (`0`, `-1`, `nan`, `abc`, an empty one) is an error
/// naming the variable and what it expects.
pub fn budget_bytes() -> Result<u64> {
    let Some(value) = std::env::var_os(BUDGET_VARIABLE) else {
        return Ok(DEFAULT_BUDGET_BYTES);
    };
    value
        .to_str()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .and_then(gib_to_bytes)
        .ok_or_else(|| {
            Error::invalid(
                BUDGET_VARIABLE,
                format!(
                    "'{}': expected a number of GiB greater than 0 and at most {MAX_BUDGET_GIB} \
                     (unset, the budget is 16 GiB)",
                    shown(&value)
                ),
            )
        })
}

/// Fails when `bytes` exceed the budget, saying what needs them and what to lower.
pub fn check(bytes: u64, what: &str, lower: &str) -> Result<()> {
    let budget = budget_bytes()?;
    if bytes > budget {
        return Err(Error::invalid(
            "memory",
            format!(
                "{what} needs about {}, more than the budget of {}: lower {lower} (or raise --memory-budget)",
                gib_text(bytes),
                gib_text(budget)
            ),
        ));
    }
    Ok(())
}

/// `bytes` in GiB for messages: two decimals below 10 GiB (`0.25 GiB`), one above.
pub fn gib_text(bytes: u64) -> String {
    let gib = bytes as f64 / (1u64 << 30) as f64;
    if gib < 10.0 {
        format!("{gib:.2} GiB")
    } else {
        format!("{gib:.1} GiB")
    }
}
