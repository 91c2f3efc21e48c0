//! Model I continuous dynamics f (paper eq:model1f), measurement g (eq:model1g), Euler discretisation and analytic Jacobians.
