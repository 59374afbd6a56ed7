//! Tests: scenes.
