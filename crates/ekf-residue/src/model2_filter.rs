//! The Model II filter: 21 states with stochastic keyframe cloning, GPS and VO measurements (paper eq:model2f, eq:model2g).
