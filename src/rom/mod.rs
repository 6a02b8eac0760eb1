//! Reduced-order neural model (stub while building).
pub mod features;
