//! WGS84 to metric plane projections, and anchors that place an odometry frame in that plane.
//!
//! The map plane is East-North (x east, y north, metres) at an origin latitude/longitude. An
//! anchor places a source's planar odometry frame (`odom`) in it before any correction: that
//! placement is the `anchored` frame, `anchored_from_odom`.

use std::f64::consts::PI;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::se2::Se2;

/// WGS84 semi-major axis (metres).
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// How geographic coordinates become plane coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    /// The local tangent plane (East-North-Up) of the WGS84 ellipsoid at the origin: true scale
    /// and true north at the origin. Right for real metric odometry.
    #[default]
    Tangent,
    /// KITTI's spherical formula: `E = (lon - lon0) pi/180 R cos(lat0)`,
    /// `N = (lat - lat0) pi/180 R`, `R = 6378137 m`. KITTI's ground truth and
    /// `kitti/georef.csv` were computed with it, so maps compared with them must use it.
    Kitti,
}

impl Projection {
    /// Both projections.
    pub const ALL: [Projection; 2] = [Projection::Tangent, Projection::Kitti];

    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Projection::Tangent => "tangent",
            Projection::Kitti => "kitti",
        }
    }
}

impl FromStr for Projection {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

fn ecef(lat_deg: f64, lon_deg: f64) -> [f64; 3] {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let (sl, cl) = (lat_deg * PI / 180.0).sin_cos();
    let (so, co) = (lon_deg * PI / 180.0).sin_cos();
    let n = WGS84_A / (1.0 - e2 * sl * sl).sqrt();
    [n * cl * co, n * cl * so, n * (1.0 - e2) * sl]
}

/// A projection fixed at an origin: maps latitude/longitude (degrees) to East/North (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapPlane {
    /// The projection.
    pub projection: Projection,
    /// Origin latitude (degrees, WGS84).
    pub origin_lat: f64,
    /// Origin longitude (degrees, WGS84).
    pub origin_lon: f64,
}

impl MapPlane {
    /// A plane at the given origin (degrees).
    pub fn new(projection: Projection, origin_lat: f64, origin_lon: f64) -> Self {
        MapPlane {
            projection,
            origin_lat,
            origin_lon,
        }
    }

    /// `[east, north]` in metres of a WGS84 point (degrees).
    pub fn project(&self, lat: f64, lon: f64) -> [f64; 2] {
        match self.projection {
            Projection::Kitti => {
                let r = WGS84_A;
                [
                    (lon - self.origin_lon) * PI / 180.0 * r * (self.origin_lat * PI / 180.0).cos(),
                    (lat - self.origin_lat) * PI / 180.0 * r,
                ]
            }
            Projection::Tangent => {
                let p = ecef(lat, lon);
                let o = ecef(self.origin_lat, self.origin_lon);
                let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
                let (sl, cl) = (self.origin_lat * PI / 180.0).sin_cos();
                let (so, co) = (self.origin_lon * PI / 180.0).sin_cos();
                [
                    -so * d[0] + co * d[1],
                    -sl * co * d[0] - sl * so * d[1] + cl * d[2],
                ]
            }
        }
    }

    /// The WGS84 point `(lat, lon)` in degrees of a plane point (inverse of [`Self::project`],
    /// on the ellipsoid surface for the tangent plane).
    pub fn unproject(&self, en: [f64; 2]) -> (f64, f64) {
        match self.projection {
            Projection::Kitti => {
                let r = WGS84_A;
                let lat = self.origin_lat + en[1] / r * 180.0 / PI;
                let lon = self.origin_lon
                    + en[0] / (r * (self.origin_lat * PI / 180.0).cos()) * 180.0 / PI;
                (lat, lon)
            }
            Projection::Tangent => {
                // Newton iterations on the forward projection: converges to sub-millimetre in a
                // few steps because the projection is nearly linear near the origin.
                let (mut lat, mut lon) = (self.origin_lat, self.origin_lon);
                for _ in 0..6 {
                    let [e, n] = self.project(lat, lon);
                    let h = 1e-6;
                    let [e_lat, n_lat] = self.project(lat + h, lon);
                    let [e_lon, n_lon] = self.project(lat, lon + h);
                    let (a, b, c, d) = (
                        (e_lat - e) / h,
                        (e_lon - e) / h,
                        (n_lat - n) / h,
                        (n_lon - n) / h,
                    );
                    let det = a * d - b * c;
                    let (re, rn) = (en[0] - e, en[1] - n);
                    lat += (d * re - b * rn) / det;
                    lon += (-c * re + a * rn) / det;
                }
                (lat, lon)
            }
        }
    }

