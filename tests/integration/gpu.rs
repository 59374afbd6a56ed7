//! Tests: the GPU backend. The adapter choice is tested on lists of adapter descriptions; the
//! GPU code runs on whatever adapter `--device gpu` takes (Mesa's lavapipe in CI), and skips,
//! saying so, only where there is no adapter at all.

use std::sync::OnceLock;

use defocus::gpu::{self, AdapterDescription, AdapterLimits, AdapterType, Device, GpuContext};

/// The GPU context of these tests (any adapter, software included), or `None`, with the
/// printed reason, where the machine has no adapter at all.
fn context() -> Option<&'static GpuContext> {
    static CONTEXT: OnceLock<Option<GpuContext>> = OnceLock::new();
    let ctx = CONTEXT.get_or_init(|| {
        if gpu::adapters().is_empty() {
            return None;
        }
        Some(
            GpuContext::open(Device::Gpu)
                .expect("an adapter was found, so --device gpu opens it")
                .expect("--device gpu takes an adapter"),
        )
    });
    if ctx.is_none() {
        eprintln!("skipped: no Vulkan adapter");
    }
    ctx.as_ref()
}

/// An adapter description for the choice tests.
fn adapter(name: &str, device_type: AdapterType) -> AdapterDescription {
    AdapterDescription {
        name: name.to_string(),
        backend: "vulkan".to_string(),
        device_type,
        driver: String::new(),
        software: device_type == AdapterType::Cpu || gpu::is_software_name(name),
        timestamp_query: true,
        limits: AdapterLimits::default(),
    }
}

#[test]
fn auto_on_a_machine_with_only_software_adapters_takes_the_cpu() {
    let software = [
        adapter("llvmpipe (LLVM 19.1.7, 256 bits)", AdapterType::Cpu),
        adapter("SwiftShader Device (Subzero)", AdapterType::Other),
        adapter("Microsoft Basic Render Driver", AdapterType::Integrated),
        adapter("lavapipe", AdapterType::Virtual),
    ];
    assert!(software.iter().all(|a| a.software && !a.is_hardware()));
    assert_eq!(gpu::choose(Device::Auto, &software).unwrap(), None);
    assert_eq!(gpu::choose(Device::Cpu, &software).unwrap(), None);
    // `gpu` takes a software adapter where it is all there is.
    assert_eq!(gpu::choose(Device::Gpu, &software).unwrap(), Some(0));
}

#[test]
fn auto_takes_a_discrete_gpu_before_an_integrated_one_and_never_a_software_one() {
    let list = [
        adapter("llvmpipe (LLVM 19.1.7, 256 bits)", AdapterType::Cpu),
        adapter("Intel(R) UHD Graphics 770", AdapterType::Integrated),
        adapter("NVIDIA H100 80GB HBM3", AdapterType::Discrete),
    ];
    assert_eq!(gpu::choose(Device::Auto, &list).unwrap(), Some(2));
    assert_eq!(gpu::choose(Device::Gpu, &list).unwrap(), Some(2));
    assert_eq!(gpu::choose(Device::Auto, &list[..2]).unwrap(), Some(1));
    assert_eq!(gpu::choose(Device::Cpu, &list).unwrap(), None);
    // A virtual GPU is not taken by auto (it may be a software one behind a VM), but by gpu
    // before a software adapter.
    let vm = [
        adapter("llvmpipe", AdapterType::Cpu),
        adapter("Virtio-GPU Venus", AdapterType::Virtual),
    ];
    assert_eq!(gpu::choose(Device::Auto, &vm).unwrap(), None);
    assert_eq!(gpu::choose(Device::Gpu, &vm).unwrap(), Some(1));
}

#[test]
fn gpu_with_no_adapter_is_a_clear_error_naming_what_was_found() {
    let e = gpu::choose(Device::Gpu, &[]).unwrap_err().to_string();
    assert!(
        e.contains("--device gpu") && e.contains("no GPU adapter") && e.contains("found no"),
        "{e}"
    );
    assert!(
        e.contains("mesa-vulkan-drivers") && e.contains("--device cpu"),
        "{e}"
    );
    assert_eq!(gpu::choose(Device::Auto, &[]).unwrap(), None);
}

#[test]
fn software_adapter_names_are_recognised_in_any_case() {
    for name in [
        "llvmpipe (LLVM 15.0.6, 256 bits)",
        "LAVAPIPE",
        "SwiftShader Device (LLVM 10.0.0)",
        "Microsoft Basic Render Driver",
        "WARP",
    ] {
        assert!(gpu::is_software_name(name), "{name}");
    }
    for name in [
        "NVIDIA GeForce RTX 4090",
        "AMD Radeon RX 7900 XTX",
        "Apple M2",
    ] {
        assert!(!gpu::is_software_name(name), "{name}");
    }
}

#[test]
fn wgsl_is_validated_by_naga_without_an_adapter() {
    let ok =
        "@compute @workgroup_size(64) fn main(@builtin(global_invocation_id) id: vec3<u32>) {}";
    gpu::naga_check(ok).unwrap();
    assert!(gpu::naga_check("fn broken( {").is_err());
}

#[test]
fn gpu_opens_a_context_on_the_adapter_it_chose() {
    let Some(ctx) = context() else { return };
    let adapters = gpu::adapters();
    let chosen = gpu::choose(Device::Gpu, &adapters).unwrap().unwrap();
    assert_eq!(ctx.description().name, adapters[chosen].name);
    assert!(ctx
        .description()
        .label()
        .contains(&ctx.description().backend));
    ctx.check().unwrap();
    let limit = ctx.description().limits.max_storage_buffer_binding_size;
    let e = ctx
        .check_storage("a test frame", limit + 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("max storage buffer binding size"), "{e}");
}
