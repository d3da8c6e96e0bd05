//! Checks that catch a run set up wrongly: everything parses and nothing is invalid, but the
//! answer would mislead. Each check returns a warning that says what to try; callers print it and
//! carry on (the run's output is still what the corrector computed).

use crate::corrector::Status;
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{AxisConvention, Pose3};
use crate::se2::Se2;
use crate::source_corrector::CorrectedPose;

/// Farthest the anchored start of a run may lie from every lane point before the anchor is
/// suspect (metres).
pub const MAX_START_TO_LANE_M: f64 = 1000.0;

/// Largest share of a run's 3D path length that may go along the axis the planar frame drops
/// (vertical) before the axis convention is suspect. Measured on the 20 shared KITTI odometry
/// runs: 1.6 to 7.2 % in their own convention (24.6 % for the stereo VO of sequence 01, whose
/// height drifts), 41 to 100 % read in the other one.
pub const MAX_VERTICAL_SHARE: f64 = 0.33;

/// Shortest 3D path (metres) the axis check judges: standing still proves nothing.
const MIN_PATH_FOR_AXIS_CHECK_M: f64 = 10.0;

/// The share of the 3D path length of `poses` (given in `convention`) that goes along the
/// planar frame's vertical axis; `None` when the path is too short to tell.
pub fn vertical_share(poses: &[Pose3], convention: AxisConvention) -> Option<f64> {
    let mut positions = poses.iter().map(|p| convention.to_planar(p).translation);
    let mut last = positions.next()?;
    let (mut vertical, mut total) = (0.0, 0.0);
    for position in positions {
        let d = position - last;
        vertical += d.z.abs();
        total += d.norm();
        last = position;
    }
    (total.is_finite() && total >= MIN_PATH_FOR_AXIS_CHECK_M).then(|| vertical / total)
}

/// A warning when the motion of `poses` looks like the other axis convention.
pub fn axis_convention_warning(poses: &[Pose3], convention: AxisConvention) -> Option<String> {
    let share = vertical_share(poses, convention)?;
    if share <= MAX_VERTICAL_SHARE {
        return None;
    }
    let better = AxisConvention::ALL
        .into_iter()
        .filter(|&c| c != convention)
        .find(|&c| vertical_share(poses, c).is_some_and(|s| s <= MAX_VERTICAL_SHARE));
    let advice = match better {
        Some(c) => format!(
            "try --frame {} (frame = \"{}\" in a config)",
            c.name(),
            c.name()
        ),
        None => "check the poses' axis convention".to_string(),
    };
    Some(format!(
        "{:.0}% of the motion is vertical in the {} convention, which a vehicle does not do: \
         the file probably uses another axis convention; {advice}",
        share * 100.0,
        convention.name()
    ))
}

/// The distance (metres) from `position_in_map` to the nearest lane point of `map`.
pub fn distance_to_lanes(map: &LaneMap, position_in_map: [f64; 2]) -> f64 {
    let mut nearest = Vec::with_capacity(1);
    map.nearest(position_in_map, 1, &mut nearest);
    nearest.first().map_or(f64::INFINITY, |c| c.0.sqrt())
}

/// A warning when the anchor places the start of the run, `first` (planar `flu`), more than
/// [`MAX_START_TO_LANE_M`] from every lane.
pub fn anchor_warning(map: &LaneMap, anchored_from_odom: &Se2, first: &Pose3) -> Option<String> {
    let start = anchored_from_odom.apply(first.planar_position());
    let distance = distance_to_lanes(map, start);
    (distance > MAX_START_TO_LANE_M).then(|| {
        format!(
            "the anchor places the first pose {} from the nearest lane: check --anchor (LAT,LON \
             in degrees, YAW_DEG from East counter-clockwise) and that the map covers the drive \
             (`lanealign-map inspect TILE --geojson lanes.geojson`)",
            if distance.is_finite() {
                format!("{:.1} km", distance / 1000.0)
            } else {
                "arbitrarily far".to_string()
            }
        )
    })
}

/// A warning when no correction was accepted over a whole run of `poses` poses.
pub fn no_correction_warning(poses: usize, accepted: usize) -> Option<String> {
    (poses > 0 && accepted == 0).then(|| {
        format!(
            "no correction was accepted in {poses} poses, so the output is the raw odometry: \
             check the anchor, --frame and that the map covers the drive; the status file's \
             reason column says why each attempt was refused"
        )
    })
}

