//! Developer and user tasks for QUADFormer-rs (`cargo xtask <task>`).
fn main() {}
