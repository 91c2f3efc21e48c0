//! Property tests of the differential-flatness map (`sim::flat_attitude`): the body z axis is
//! the thrust direction, the yaw is the reference yaw, and the body rate matches the derivative
//! of `R(t)` along a constant-jerk segment.

use nalgebra::Vector3;
use proptest::prelude::*;
use uav_dynamics::rotation::{skew, wrap_angle};
use uav_dynamics::sim::{flat_attitude, gravity};

fn vec3(range: f64) -> impl Strategy<Value = Vector3<f64>> {
    (-range..range, -range..range, -range..range).prop_map(|(x, y, z)| Vector3::new(x, y, z))
}

proptest! {
    /// Accelerations up to 6 m/s² per axis (tilt below ~60°), jerks up to 5 m/s³, any yaw.
    /// Central differences with h = 1e-6 s have error ~h²·|R‴| ≲ 1e-9; tolerance 1e-5.
    #[test]
    fn flatness_is_consistent(a in vec3(6.0), j in vec3(5.0), yaw in -3.1f64..3.1, yaw_rate in -1.0f64..1.0) {
        let at = |s: f64| flat_attitude(&(a + j * s), &j, yaw + yaw_rate * s, yaw_rate, s);
        let c = at(0.0).unwrap();
        let thrust = a - gravity();
        prop_assert!((c.r * Vector3::z() * c.thrust - thrust).norm() < 1e-9);
        prop_assert!((wrap_angle(c.q[2] - yaw)).abs() < 1e-12);
        let h = 1e-6;
        let (m, p) = (at(-h).unwrap(), at(h).unwrap());
        let w_fd = c.r.transpose() * (p.r - m.r) / (2.0 * h);
        prop_assert!((w_fd - skew(&c.omega)).norm() < 1e-5, "{} vs {}", w_fd, skew(&c.omega));
    }
}
