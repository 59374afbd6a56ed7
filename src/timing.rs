//! Per-pass timings, reported by `--timings`: wall-clock time of the CPU passes, and GPU time
//! of the GPU passes ([`Clock`] says which).

use std::time::Instant;

use serde::Serialize;

/// Label of reading input files (images, depth passes, scenes), apart from any method's passes.
pub const READ: &str = "io/read";
/// Label of writing output files, apart from any method's passes.
pub const WRITE: &str = "io/write";

/// How a pass was timed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Clock {
    /// Wall-clock time on the CPU around the pass.
    #[default]
    Wall,
    /// GPU time between timestamp queries written at the start and the end of the pass.
    GpuTimestamps,
    /// Wall-clock time around the pass's submit to the GPU and the wait for it (an adapter
    /// without timestamp queries): GPU time plus the submit's overhead.
    SubmitWait,
}

impl Clock {
    /// How `--timings` names it: `wall`, `gpu-timestamps` or `submit-wait`.
    pub fn name(self) -> &'static str {
        match self {
            Clock::Wall => "wall",
            Clock::GpuTimestamps => "gpu-timestamps",
            Clock::SubmitWait => "submit-wait",
        }
    }
}

/// One timed pass: `<method>/<pass>`, its time in milliseconds and how it was measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PassTiming {
    /// `<method>/<pass>`, e.g. `reference/raster`.
    pub name: String,
    /// Milliseconds.
    pub ms: f64,
    /// How `ms` was measured.
    pub clock: Clock,
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

    /// Adds `ms` of wall-clock time to the pass `name` (created at the end if new).
    pub fn add(&mut self, name: &str, ms: f64) {
        self.add_with(name, ms, Clock::Wall);
    }

    /// Adds `ms` measured by `clock` to the pass `name` (created at the end if new; a pass
    /// keeps the clock it was first timed by).
    pub fn add_with(&mut self, name: &str, ms: f64, clock: Clock) {
        match self.passes.iter_mut().find(|p| p.name == name) {
            Some(p) => p.ms += ms,
            None => self.passes.push(PassTiming {
                name: name.to_string(),
                ms,
                clock,
            }),
        }
    }

    /// Appends all passes of `other`.
    pub fn extend(&mut self, other: &Timings) {
        for p in &other.passes {
            self.add_with(&p.name, p.ms, p.clock);
        }
    }

    /// Sum of all passes in milliseconds.
    pub fn total_ms(&self) -> f64 {
        self.passes.iter().map(|p| p.ms).sum()
    }
}
