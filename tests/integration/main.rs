//! Behaviour tests of defocus: one binary, one module per area.

mod cli;
mod image_io;
mod lens;
mod metrics;
mod raster;
mod reference;
mod scenes;

/// Path of the shared assets folder, or `None` (with a printed reason) when it is absent.
pub fn shared_assets() -> Option<std::path::PathBuf> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipped: ../shared/assets is absent");
        None
    }
}
