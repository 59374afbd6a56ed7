//! Tests: lens.
