//! Criterion benchmarks of the baseline detectors (filled in below).
fn main() {}
