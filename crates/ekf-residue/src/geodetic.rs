//! WGS-84 geodetic → ECEF → local ENU coordinate transformation (paper alg:alg1,
//! CoordinateTransformation).
//!
//! Geodetic coordinates are latitude and longitude in **degrees** (as GPS receivers report) and
//! ellipsoidal height in metres; ECEF and ENU in metres. Constants are the WGS-84 defining
//! parameters (NIMA TR8350.2, 3rd ed., Table 3.1): `a = 6 378 137 m`, `1/f = 298.257223563`.
//!
//! ```text
//! N(φ) = a / √(1 − e² sin²φ)
//! X = (N + h) cos φ cos λ,   Y = (N + h) cos φ sin λ,   Z = (N(1 − e²) + h) sin φ
//! ENU = R_enu(φ₀, λ₀) (X − X₀),  R_enu rows: e = [−sin λ₀, cos λ₀, 0],
//!       n = [−sin φ₀ cos λ₀, −sin φ₀ sin λ₀, cos φ₀], u = [cos φ₀ cos λ₀, cos φ₀ sin λ₀, sin φ₀]
//! ```

use nalgebra::{Matrix3, Vector3};

use crate::error::FilterError;

/// WGS-84 semi-major axis, metres.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS-84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS-84 first eccentricity squared `e² = f(2 − f)`.
pub const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);

/// A geodetic position: latitude and longitude in degrees, ellipsoidal height in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geodetic {
    /// Latitude in degrees, [−90, 90].
    pub lat_deg: f64,
    /// Longitude in degrees, [−180, 180] (other finite values are accepted and wrap).
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, metres.
    pub h_m: f64,
}

impl Geodetic {
    fn check(&self) -> Result<(), FilterError> {
        if !self.lat_deg.is_finite() || self.lat_deg.abs() > 90.0 {
            return Err(FilterError::Geodetic { what: "latitude (deg)", value: self.lat_deg });
        }
        if !self.lon_deg.is_finite() {
            return Err(FilterError::Geodetic { what: "longitude (deg)", value: self.lon_deg });
        }
        if !self.h_m.is_finite() {
            return Err(FilterError::Geodetic { what: "height (m)", value: self.h_m });
        }
        Ok(())
    }
}

/// Geodetic → Earth-centred Earth-fixed coordinates (metres).
///
/// # Errors
/// [`FilterError::Geodetic`] for a latitude outside [−90°, 90°] or non-finite input.
pub fn geodetic_to_ecef(g: &Geodetic) -> Result<Vector3<f64>, FilterError> {
    g.check()?;
    let (sl, cl) = g.lat_deg.to_radians().sin_cos();
    let (so, co) = g.lon_deg.to_radians().sin_cos();
    let n = WGS84_A / (1.0 - WGS84_E2 * sl * sl).sqrt();
    Ok(Vector3::new((n + g.h_m) * cl * co, (n + g.h_m) * cl * so, (n * (1.0 - WGS84_E2) + g.h_m) * sl))
}

/// A local ENU frame anchored at a geodetic origin (e.g. the first GPS fix of a flight).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalEnu {
    origin_ecef: Vector3<f64>,
    r_enu: Matrix3<f64>,
}

impl LocalEnu {
    /// The ENU frame at `origin`.
    ///
    /// # Errors
    /// As [`geodetic_to_ecef`].
    pub fn new(origin: &Geodetic) -> Result<Self, FilterError> {
        let origin_ecef = geodetic_to_ecef(origin)?;
        let (sl, cl) = origin.lat_deg.to_radians().sin_cos();
        let (so, co) = origin.lon_deg.to_radians().sin_cos();
        #[rustfmt::skip]
        let r_enu = Matrix3::new(
            -so,       co,      0.0,
            -sl * co, -sl * so, cl,
            cl * co,   cl * so, sl,
        );
        Ok(Self { origin_ecef, r_enu })
    }

    /// ECEF (metres) → local ENU (metres).
    #[must_use]
    pub fn ecef_to_enu(&self, ecef: &Vector3<f64>) -> Vector3<f64> {
        self.r_enu * (ecef - self.origin_ecef)
    }

    /// Geodetic → local ENU (metres).
    ///
    /// # Errors
    /// As [`geodetic_to_ecef`].
    pub fn to_enu(&self, g: &Geodetic) -> Result<Vector3<f64>, FilterError> {
        Ok(self.ecef_to_enu(&geodetic_to_ecef(g)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matterhorn_relative_to_zermatt() {
        // Published example of MATLAB Mapping Toolbox `geodetic2enu` (WGS-84): the Matterhorn
        // (45.976°, 7.658°, 4531 m) seen from Zermatt (46.017°, 7.750°, 1673 m) is at
        // xEast = −7134.8, yNorth = −4556.3, zUp = 2852.4 m (printed to 0.1 m, hence the tolerance).
        let enu = LocalEnu::new(&Geodetic { lat_deg: 46.017, lon_deg: 7.750, h_m: 1673.0 }).unwrap();
        let p = enu.to_enu(&Geodetic { lat_deg: 45.976, lon_deg: 7.658, h_m: 4531.0 }).unwrap();
        assert!((p - Vector3::new(-7134.8, -4556.3, 2852.4)).abs().max() < 0.06, "{p:?}");
    }

    #[test]
    fn ecef_on_the_axes() {
        // Definitional values: equator/prime meridian → (a, 0, 0); north pole → (0, 0, b) with
        // b = a(1 − f) = 6 356 752.314 245 m (NIMA TR8350.2 Table 3.3).
        let e = geodetic_to_ecef(&Geodetic { lat_deg: 0.0, lon_deg: 0.0, h_m: 0.0 }).unwrap();
        assert!((e - Vector3::new(WGS84_A, 0.0, 0.0)).norm() < 1e-6);
        let n = geodetic_to_ecef(&Geodetic { lat_deg: 90.0, lon_deg: 0.0, h_m: 0.0 }).unwrap();
        assert!((n[2] - 6_356_752.314_245).abs() < 1e-3);
        assert!(n[0].abs() < 1e-6);
    }

    #[test]
    fn bad_latitude_is_an_error() {
        assert!(matches!(
            geodetic_to_ecef(&Geodetic { lat_deg: 91.0, lon_deg: 0.0, h_m: 0.0 }),
            Err(FilterError::Geodetic { .. })
        ));
    }
}
