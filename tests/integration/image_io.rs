//! Tests: image_io.
