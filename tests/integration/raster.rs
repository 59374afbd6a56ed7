//! Tests: raster.
