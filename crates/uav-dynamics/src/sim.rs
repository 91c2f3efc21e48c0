//! Flight simulator: true quadrotor states and multi-rate sensor streams.