    /// The WGS84 point `(lat, lon)` in degrees of a plane point, or `None` where the plane does
    /// not map back to the Earth: beyond the latitudes and longitudes that exist, or (the tangent
    /// plane) where [`Self::unproject`] finds no point that projects to within
    /// [`ROUND_TRIP_M`] of it. What a reader of untrusted plane points (a tile) must use.
    pub fn lat_lon_of(&self, en: [f64; 2]) -> Option<(f64, f64)> {
        let (lat, lon) = self.unproject(en);
        check_lat_lon(lat, lon).ok()?;
        let back = self.project(lat, lon);
        ((back[0] - en[0]).hypot(back[1] - en[1]) <= ROUND_TRIP_M).then_some((lat, lon))
    }
}

/// How far (metres) a plane point may lie from the projection of the latitude and longitude
/// [`MapPlane::lat_lon_of`] finds for it.
pub const ROUND_TRIP_M: f64 = 1e-3;

/// A geographic value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeoError {
    /// Latitude outside [-90, 90] degrees or not finite.
    #[error("latitude {0:?} is outside [-90, 90] degrees")]
    Latitude(f64),
    /// Longitude outside [-180, 180] degrees or not finite.
    #[error("longitude {0:?} is outside [-180, 180] degrees")]
    Longitude(f64),
    /// Yaw not finite, or beyond a turn either way.
    #[error("yaw {0:?} is not a number of degrees in [-360, 360]")]
    Yaw(f64),
    /// An offset that is not finite or beyond [`MAX_OFFSET_M`].
    #[error("offset {0:.3e} m is not finite or beyond 1e7 m")]
    Offset(f64),
    /// An anchor string that does not have three or five numbers.
    #[error("anchor '{0}': expected LAT,LON,YAW_DEG or LAT,LON,YAW_DEG,EAST_M,NORTH_M")]
    AnchorSyntax(String),
}

/// The largest yaw an anchor may turn an odometry frame by, either way (degrees): a turn. Beyond
/// it a yaw is a mistake (1e300 degrees was taken, as whatever its sine is).
pub const MAX_YAW_DEG: f64 = 360.0;

/// Whether `yaw_rad` (radians) is a yaw an anchor may turn an odometry frame by: within
/// [`MAX_YAW_DEG`] either way. For the anchor yaws read back in radians (a status CSV's
/// `anchor_yaw`, the Python package's `eval`).
pub fn is_anchor_yaw_rad(yaw_rad: f64) -> bool {
    let max = MAX_YAW_DEG.to_radians();
    (-max..=max).contains(&yaw_rad)
}

/// The largest offset an anchor may place an odometry origin at (metres): beyond it a local
/// plane is meaningless (Earth's circumference is 4e7 m).
pub const MAX_OFFSET_M: f64 = 1e7;

/// Checks a WGS84 position (degrees).
pub fn check_lat_lon(lat: f64, lon: f64) -> Result<(), GeoError> {
    if !(lat.is_finite() && lat.abs() <= 90.0) {
        return Err(GeoError::Latitude(lat));
    }
    if !(lon.is_finite() && lon.abs() <= 180.0) {
        return Err(GeoError::Longitude(lon));
    }
    Ok(())
}

/// Places a source's planar odometry frame in the East-North plane: the plane's origin
/// (degrees) and the pose of the odometry frame in it, `[E, N] = R(yaw) [u, v] + [east, north]`,
/// yaw counter-clockwise from East (the semantics of `kitti/georef.csv`).
///
/// Every way of making one ([`Anchor::new`], parsing `LAT,LON,YAW_DEG[,EAST_M,NORTH_M]`,
/// deserialising a config) applies the same range checks.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "AnchorFields")]
pub struct Anchor {
    lat: f64,
    lon: f64,
    yaw_deg: f64,
    east_m: f64,
    north_m: f64,
}

/// An anchor as written in a configuration file, before its checks.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AnchorFields {
    lat: f64,
    lon: f64,
    yaw_deg: f64,
    #[serde(default)]
    east_m: f64,
    #[serde(default)]
    north_m: f64,
}

impl TryFrom<AnchorFields> for Anchor {
    type Error = GeoError;

