//! Model II dynamics and VO measurement with keyframe pose (paper eq:model2f, eq:model2g) and analytic Jacobians.
