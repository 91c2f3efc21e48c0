//! Generic extended Kalman filter over nalgebra (paper eq:ekf_predict, eq:ekf_update) with Joseph-form covariance update.
