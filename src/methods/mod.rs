//! DoF methods.
