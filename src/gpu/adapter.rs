//! Adapters: what the machine has ([`adapters`]), how each is described
//! ([`AdapterDescription`]) and which one a run takes ([`choose`]).

use serde::Serialize;

use crate::{Error, Result};

/// Where a run computes: `--device cpu|gpu|auto`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Device {
    /// The CPU code, whatever adapters there are.
    Cpu,
    /// A GPU adapter, software ones included (lavapipe in tests); an error when there is none.
    Gpu,
    /// A hardware adapter (discrete or integrated) where there is one and the method runs on
    /// the GPU; otherwise the CPU. Never a software adapter.
    #[default]
    Auto,
}

impl Device {
    /// The flag's spelling: `cpu`, `gpu` or `auto`.
    pub fn name(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Gpu => "gpu",
            Device::Auto => "auto",
        }
    }
}

/// The kind of an adapter, as the driver reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AdapterType {
    /// A GPU of its own.
    Discrete,
    /// A GPU sharing the CPU's package and memory.
    Integrated,
    /// A GPU seen through a virtual machine.
    Virtual,
    /// A software renderer on the CPU (lavapipe, llvmpipe, SwiftShader, WARP).
    Cpu,
    /// Unknown.
    Other,
}

impl AdapterType {
    /// Lower-case name, as `defocus devices` prints it.
    pub fn name(self) -> &'static str {
        match self {
            AdapterType::Discrete => "discrete",
            AdapterType::Integrated => "integrated",
            AdapterType::Virtual => "virtual",
            AdapterType::Cpu => "cpu",
            AdapterType::Other => "other",
        }
    }

    fn from_wgpu(t: wgpu::DeviceType) -> Self {
        match t {
            wgpu::DeviceType::DiscreteGpu => AdapterType::Discrete,
            wgpu::DeviceType::IntegratedGpu => AdapterType::Integrated,
            wgpu::DeviceType::VirtualGpu => AdapterType::Virtual,
            wgpu::DeviceType::Cpu => AdapterType::Cpu,
            wgpu::DeviceType::Other => AdapterType::Other,
        }
    }
}

/// The limits of an adapter that decide which frames it can run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct AdapterLimits {
    /// Largest width or height of a 2D texture, in texels.
    pub max_texture_dimension_2d: u32,
    /// Largest buffer, in bytes.
    pub max_buffer_size: u64,
    /// Largest storage buffer one binding may see, in bytes: an RGBA f32 frame of `w` x `h`
    /// pixels needs `16 w h`.
    pub max_storage_buffer_binding_size: u64,
    /// Largest compute workgroup, in invocations along x, y and z.
    pub max_compute_workgroup_size: [u32; 3],
    /// Most invocations in one compute workgroup.
    pub max_compute_invocations_per_workgroup: u32,
    /// Most workgroups of one dispatch along each dimension.
    pub max_compute_workgroups_per_dimension: u32,
}

impl AdapterLimits {
    pub(crate) fn from_wgpu(l: &wgpu::Limits) -> Self {
        Self {
            max_texture_dimension_2d: l.max_texture_dimension_2d,
            max_buffer_size: l.max_buffer_size,
            max_storage_buffer_binding_size: l.max_storage_buffer_binding_size,
            max_compute_workgroup_size: [
                l.max_compute_workgroup_size_x,
                l.max_compute_workgroup_size_y,
                l.max_compute_workgroup_size_z,
            ],
            max_compute_invocations_per_workgroup: l.max_compute_invocations_per_workgroup,
            max_compute_workgroups_per_dimension: l.max_compute_workgroups_per_dimension,
        }
    }
}

/// One adapter as `defocus devices` lists it and [`choose`] decides on it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct AdapterDescription {
    /// The driver's name for the device (`llvmpipe (LLVM 19.1.7, 256 bits)`, `NVIDIA H100`).
    pub name: String,
    /// The API it is reached through: `vulkan`, `metal`, `dx12`.
    pub backend: String,
    /// Discrete, integrated, virtual, CPU or other.
    pub device_type: AdapterType,
    /// The driver and its version, as reported (may be empty).
    pub driver: String,
    /// A software renderer: `device_type` is `cpu`, or the name is that of a known one
    /// ([`is_software_name`]). `auto` never takes it.
    pub software: bool,
    /// Whether the adapter has timestamp queries (GPU time per pass).
    pub timestamp_query: bool,
    /// The limits that matter for a frame.
    pub limits: AdapterLimits,
}