/// A warning when the odometry jumped (status [`Status::OdometryJump`]) in `run`: at which
/// poses (0-based, the first few), and what to give when the poses only paused.
pub fn odometry_jump_warning(run: &[CorrectedPose], params: &Params) -> Option<String> {
    let jumps: Vec<usize> = run
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c.status, Status::OdometryJump { .. }))
        .map(|(i, _)| i)
        .collect();
    if jumps.is_empty() {
        return None;
    }
    let shown: Vec<String> = jumps.iter().take(5).map(usize::to_string).collect();
    Some(format!(
        "the odometry jumped at {} pose{} ({}{}): farther than max_speed_mps ({} m/s) from the \
         pose before, so each was continued from where the vehicle was (status odometry_jump); \
         if the poses only paused or come slower than odometry_rate_hz ({} Hz), give their \
         stamps (TUM) or the rate",
        jumps.len(),
        if jumps.len() == 1 { "" } else { "s" },
        shown.join(", "),
        if jumps.len() > shown.len() {
            ", ..."
        } else {
            ""
        },
        params.max_speed_mps,
        params.odometry_rate_hz,
    ))
}

/// How much faster (or slower) than the corrector's [`Params::odometry_rate_hz`] a source's
/// stamps may say it is before its window is suspect of spanning too short (or too long) a
/// stretch of road.
pub const MAX_RATE_RATIO: f64 = 1.5;

/// Stamps closer than this (seconds) are no sensor's: counters or a fixed value, not time.
const MIN_PLAUSIBLE_INTERVAL_S: f64 = 1e-5;

/// The rate (Hz) consecutive stamps (seconds, in arrival order) say the source runs at: the
/// median interval's; `None` unless at least two intervals, and half of them, are plausible
/// (at least 10 us; a source whose stamps are counters or constant says nothing).
pub fn rate_from_stamps(stamps_s: &[f64]) -> Option<f64> {
    let mut intervals: Vec<f64> = stamps_s
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|dt| dt.is_finite() && *dt >= MIN_PLAUSIBLE_INTERVAL_S)
        .collect();
    if intervals.len() < 2 || intervals.len() * 2 < stamps_s.len() {
        return None;
    }
    let mid = intervals.len() / 2;
    let (_, median, _) = intervals.select_nth_unstable_by(mid, f64::total_cmp);
    Some(1.0 / *median)
}

/// A warning when a source's measured `rate_hz` is well above or below the rate `params` are set
/// for: its window then spans a fraction of the road the preset was chosen for, or a multiple of
/// it (and its first correction comes as many times later).
pub fn rate_warning(rate_hz: f64, params: &Params) -> Option<String> {
    let set_hz = params.odometry_rate_hz;
    let consequence = if rate_hz > MAX_RATE_RATIO * set_hz {
        "only part of the road its preset was chosen for"
    } else if rate_hz * MAX_RATE_RATIO < set_hz {
        "more time and road than its preset was chosen for, and its first correction comes later"
    } else {
        return None;
    };
    // Whole hertz above 10 Hz; below, a tenth matters (2.5 Hz is not 2 or 3).
    let rate = if rate_hz >= 10.0 {
        format!("{rate_hz:.0}")
    } else {
        format!("{rate_hz:.1}")
    };
    Some(format!(
        "the poses come at about {rate} Hz (their stamps) but the corrector is set for {set_hz} \
         Hz, so its window spans {consequence}: set odometry_rate_hz = {rate} (--set \
         odometry_rate_hz={rate}, or in the source's overrides)"
    ))
}

/// Gathers a session's first stamps to tell its rate once (see [`rate_from_stamps`]).
#[derive(Clone, Debug)]
pub struct RateProbe {
    stamps_s: [f64; RateProbe::STAMPS],
    seen: usize,
}

impl Default for RateProbe {
    fn default() -> Self {
        RateProbe {
            stamps_s: [0.0; RateProbe::STAMPS],
            seen: 0,
        }
    }
}

impl RateProbe {
    /// Stamps gathered before the rate is told.
    pub const STAMPS: usize = 64;

