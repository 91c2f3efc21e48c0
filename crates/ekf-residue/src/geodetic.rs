//! WGS-84 geodetic to local ENU coordinate transformation (alg:alg1, CoordinateTransformation).
