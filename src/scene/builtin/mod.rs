//! Built-in scenes, each stressing one aspect of depth of field (see DESIGN.md).

use super::Scene;
use crate::{Error, Result};

/// Names of the built-in scenes; the first is the default.
pub const NAMES: &[&str] = &["railing", "lights", "grass", "glass"];

/// Builds the built-in scene `name`, with its suggested camera in [`Scene::defaults`].
pub fn load(name: &str) -> Result<Scene> {
    match name {
        _ => Err(Error::Unknown {
            kind: "scene",
            name: name.to_string(),
            expected: NAMES.join(", "),
        }),
    }
}