impl AdapterDescription {
    /// Describes a wgpu adapter.
    pub fn of(adapter: &wgpu::Adapter) -> Self {
        let info = adapter.get_info();
        let device_type = AdapterType::from_wgpu(info.device_type);
        let driver = [info.driver.as_str(), info.driver_info.as_str()]
            .iter()
            .filter(|s| !s.is_empty())
            .copied()
            .collect::<Vec<_>>()
            .join(" ");
        Self {
            software: device_type == AdapterType::Cpu || is_software_name(&info.name),
            name: info.name,
            backend: info.backend.to_str().to_string(),
            device_type,
            driver,
            timestamp_query: adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY),
            limits: AdapterLimits::from_wgpu(&adapter.limits()),
        }
    }

    /// `name (backend, type)`, with `software` for a software adapter: the device line of
    /// `--timings`, e.g. `llvmpipe (LLVM 19.1.7, 256 bits) (vulkan, cpu, software)`.
    pub fn label(&self) -> String {
        format!(
            "{} ({}, {}{})",
            self.name,
            self.backend,
            self.device_type.name(),
            if self.software { ", software" } else { "" }
        )
    }

    /// A hardware adapter `auto` may take: discrete or integrated, and not software.
    pub fn is_hardware(&self) -> bool {
        !self.software
            && matches!(
                self.device_type,
                AdapterType::Discrete | AdapterType::Integrated
            )
    }
}

/// Whether an adapter name is that of a known software renderer: llvmpipe, lavapipe,
/// SwiftShader or Microsoft's WARP ("Microsoft Basic Render Driver"), in any case.
pub fn is_software_name(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    [
        "llvmpipe",
        "lavapipe",
        "swiftshader",
        "warp",
        "basic render driver",
    ]
    .iter()
    .any(|s| lower.contains(s))
}

/// Which adapter of `adapters` a run on `device` takes: its index, or `None` for the CPU.
///
/// - `cpu`: `None`.
/// - `auto`: the first discrete hardware adapter, else the first integrated one, else `None`.
///   A software adapter is never taken.
/// - `gpu`: the best adapter there is (discrete, integrated, virtual, other, then software);
///   an error naming what was found when there is none.
pub fn choose(device: Device, adapters: &[AdapterDescription]) -> Result<Option<usize>> {
    let rank = |a: &AdapterDescription| -> u8 {
        if a.software {
            return 4;
        }
        match a.device_type {
            AdapterType::Discrete => 0,
            AdapterType::Integrated => 1,
            AdapterType::Virtual => 2,
            AdapterType::Other => 3,
            AdapterType::Cpu => 4,
        }
    };
    let best = |keep: &dyn Fn(&AdapterDescription) -> bool| {
        adapters
            .iter()
            .enumerate()
            .filter(|(_, a)| keep(a))
            .min_by_key(|(i, a)| (rank(a), *i))
            .map(|(i, _)| i)
    };
    match device {
        Device::Cpu => Ok(None),
        Device::Auto => Ok(best(&|a| a.is_hardware())),
        Device::Gpu => best(&|_| true).map(Some).ok_or_else(|| {
            Error::Gpu(format!(
                "--device gpu: no GPU adapter was found ({}); install a Vulkan driver (on Debian \
                 and Ubuntu: mesa-vulkan-drivers libvulkan1, which include the software \
                 lavapipe), or use --device cpu",
                found(adapters)
            ))
        }),
    }
}

/// What was found, for messages: `none through Vulkan, Metal or DX12` or the adapters' labels.
fn found(adapters: &[AdapterDescription]) -> String {
    if adapters.is_empty() {
        "wgpu found no adapter through Vulkan, Metal or DX12".to_string()
    } else {
        let labels: Vec<String> = adapters.iter().map(AdapterDescription::label).collect();
        format!("found: {}", labels.join("; "))
    }
}

/// Whether this machine may have a hardware GPU for `auto` to take, known without loading a
/// Vulkan driver. On Linux a hardware GPU is reached through a device node: a DRM render node
/// (`/dev/dri/renderD*`: AMD, Intel, NVIDIA's DRM module, virtual GPUs), NVIDIA's
/// `/dev/nvidia0` or WSL's `/dev/dxg`; where there is none, `auto` takes the CPU without
/// asking Vulkan, whose software driver alone costs a run about 50 ms and 55 MB of resident
/// memory (lavapipe, measured with `blur` and `render` on the test machine). Elsewhere: true.
pub fn hardware_may_exist() -> bool {
    if !cfg!(target_os = "linux") {
        return true;
    }
    let path = std::path::Path::new;
    let render_node = std::fs::read_dir("/dev/dri").is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| e.file_name().to_string_lossy().starts_with("renderD"))
    });
    render_node || path("/dev/nvidia0").exists() || path("/dev/dxg").exists()
}

/// Every adapter wgpu finds on this machine, described. An empty list where there is no
/// driver (no Vulkan loader, no device); never an error.
pub fn adapters() -> Vec<AdapterDescription> {
    let instance = super::context::new_instance();
    super::context::enumerate(&instance)
        .iter()
        .map(AdapterDescription::of)
        .collect()
}
