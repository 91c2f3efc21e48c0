//! The Model I filter: 15 states, pose measurement (paper eq:model1f, eq:model1g).
