//! Whether a run's setup lets the map correct it: the anchor against the map, whether enough
//! corrections were accepted, the odometry's jumps and the poses missing from it.

use super::{first_few, plural};
use crate::continuity::{Continued, Continuity};
use crate::corrector::Status;
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{AxisConvention, Pose3};
use crate::se2::Se2;
use crate::source_corrector::CorrectedPose;

/// Farthest the anchored start of a run may lie from every lane point before the anchor is
/// suspect (metres).
pub const MAX_START_TO_LANE_M: f64 = 1000.0;

/// The distance (metres) from `position_in_map` to the nearest lane point of `map`.
pub fn distance_to_lanes(map: &LaneMap, position_in_map: [f64; 2]) -> f64 {
    let mut nearest = Vec::with_capacity(1);
    map.nearest(position_in_map, 1, &mut nearest);
    nearest.first().map_or(f64::INFINITY, |c| c.0.sqrt())
}

/// How far `position_in_map` lies from the nearest lane of `map`, spelt in kilometres ("536.2
/// km", or "arbitrarily far"), when that is more than [`MAX_START_TO_LANE_M`]: an anchor that
/// places a run's start (or a source's odometry origin) there is suspect.
pub fn too_far_from_lanes(map: &LaneMap, position_in_map: [f64; 2]) -> Option<String> {
    let distance = distance_to_lanes(map, position_in_map);
    (distance > MAX_START_TO_LANE_M).then(|| {
        if distance.is_finite() {
            format!("{:.1} km", distance / 1000.0)
        } else {
            "arbitrarily far".to_string()
        }
    })
}

/// A warning when the anchor places the start of the run, `first` (planar `flu`), more than
/// [`MAX_START_TO_LANE_M`] from every lane.
pub fn anchor_warning(map: &LaneMap, anchored_from_odom: &Se2, first: &Pose3) -> Option<String> {
    let start = anchored_from_odom.apply(first.planar_position());
    too_far_from_lanes(map, start).map(|distance| {
        format!(
            "the anchor places the first pose {distance} from the nearest lane: check --anchor \
             (LAT,LON in degrees, YAW_DEG from East counter-clockwise) and that the map covers \
             the drive (`lanealign-map inspect TILE --geojson lanes.geojson`)"
        )
    })
}

/// What `lanealign correct` asks to check when no correction, or few, were accepted.
pub const CHECK_CORRECT_SETUP: &str =
    "the anchor (YAW_DEG in degrees from East, counter-clockwise), --frame, that the poses are \
     in metres and that the map covers the drive";

/// Fewest alignments over which [`refusals_warning`] judges the share accepted.
pub const MIN_ATTEMPTS_JUDGED: usize = 100;

/// Smallest share of at least [`MIN_ATTEMPTS_JUDGED`] alignments accepted before the setup is
/// suspect. Measured on the 240 runs of the shared KITTI data (ground truth, LiDAR and visual
/// odometry; every preset; both methods): at least 26 % accepted over a whole run and 37 of the
/// first 100 alignments. KITTI 00's LiDAR run with its anchor's yaw in radians, clockwise from
/// North, or of the other sign gets 0.5-0.9 %, with the anchor 50 m off 7.4 %.
pub const MIN_ACCEPTED_SHARE: f64 = 0.1;