    fn try_from(f: AnchorFields) -> Result<Self, Self::Error> {
        Anchor::new(f.lat, f.lon, f.yaw_deg, f.east_m, f.north_m)
    }
}

impl Anchor {
    /// An anchor: origin latitude and longitude (degrees, WGS84), the yaw of the odometry
    /// frame's x axis counter-clockwise from East (degrees), and the odometry origin's East and
    /// North offsets from the plane origin (metres). Refuses values out of range.
    pub fn new(
        lat: f64,
        lon: f64,
        yaw_deg: f64,
        east_m: f64,
        north_m: f64,
    ) -> Result<Anchor, GeoError> {
        check_lat_lon(lat, lon)?;
        if !(-MAX_YAW_DEG..=MAX_YAW_DEG).contains(&yaw_deg) {
            return Err(GeoError::Yaw(yaw_deg));
        }
        for offset in [east_m, north_m] {
            if !(offset.is_finite() && offset.abs() <= MAX_OFFSET_M) {
                return Err(GeoError::Offset(offset));
            }
        }
        Ok(Anchor {
            lat,
            lon,
            yaw_deg,
            east_m,
            north_m,
        })
    }

    /// Origin latitude of the anchor's plane (degrees).
    pub fn lat(&self) -> f64 {
        self.lat
    }

    /// Origin longitude of the anchor's plane (degrees).
    pub fn lon(&self) -> f64 {
        self.lon
    }

    /// Yaw of the odometry frame's x axis, counter-clockwise from East (degrees).
    pub fn yaw_deg(&self) -> f64 {
        self.yaw_deg
    }

    /// East offset of the odometry origin (metres).
    pub fn east_m(&self) -> f64 {
        self.east_m
    }

    /// North offset of the odometry origin (metres).
    pub fn north_m(&self) -> f64 {
        self.north_m
    }

    /// `anchored_from_odom` in the map plane `plane`: where the anchor places planar odometry
    /// coordinates before any correction. In the anchor's own plane (same origin) this is the
    /// anchor's rigid transform; in another plane (a tile's) it is that transform composed with
    /// the rigid transform that maps the anchor origin and a point 100 m east of it exactly.
    /// Exact when the origins coincide; the residual scale difference elsewhere is below 1e-6
    /// within a few kilometres for tangent planes.
    pub fn anchored_from_odom(&self, plane: &MapPlane) -> Se2 {
        let own_from_odom = Se2::new(self.yaw_deg * PI / 180.0, self.east_m, self.north_m);
        if (plane.origin_lat, plane.origin_lon) == (self.lat, self.lon) {
            return own_from_odom;
        }
        let own = MapPlane::new(plane.projection, self.lat, self.lon);
        let (lat0, lon0) = own.unproject([0.0, 0.0]);
        let (lat1, lon1) = own.unproject([100.0, 0.0]);
        let t0 = plane.project(lat0, lon0);
        let t1 = plane.project(lat1, lon1);
        let yaw = (t1[1] - t0[1]).atan2(t1[0] - t0[0]);
        Se2::new(yaw, t0[0], t0[1]) * own_from_odom
    }
}

impl FromStr for Anchor {
    type Err = GeoError;

