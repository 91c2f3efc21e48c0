//! ZYX Euler rotations R(q), the Euler-rate map G(q) and its inverse, matrix to Euler, angle wrapping.