/// A warning when no correction, or fewer than [`MIN_ACCEPTED_SHARE`] of at least
/// [`MIN_ATTEMPTS_JUDGED`], was accepted over a run of `poses` poses in which `attempts`
/// alignments were tried: that `what_to_check` is the likely cause when they were refused, and
/// that the run never filled the corrector's window when none was tried.
pub fn refusals_warning(
    poses: usize,
    attempts: usize,
    accepted: usize,
    what_to_check: &str,
) -> Option<String> {
    let share = accepted as f64 / attempts as f64;
    let few = attempts >= MIN_ATTEMPTS_JUDGED && share < MIN_ACCEPTED_SHARE;
    if poses == 0 || (accepted > 0 && !few) {
        return None;
    }
    Some(if attempts == 0 {
        format!(
            "no alignment was tried in {poses} poses, so the output is the raw odometry: the \
             run ends before the corrector's window fills (or the vehicle stands still \
             throughout); a source faster than odometry_rate_hz fills it in as many times more \
             poses; the status file says each pose's status"
        )
    } else if accepted == 0 {
        format!(
            "no correction was accepted in {attempts} attempt{} over {poses} poses, so the output \
             is the raw odometry: check {what_to_check}; the status file's reason column says \
             why each attempt was refused",
            plural(attempts)
        )
    } else {
        format!(
            "only {accepted} of {attempts} alignments over {poses} poses were accepted ({:.1}%), \
             so the output is mostly the odometry: check {what_to_check}; the status file's \
             reason column says why each attempt was refused",
            share * 100.0
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
    Some(format!(
        "the odometry jumped at {} pose{} ({}): farther than max_speed_mps ({} m/s) from the \
         pose before, so each was continued from where the vehicle was (status odometry_jump); \
         if the poses only paused or come slower than odometry_rate_hz ({} Hz), give their \
         stamps (TUM) or the rate",
        jumps.len(),
        plural(jumps.len()),
        first_few(jumps.iter().map(usize::to_string), jumps.len()),
        params.max_speed_mps,
        params.odometry_rate_hz,
    ))
}

/// A warning when steps of the odometry were taken for poses missing from the input
/// ([`Continued::OverGap`]: longer than [`Params::max_speed_mps`] allows in one period, driving
/// on as the step before, without stamps that time them): at which poses (0-based, the first
/// few), and that a glitch straight ahead reads the same. `poses` in `convention`, stamped
/// `stamps_s` (seconds) where the input has stamps; judged as the corrector judges them.
pub fn poses_missing_warning(
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
    convention: AxisConvention,
    params: &Params,
) -> Option<String> {
    let mut continuity = Continuity::default();
    let gaps: Vec<usize> = poses
        .iter()
        .enumerate()
        .filter(|(_, pose)| pose.problem().is_none())
        .filter(|&(i, pose)| {
            let stamp_s = stamps_s.and_then(|s| s.get(i).copied()).unwrap_or(f64::NAN);
            let planar = convention.to_planar(pose).to_se2();
            matches!(
                continuity.observe(planar, stamp_s, params),
                Continued::OverGap { .. }
            )
        })
        .map(|(i, _)| i)
        .collect();
    if gaps.is_empty() {
        return None;
    }
    Some(format!(
        "{} step{} of the odometry ({}) {} longer than max_speed_mps ({} m/s) allows in one \
         period at odometry_rate_hz ({} Hz) and drove on as the step before: taken for poses \
         missing from the input; a pose that glitched straight ahead reads the same, so each is \
         published with a covariance that covers that; give the stamps (TUM) to have each \
         judged by its time",
        gaps.len(),
        plural(gaps.len()),
        first_few(gaps.iter().map(usize::to_string), gaps.len()),
        if gaps.len() == 1 { "was" } else { "were" },
        params.max_speed_mps,
        params.odometry_rate_hz,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;

    #[test]
    fn a_far_anchor_is_noticed() {
        let lane = Lane::new(1, (0..10).map(|i| [i as f64 * 3.0, 0.0]).collect());
        let map = LaneMap::new(&[lane]).unwrap();
        let first = Pose3::identity();
        assert!(anchor_warning(&map, &Se2::new(0.0, 999.0, 0.0), &first).is_none());
        let w = anchor_warning(&map, &Se2::new(0.0, 2500.0, 0.0), &first).unwrap();
        assert!(w.contains("2.5 km"), "{w}");
        let check = CHECK_CORRECT_SETUP;
        let refused = refusals_warning(10, 4, 0, check).unwrap();
        assert!(refused.contains("4 attempts over 10 poses") && refused.contains("--frame"));
        let untried = refusals_warning(10, 0, 0, check).unwrap();
        assert!(
            untried.contains("no alignment was tried in 10 poses"),
            "{untried}"
        );
        assert!(!untried.contains("--frame"), "{untried}");
        assert!(refusals_warning(10, 4, 1, check).is_none());
        assert!(refusals_warning(0, 0, 0, check).is_none());
        // Few accepted: judged over 100 attempts or more.
        let few = refusals_warning(4541, 4332, 40, check).unwrap();
        assert!(
            few.starts_with("only 40 of 4332 alignments over 4541 poses were accepted (0.9%)"),
            "{few}"
        );
        assert!(refusals_warning(500, 100, 9, check).is_some());
        assert!(refusals_warning(500, 100, 10, check).is_none());
        assert!(refusals_warning(500, 99, 1, check).is_none());
    }
}