    /// Parses `LAT,LON,YAW_DEG[,EAST_M,NORTH_M]`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let syntax = || GeoError::AnchorSyntax(s.to_string());
        let values: Vec<f64> = s
            .split(',')
            .map(|v| v.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| syntax())?;
        match values[..] {
            [lat, lon, yaw_deg] => Anchor::new(lat, lon, yaw_deg, 0.0, 0.0),
            [lat, lon, yaw_deg, east_m, north_m] => Anchor::new(lat, lon, yaw_deg, east_m, north_m),
            _ => Err(syntax()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_points_the_plane_maps_back_have_a_latitude_and_longitude() {
        for projection in Projection::ALL {
            let plane = MapPlane::new(projection, 49.0, 8.4);
            for en in [[0.0, 0.0], [1e5, -3e4], [-2e6, 1e6]] {
                let (lat, lon) = plane.lat_lon_of(en).unwrap();
                let back = plane.project(lat, lon);
                assert!((back[0] - en[0]).hypot(back[1] - en[1]) < 1e-6, "{en:?}");
            }
            // Beyond the pole, and (tangent) where Newton's iterations find no point.
            for en in [[0.0, 5e6], [3e7, 0.0], [1e9, 0.0], [-1e9, 1e9]] {
                assert_eq!(plane.lat_lon_of(en), None, "{} {en:?}", projection.name());
            }
        }
    }

    #[test]
    fn tangent_plane_has_true_scale() {
        // One arc-minute of latitude at 49 N is about 1853 m on the ellipsoid.
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let [e, n] = plane.project(49.0 + 1.0 / 60.0, 8.4);
        assert!(e.abs() < 1e-3 && (n - 1853.2).abs() < 0.5, "{e} {n}");
        let (lat, lon) = plane.unproject(plane.project(49.01, 8.43));
        assert!((lat - 49.01).abs() < 1e-9 && (lon - 8.43).abs() < 1e-9);
    }

    #[test]
    fn kitti_projection_is_the_spherical_formula() {
        let plane = MapPlane::new(Projection::Kitti, 49.0, 8.0);
        let [e, n] = plane.project(49.001, 8.001);
        let r = WGS84_A;
        assert!((n - 0.001 * PI / 180.0 * r).abs() < 1e-9);
        assert!((e - 0.001 * PI / 180.0 * r * (49.0 * PI / 180.0).cos()).abs() < 1e-9);
        let (lat, lon) = plane.unproject([e, n]);
        assert!((lat - 49.001).abs() < 1e-12 && (lon - 8.001).abs() < 1e-12);
    }

    #[test]
    fn anchor_in_another_plane_keeps_positions() {
        let a: Anchor = "49.0,8.4,30,5,-3".parse().unwrap();
        let tile = MapPlane::new(Projection::Tangent, 49.004, 8.41);
        let own = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let p_odom = [120.0, -40.0];
        let via_latlon = {
            let (lat, lon) = own.unproject(a.anchored_from_odom(&own).apply(p_odom));
            tile.project(lat, lon)
        };
        let direct = a.anchored_from_odom(&tile).apply(p_odom);
        assert!(
            (via_latlon[0] - direct[0]).abs() < 1e-3 && (via_latlon[1] - direct[1]).abs() < 1e-3
        );
        assert_eq!(
            a.anchored_from_odom(&own),
            Se2::new(30f64.to_radians(), 5.0, -3.0)
        );
    }

    #[test]
    fn anchors_parse() {
        let a: Anchor = "48.98,8.39,59.5,0.8,0.3".parse().unwrap();
        assert_eq!(a.north_m(), 0.3);
        assert!(matches!(
            "48.98,8.39".parse::<Anchor>(),
            Err(GeoError::AnchorSyntax(_))
        ));
        assert!(matches!(
            "48.98,nan,1".parse::<Anchor>(),
            Err(GeoError::Longitude(_))
        ));
        assert!(matches!(
            "91,8,1".parse::<Anchor>(),
            Err(GeoError::Latitude(_))
        ));
        assert!(matches!(
            "49,181,1".parse::<Anchor>(),
            Err(GeoError::Longitude(_))
        ));
        assert!(matches!(
            "49,8,inf".parse::<Anchor>(),
            Err(GeoError::Yaw(_))
        ));
        assert!(matches!(
            "49,8,1,2e7,0".parse::<Anchor>(),
            Err(GeoError::Offset(_))
        ));
        // A configuration file goes through the same checks.
        let parsed: Result<Anchor, _> = toml::from_str("lat = 91.0\nlon = 8.0\nyaw_deg = 0.0");
        assert!(parsed.unwrap_err().to_string().contains("latitude 91"));
        // A number is quoted as written, not in the 301 digits `Display` spells 1e300 with.
        for (anchor, message) in [
            ("1e300,8,0", "latitude 1e300 is outside [-90, 90] degrees"),
            (
                "49,-1e300,0",
                "longitude -1e300 is outside [-180, 180] degrees",
            ),
            // A yaw beyond a turn either way is a mistake, not an angle.
            (
                "49,8,1e300",
                "yaw 1e300 is not a number of degrees in [-360, 360]",
            ),
            (
                "49,8,-360.5",
                "yaw -360.5 is not a number of degrees in [-360, 360]",
            ),
        ] {
            let refused = anchor.parse::<Anchor>().map(|_| ()).unwrap_err();
            assert_eq!(refused.to_string(), message);
        }
        let ok: Anchor = toml::from_str("lat = 48.98\nlon = 8.39\nyaw_deg = 59.5").unwrap();
        assert_eq!(ok, "48.98,8.39,59.5".parse().unwrap());
    }
}
