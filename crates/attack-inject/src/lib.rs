//! False-data-injection attacks on GPS streams (paper eq:fdi), with per-step labels.
//!
//! This crate sits above `uav-dynamics` and below the learning crates: it knows sensor sample
//! types but nothing about filters' internals or learning.
#![warn(missing_docs)]
