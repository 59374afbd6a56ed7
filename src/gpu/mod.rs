//! The GPU backend that every GPU method shares: the choice of adapter, one wgpu context made
//! once per job and passed in, pipelines compiled once and cached in it, a small pool of
//! buffers, and per-pass GPU timing.
//!
//! 1. One API and one shading language: [`wgpu`] and WGSL, so the same shaders run on Vulkan,
//!    Metal and DX12, and on Mesa's software Vulkan (lavapipe) in tests and CI. A method's
//!    passes live beside its CPU passes (`methods/gaussian/gpu.rs` and `gaussian.wgsl`), under
//!    the same pass names; the CPU pass is their oracle.
//! 2. The adapter ([`adapter`]): `--device auto` takes a hardware adapter (discrete or
//!    integrated) and never a software one, so without a GPU it is the CPU; `gpu` takes any
//!    adapter, software ones included, and fails naming what was found when there is none.
//!    [`choose`] decides from a list of [`AdapterDescription`]s, so the rule is tested without
//!    the machine's adapters.
//! 3. The context ([`GpuContext`]) is a value the jobs make and pass to the methods: no hidden
//!    global device. A sequence makes one and every frame reuses its pipelines and buffers.
//! 4. Timings ([`PassTimer`]): each pass's GPU time from timestamp queries where the adapter
//!    has `TIMESTAMP_QUERY`, else the wall time around the pass's submit and its wait; the
//!    timings say which ([`crate::timing::Clock`]). A software adapter's times are not GPU
//!    times.
//! 5. Errors: a wgpu validation error, an out-of-memory or a lost device is recorded by the
//!    context and returned as [`crate::Error::Gpu`] by the run that met it, never a panic.
//!
//! The library prints nothing; [`adapters`] lists what `defocus devices` shows.

pub mod adapter;
mod context;

pub use adapter::{
    adapters, choose, hardware_may_exist, is_software_name, AdapterDescription, AdapterLimits,
    AdapterType, Device,
};
pub use context::{GpuContext, PassStamps, PassTimer};

/// The value of a status word no pass has written: no failing pixel
/// ([`GpuContext::read_frame`]).
pub const NO_FAILURE: u32 = u32::MAX;

/// Parses and validates WGSL `source` with naga, as wgpu does before it builds a pipeline, but
/// without an adapter: `Err` ([`crate::Error::Gpu`]) with naga's message.
pub fn naga_check(source: &str) -> crate::Result<()> {
    use wgpu::naga;
    let module = naga::front::wgsl::parse_str(source)
        .map_err(|e| crate::Error::Gpu(e.emit_to_string(source)))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .map_err(|e| crate::Error::Gpu(e.emit_to_string(source)))?;
    Ok(())
}
