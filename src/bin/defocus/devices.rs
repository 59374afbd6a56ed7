//! `defocus devices`: the GPU adapters wgpu finds, their limits, and what `--device auto`
//! takes.

use anyhow::Result;
use clap::Args;
use defocus::gpu::{self, AdapterDescription, Device};

use crate::common::print_output;

/// Flags of `devices`.
#[derive(Debug, Args)]
pub struct DevicesArgs {
    /// Print one JSON object (`adapters`, each with its limits, and `auto`) instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Lists the adapters on standard output.
pub fn run(args: &DevicesArgs) -> Result<()> {
    let adapters = gpu::adapters();
    let auto = gpu::choose(Device::Auto, &adapters)?;
    let auto_name = auto.map_or_else(|| "cpu".to_string(), |i| adapters[i].label());
    if args.json {
        let value = serde_json::json!({ "adapters": adapters, "auto": auto_name });
        return print_output(&value.to_string());
    }
    let mut lines = Vec::new();
    if adapters.is_empty() {
        lines.push(
            "no GPU adapter (wgpu found none through Vulkan, Metal or DX12; on Debian and \
             Ubuntu, mesa-vulkan-drivers libvulkan1 give the software lavapipe)"
                .to_string(),
        );
    }
    for a in &adapters {
        lines.extend(describe(a));
    }
    lines.push(format!(
        "--device auto: {auto_name}{}",
        if auto.is_none() {
            " (no hardware adapter; auto never takes a software one)"
        } else {
            ""
        }
    ));
    print_output(&lines.join("\n"))
}

/// The lines of one adapter.
fn describe(a: &AdapterDescription) -> Vec<String> {
    let l = &a.limits;
    let [x, y, z] = l.max_compute_workgroup_size;
    vec![
        a.name.clone(),
        format!("  backend: {}", a.backend),
        format!("  type: {}", a.device_type.name()),
        format!(
            "  software: {}",
            if a.software {
                "yes (for tests: its times are not GPU times)"
            } else {
                "no"
            }
        ),
        format!("  driver: {}", a.driver),
        format!(
            "  timestamp queries: {}",
            if a.timestamp_query { "yes" } else { "no" }
        ),
        format!(
            "  max texture dimension 2D: {} px",
            l.max_texture_dimension_2d
        ),
        format!("  max buffer size: {} bytes", l.max_buffer_size),
        format!(
            "  max storage buffer binding size: {} bytes",
            l.max_storage_buffer_binding_size
        ),
        format!("  max compute workgroup size: {x} x {y} x {z}"),
        format!(
            "  max compute invocations per workgroup: {}",
            l.max_compute_invocations_per_workgroup
        ),
        format!(
            "  max compute workgroups per dimension: {}",
            l.max_compute_workgroups_per_dimension
        ),
    ]
}
