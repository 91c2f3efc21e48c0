//! Position controller that flies on a caller-supplied estimate.
