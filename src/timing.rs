//! Per-pass wall-clock timings, reported by `--timings`.

use std::time::Instant;

use serde::Serialize;

/// Label of reading input files (images, depth passes, scenes), apart from any method's passes.
pub const READ: &str = "io/read";
/// Label of writing output files, apart from any method's passes.
pub const WRITE: &str = "io/write";

/// One timed pass: `<method>/<pass>` and its wall-clock time in milliseconds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PassTiming {
    /// `<method>/<pass>`, e.g. `reference/raster`.
    pub name: String,
    /// Wall-clock milliseconds.
    pub ms: f64,
}

/// The timings of one run of a method.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Timings {
    /// Passes in the order they ran (a pass run several times is summed into one row).
    pub passes: Vec<PassTiming>,
}

impl Timings {
    /// Runs `f`, adding its wall-clock time to the pass `name`.
    pub fn time<T>(&mut self, name: &str, f: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let out = f();
        self.add(name, start.elapsed().as_secs_f64() * 1e3);
        out
    }

    /// Adds `ms` to the pass `name` (created at the end if new).
    pub fn add(&mut self, name: &str, ms: f64) {
        match self.passes.iter_mut().find(|p| p.name == name) {
            Some(p) => p.ms += ms,
            None => self.passes.push(PassTiming {
                name: name.to_string(),
                ms,
            }),
        }
    }

    /// Appends all passes of `other`.
    pub fn extend(&mut self, other: &Timings) {
        for p in &other.passes {
            self.add(&p.name, p.ms);
        }
    }

    /// Sum of all passes in milliseconds.
    pub fn total_ms(&self) -> f64 {
        self.passes.iter().map(|p| p.ms).sum()
    }
}
