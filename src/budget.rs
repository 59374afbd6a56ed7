//! The peak-memory budget: everything that grows with the input is counted before it is
//! allocated, and a run that would exceed the budget is refused, naming what needs the memory
//! and what to lower, instead of exhausting the machine: images from their headers
//! ([`crate::image::io::read_peak_bytes`]), each method's frame and scene
//! ([`crate::methods::registry::check_scene_budget`]), the storage that grows with a method's
//! options (the fragment lists of `multilayer` and `splat --layers`, the depth layers of
//! `multiview`, everything `splat` makes), and a scene file's buffers, meshes and textures as
//! it loads ([`Ledger`], which counts step by step what a job holds).
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

/// A running count of the bytes a job holds, for work that allocates step by step (a scene
/// file's buffers, meshes and textures): each step reserves what it is about to allocate, and
/// is refused, before allocating, when the count would pass the budget. Memory a step frees is
/// released. Safe to share between threads (textures are decoded in parallel).
#[derive(Debug)]
pub struct Ledger {
    budget: u64,
    held: std::sync::atomic::AtomicU64,
}

impl Ledger {
    /// An empty ledger under the budget ([`budget_bytes`]).
    pub fn new() -> Result<Self> {
        Ok(Self::with_budget(budget_bytes()?))
    }

    /// An empty ledger under `budget` bytes.
    pub fn with_budget(budget: u64) -> Self {
        Self {
            budget,
            held: std::sync::atomic::AtomicU64::new(0),
        }
    }

    /// Counts `bytes` more, unless that passes the budget: then nothing is counted and the
    /// error says what needs them (`what()`), what is held already and what to lower.
    pub fn reserve(&self, bytes: u64, what: impl FnOnce() -> String, lower: &str) -> Result<()> {
        if self.try_reserve(bytes) {
            return Ok(());
        }
        let held = match self.held() {
            0 => String::new(),
            held => format!(" beside the {} held before it", gib_text(held)),
        };
        Err(Error::invalid(
            "memory",
            format!(
                "{} needs about {}{held}, more than the budget of {}: lower {lower} (or raise \
                 --memory-budget)",
                what(),
                gib_text(bytes),
                gib_text(self.budget)
            ),
        ))
    }

    /// Counts `bytes` more if that stays within the budget; false (and nothing counted) when
    /// it would not.
    pub fn try_reserve(&self, bytes: u64) -> bool {
        use std::sync::atomic::Ordering;
        self.held
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |held| {
                held.checked_add(bytes)
                    .filter(|&total| total <= self.budget)
            })
            .is_ok()
    }

    /// The budget this ledger counts against, in bytes.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Counts `bytes` fewer (memory a step freed).
    pub fn release(&self, bytes: u64) {
        use std::sync::atomic::Ordering;
        let _ = self
            .held
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |held| {
                Some(held.saturating_sub(bytes))
            });
    }

    /// The bytes counted now.
    pub fn held(&self) -> u64 {
        self.held.load(std::sync::atomic::Ordering::SeqCst)
    }
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