    /// Takes the next stamp (seconds); returns the rate once, when enough stamps are in (and
    /// `None` for good after, or when the stamps tell no rate).
    pub fn observe(&mut self, stamp_s: f64) -> Option<f64> {
        let slot = self.stamps_s.get_mut(self.seen)?;
        *slot = stamp_s;
        self.seen += 1;
        if self.seen < Self::STAMPS {
            return None;
        }
        rate_from_stamps(&self.stamps_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;

    fn straight(convention: AxisConvention) -> Vec<Pose3> {
        (0..100)
            .map(|i| {
                let flu = Pose3::planar(i as f64, 0.02 * i as f64, 0.0, 0.01 * i as f64);
                convention.from_planar(&flu)
            })
            .collect()
    }

    #[test]
    fn a_camera_file_read_as_flu_is_noticed_and_the_fix_named() {
        let camera = straight(AxisConvention::KittiCamera);
        assert!(axis_convention_warning(&camera, AxisConvention::KittiCamera).is_none());
        let w = axis_convention_warning(&camera, AxisConvention::Flu).unwrap();
        assert!(w.contains("--frame kitti-camera"), "{w}");
        let flu = straight(AxisConvention::Flu);
        assert!(axis_convention_warning(&flu, AxisConvention::Flu).is_none());
        assert!(axis_convention_warning(&flu[..3], AxisConvention::KittiCamera).is_none());
    }

    #[test]
    fn a_far_anchor_is_noticed() {
        let lane = Lane::new(1, (0..10).map(|i| [i as f64 * 3.0, 0.0]).collect());
        let map = LaneMap::new(&[lane]).unwrap();
        let first = Pose3::identity();
        assert!(anchor_warning(&map, &Se2::new(0.0, 999.0, 0.0), &first).is_none());
        let w = anchor_warning(&map, &Se2::new(0.0, 2500.0, 0.0), &first).unwrap();
        assert!(w.contains("2.5 km"), "{w}");
        assert!(no_correction_warning(10, 0).is_some());
        assert!(no_correction_warning(10, 1).is_none());
    }

    #[test]
    fn a_source_faster_or_slower_than_its_preset_is_noticed_and_the_setting_named() {
        let params = crate::params::Preset::KissIcp.robust_params();
        let stamps = |hz: f64| {
            (0..100)
                .map(|i| 1.7e9 + i as f64 / hz)
                .collect::<Vec<f64>>()
        };
        let rate = rate_from_stamps(&stamps(100.0)).unwrap();
        assert!((rate - 100.0).abs() < 1e-3, "{rate}");
        let w = rate_warning(rate, &params).unwrap();
        assert!(w.contains("odometry_rate_hz=100"), "{w}");
        assert!(rate_warning(rate_from_stamps(&stamps(10.0)).unwrap(), &params).is_none());
        assert!(rate_warning(rate_from_stamps(&stamps(14.0)).unwrap(), &params).is_none());
        assert!(rate_warning(rate_from_stamps(&stamps(7.0)).unwrap(), &params).is_none());
        // A slower source too: its window would span twice the time and road.
        let w = rate_warning(rate_from_stamps(&stamps(5.0)).unwrap(), &params).unwrap();
        assert!(
            w.contains("about 5.0 Hz") && w.contains("odometry_rate_hz=5.0"),
            "{w}"
        );
        assert!(w.contains("first correction comes later"), "{w}");
        let mut set = params;
        set.odometry_rate_hz = 100.0;
        assert!(rate_warning(rate, &set).is_none());
        // Counters, a constant or stamps out of order tell no rate.
        let counters: Vec<f64> = (0..100).map(|i| i as f64 * 1e-9).collect();
        assert_eq!(rate_from_stamps(&counters), None);
        assert_eq!(rate_from_stamps(&[0.0; 100]), None);
        assert_eq!(rate_from_stamps(&[3.0, 2.0, 1.0, 0.0]), None);
        // The probe tells it once, after its stamps are in.
        let mut probe = RateProbe::default();
        let told: Vec<Option<f64>> = stamps(100.0)
            .into_iter()
            .map(|s| probe.observe(s))
            .collect();
        assert_eq!(told.iter().flatten().count(), 1);
        assert!(told[RateProbe::STAMPS - 1].is_some());
    }
}
