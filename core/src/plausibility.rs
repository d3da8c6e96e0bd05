//! Checks that catch a run set up wrongly: everything parses and nothing is invalid, but the
//! answer would mislead. Each check returns a warning that says what to try; callers print it and
//! carry on (the run's output is still what the corrector computed).

use std::collections::VecDeque;

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

/// A warning when the motion of `poses` looks like the other axis convention.
pub fn axis_convention_warning(poses: &[Pose3], convention: AxisConvention) -> Option<String> {
    let mut motion = AxisMotion::default();
    poses.iter().for_each(|p| motion.observe(p));
    motion.warning(convention)
}

/// The path length of a stream of poses, and how much of it goes along the vertical axis, in
/// every axis convention, pose by pose.
#[derive(Clone, Debug, Default)]
struct AxisMotion {
    last: Option<Pose3>,
    /// Per convention of [`AxisConvention::ALL`]: metres along the vertical, metres in all.
    vertical_and_path_m: [(f64, f64); AxisConvention::ALL.len()],
}

impl AxisMotion {
    fn observe(&mut self, pose: &Pose3) {
        if let Some(last) = self.last.replace(*pose) {
            for (c, (vertical, path)) in AxisConvention::ALL
                .iter()
                .zip(&mut self.vertical_and_path_m)
            {
                let d = c.to_planar(pose).translation - c.to_planar(&last).translation;
                *vertical += d.z.abs();
                *path += d.norm();
            }
        }
    }

    /// The path length (metres).
    fn path_m(&self) -> f64 {
        self.vertical_and_path_m[0].1
    }

    /// The share of the 3D path length that goes along `convention`'s vertical axis; `None`
    /// while the path is too short to tell.
    fn vertical_share(&self, convention: AxisConvention) -> Option<f64> {
        let k = AxisConvention::ALL.iter().position(|&c| c == convention)?;
        let (vertical, path) = self.vertical_and_path_m[k];
        (path.is_finite() && path >= MIN_PATH_FOR_AXIS_CHECK_M).then(|| vertical / path)
    }

    /// A warning when the motion looks like another convention than `convention`.
    fn warning(&self, convention: AxisConvention) -> Option<String> {
        let share = self.vertical_share(convention)?;
        if share <= MAX_VERTICAL_SHARE {
            return None;
        }
        let better = AxisConvention::ALL
            .into_iter()
            .filter(|&c| c != convention)
            .find(|&c| {
                self.vertical_share(c)
                    .is_some_and(|s| s <= MAX_VERTICAL_SHARE)
            });
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
             the poses probably use another axis convention; {advice}",
            share * 100.0,
            convention.name()
        ))
    }
}

/// From how far (metres of path) into a stream a [`SourceWatch`] tells that its poses move
/// vertically more than [`MAX_VERTICAL_SHARE`] of the way. The share of the path so far: on the
/// 30 shared KITTI runs read in their own axes it stays below 0.07 from here to
/// [`AXIS_JUDGED_UNTIL_M`], but for the ground truth of 08, which rises 0.18 m a pose while the
/// car sets off (0.45 at 30 m, 0.30 at 60 m); read in the other axes it passes 0.33 by 97 m on
/// all of them but that one. The first metres alone cannot tell: a drive that turns at once
/// moves along an axis that is horizontal in both conventions.
const AXIS_JUDGED_FROM_M: f64 = 60.0;

/// How far (metres of path) a [`SourceWatch`] follows a stream's axes before it takes them as
/// right.
const AXIS_JUDGED_UNTIL_M: f64 = 300.0;

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

/// What `lanealign correct` asks to check when no correction was accepted.
pub const CHECK_CORRECT_SETUP: &str = "the anchor, --frame and that the map covers the drive";

/// A warning when no correction was accepted over a whole run of `poses` poses, in which
/// `attempts` alignments were tried: that `what_to_check` is the likely cause when they were
/// refused, and that the run never filled the corrector's window when none was tried.
pub fn no_correction_warning(
    poses: usize,
    attempts: usize,
    accepted: usize,
    what_to_check: &str,
) -> Option<String> {
    if poses == 0 || accepted > 0 {
        return None;
    }
    Some(if attempts == 0 {
        format!(
            "no alignment was tried in {poses} poses, so the output is the raw odometry: the \
             run ends before the corrector's window fills (or the vehicle stands still \
             throughout); a source faster than odometry_rate_hz fills it in as many times more \
             poses; the status file says each pose's status"
        )
    } else {
        format!(
            "no correction was accepted in {attempts} attempt{} over {poses} poses, so the output \
             is the raw odometry: check {what_to_check}; the status file's reason column says \
             why each attempt was refused",
            plural(attempts)
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

/// The most a car's speed changes per second (m/s^2): about 1 g, what its tyres give at most
/// when it brakes. Measured as [`SpeedWatch`] does, the speed of the 30 shared KITTI runs
/// (ground truth, LiDAR and visual odometry) changes by at most 5.5 m/s^2, but for the visual
/// odometry of sequence 01, which falls from 19 to 1 m/s within 0.6 s on the highway while the
/// car drives on at 22 m/s (docs/method.md, "Confidence").
pub const MAX_ACCELERATION_MPS2: f64 = 10.0;

/// How long (seconds) a stretch of poses the speed check measures a speed over: the median of
/// its steps' speeds, so that one long step (poses missing from the input, a jump) or one noisy
/// step does not count as a change of speed.
pub const SPEED_SPAN_S: f64 = 0.5;

/// A change of the odometry's speed faster than [`MAX_ACCELERATION_MPS2`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedChange {
    /// The pose (0-based) between the stretch before the change and the one after it.
    pub pose: usize,
    /// The speed before (m/s): the median over the [`SPEED_SPAN_S`] before `pose`.
    pub from_mps: f64,
    /// The speed after (m/s): the median over the [`SPEED_SPAN_S`] after `pose`.
    pub to_mps: f64,
    /// The time (seconds) from one stretch's middle to the other's: [`SPEED_SPAN_S`] in whole
    /// poses, at least one.
    pub over_s: f64,
}

impl SpeedChange {
    /// The acceleration (m/s^2, negative when braking) from one stretch's middle to the other's.
    pub fn acceleration_mps2(&self) -> f64 {
        (self.to_mps - self.from_mps) / self.over_s
    }
}

/// The most steps the speed check takes the median of: at a higher rate it looks at every few
/// poses only, so that a pose costs it a median of a few numbers at any rate.
const MAX_SPAN_STEPS: usize = 8;

/// Watches an odometry's speed, pose by pose, for changes faster than a car's can be
/// ([`MAX_ACCELERATION_MPS2`]): the speed is the median of the steps' over [`SPEED_SPAN_S`],
/// compared with the one over the [`SPEED_SPAN_S`] after it, so that one long step (poses missing
/// from the input, a jump) or one noisy step is no change. Above 16 Hz it takes every few poses
/// (at most eight steps to a span). Of the changes next to one another, the
/// steepest stands for them all, told when they end.
#[derive(Clone, Debug)]
pub struct SpeedWatch {
    /// The rate (Hz) of the poses it takes.
    rate_hz: f64,
    /// It takes every `every`-th pose.
    every: usize,
    /// Steps to a span.
    span: usize,
    /// Poses observed.
    seen: usize,
    /// The last pose taken (planar, metres).
    last: Option<[f64; 2]>,
    /// The last `2 span` steps' speeds (m/s), oldest first.
    speeds: VecDeque<f64>,
    scratch: Vec<f64>,
    /// The steepest change of the ones under way, and the pose of the last one as steep.
    open: Option<(SpeedChange, usize)>,
}

impl SpeedWatch {
    /// A watch for poses coming at `rate_hz` (a rate that is no rate, zero or not finite, is
    /// taken as the presets' 10 Hz).
    pub fn new(rate_hz: f64) -> Self {
        let rate_hz = if rate_hz.is_finite() && rate_hz > 0.0 {
            rate_hz
        } else {
            crate::params::PRESET_RATE_HZ
        };
        let steps = SPEED_SPAN_S * rate_hz;
        let every = ((steps / MAX_SPAN_STEPS as f64).ceil() as usize).max(1);
        let rate_hz = rate_hz / every as f64;
        // At most MAX_SPAN_STEPS already, but for rates beyond what `every` can count.
        let span = ((SPEED_SPAN_S * rate_hz).round() as usize).clamp(1, MAX_SPAN_STEPS);
        SpeedWatch {
            rate_hz,
            every,
            span,
            seen: 0,
            last: None,
            speeds: VecDeque::with_capacity(2 * span),
            scratch: Vec::with_capacity(span),
            open: None,
        }
    }

    /// Takes the next pose's position (planar, metres, any fixed frame); returns a change of
    /// speed no car makes when one has ended with this pose.
    pub fn observe(&mut self, position: [f64; 2]) -> Option<SpeedChange> {
        let index = self.seen;
        self.seen += 1;
        if !index.is_multiple_of(self.every) {
            return None;
        }
        let last = self.last.replace(position)?;
        if self.speeds.len() == 2 * self.span {
            self.speeds.pop_front();
        }
        let moved = (position[0] - last[0]).hypot(position[1] - last[1]);
        self.speeds.push_back(moved * self.rate_hz);
        if self.speeds.len() < 2 * self.span {
            return None;
        }
        let change = SpeedChange {
            pose: index.saturating_sub(self.span.saturating_mul(self.every)),
            from_mps: self.median(0),
            to_mps: self.median(self.span),
            over_s: self.span as f64 / self.rate_hz,
        };
        // NaN compares false: a span without a speed is no change.
        let steepness = change.acceleration_mps2().abs();
        if steepness > MAX_ACCELERATION_MPS2 {
            match &mut self.open {
                Some((steepest, last_as_steep)) => {
                    let steepest_so_far = steepest.acceleration_mps2().abs();
                    if steepness > steepest_so_far {
                        (*steepest, *last_as_steep) = (change, change.pose);
                    } else if steepness == steepest_so_far {
                        *last_as_steep = change.pose;
                    }
                }
                None => self.open = Some((change, change.pose)),
            }
            return None;
        }
        self.finish()
    }

    /// How many poses `change` (told by this watch) lies before the last pose observed.
    pub fn poses_since(&self, change: &SpeedChange) -> usize {
        self.seen.saturating_sub(1 + change.pose)
    }

    /// The change under way when the poses end, if one is.
    pub fn finish(&mut self) -> Option<SpeedChange> {
        let (mut steepest, last_as_steep) = self.open.take()?;
        // Spans that see the same change from a few poses apart are as steep (a change within
        // a step, medians of the same speeds): it lies in their middle.
        steepest.pose = (steepest.pose + last_as_steep) / 2;
        Some(steepest)
    }

    /// The median speed (m/s) of the span of steps from `first`; NaN when half of them or more
    /// are not finite.
    fn median(&mut self, first: usize) -> f64 {
        self.scratch.clear();
        let span = self.speeds.range(first..first + self.span);
        self.scratch.extend(span.copied().filter(|s| s.is_finite()));
        if self.scratch.len() * 2 <= self.span {
            return f64::NAN;
        }
        let mid = self.scratch.len() / 2;
        *self.scratch.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// The changes of speed faster than [`MAX_ACCELERATION_MPS2`] along `positions` (planar, metres,
/// any fixed frame) coming at `rate_hz`, as a [`SpeedWatch`] tells them.
pub fn speed_changes(positions: &[[f64; 2]], rate_hz: f64) -> Vec<SpeedChange> {
    let mut watch = SpeedWatch::new(rate_hz);
    let mut changes: Vec<SpeedChange> =
        positions.iter().filter_map(|&p| watch.observe(p)).collect();
    changes.extend(watch.finish());
    changes
}

/// A warning when the odometry's speed (the planar positions of `poses`, given in `convention`,
/// at `rate_hz`) changes faster than a car's can ([`speed_changes`]): where, and what it means
/// for the corrected poses.
pub fn speed_change_warning(
    poses: &[Pose3],
    convention: AxisConvention,
    rate_hz: f64,
) -> Option<String> {
    let positions: Vec<[f64; 2]> = poses
        .iter()
        .map(|p| convention.to_planar(p).planar_position())
        .collect();
    let changes = speed_changes(&positions, rate_hz);
    if changes.is_empty() {
        return None;
    }
    let shown = changes
        .iter()
        .map(|c| format!("pose {} ({:.1} -> {:.1} m/s)", c.pose, c.from_mps, c.to_mps));
    Some(format!(
        "the odometry's speed changes faster than a car's can (more than {MAX_ACCELERATION_MPS2} \
         m/s^2 over {SPEED_SPAN_S} s) at {} place{}: {}; it probably lost track there (a \
         visual odometry stalls where it sees too little), and where the lanes run straight the \
         corrector cannot tell how far the vehicle went meanwhile, so the corrected poses after \
         it may be off along the road by more than their covariance says (this takes the poses \
         to come at {rate_hz} Hz: where they do not, give their stamps or odometry_rate_hz)",
        changes.len(),
        plural(changes.len()),
        first_few(shown, changes.len()),
    ))
}

/// `"s"` unless `count` is one.
pub fn plural(count: usize) -> &'static str {
    if count == 1 {
        ""
    } else {
        "s"
    }
}

/// The first five of `count` items, comma-separated, with `, ...` when there are more.
pub fn first_few(items: impl Iterator<Item = String>, count: usize) -> String {
    let shown: Vec<String> = items.take(5).collect();
    let more = if count > shown.len() { ", ..." } else { "" };
    format!("{}{more}", shown.join(", "))
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

/// What a stream of stamped poses (a daemon session's) says of its source as the poses come,
/// as `correct` judges a file: whether they move as the set axis convention says (told once,
/// between [`AXIS_JUDGED_FROM_M`] and [`AXIS_JUDGED_UNTIL_M`] of path, as
/// [`axis_convention_warning`] tells it); the rate its first
/// [`SourceWatch::STAMPS`] stamps say ([`rate_from_stamps`]), told once; and the changes of speed
/// no car makes ([`SpeedWatch`]) judged at that rate, or at the rate the corrector is set for
/// where the stamps say none. Until the stamps tell the rate, it holds the positions, and then
/// judges them.
#[derive(Clone, Debug)]
pub struct SourceWatch {
    /// The rate (Hz) the corrector is set for: the speed's when the stamps tell no rate.
    set_rate_hz: f64,
    /// The axis convention the poses are said to come in.
    convention: AxisConvention,
    /// The motion so far, until the axes are judged.
    axes: Option<AxisMotion>,
    /// The first stamps (seconds), until they tell the rate.
    stamps_s: Vec<f64>,
    /// The planar positions (metres) that came with them.
    held: Vec<[f64; 2]>,
    /// The watch and the rate (Hz) it judges at, once that is known.
    speed: Option<(SpeedWatch, f64)>,
}

/// What one pose told a [`SourceWatch`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceNews {
    /// The rate (Hz) the stamps say, with the pose that completed the first
    /// [`SourceWatch::STAMPS`] of them (never again, nor when they say none).
    pub rate_hz: Option<f64>,
    /// A warning when the poses move as no vehicle does in the set axis convention, with the
    /// pose that judged them.
    pub axis_warning: Option<String>,
    /// The changes of speed no car makes that ended with this pose (or, with the pose that
    /// told the rate, among the poses held until then), oldest first.
    pub speed_changes: Vec<SpeedChange>,
}

impl SourceWatch {
    /// Stamps gathered before the rate is told.
    pub const STAMPS: usize = 64;

    /// A watch for a source whose corrector is set for `set_rate_hz` and whose poses are said
    /// to come in `convention`.
    pub fn new(set_rate_hz: f64, convention: AxisConvention) -> Self {
        SourceWatch {
            set_rate_hz,
            convention,
            axes: Some(AxisMotion::default()),
            stamps_s: Vec::with_capacity(Self::STAMPS),
            held: Vec::with_capacity(Self::STAMPS),
            speed: None,
        }
    }

    /// Takes the next pose (`odom_from_body` in the set convention) and its stamp (seconds).
    pub fn observe(&mut self, stamp_s: f64, pose: &Pose3) -> SourceNews {
        let axis_warning = self.follow_axes(pose);
        let position = self.convention.to_planar(pose).planar_position();
        let mut news = match &mut self.speed {
            Some((speed, _)) => SourceNews {
                speed_changes: speed.observe(position).into_iter().collect(),
                ..SourceNews::default()
            },
            None => {
                self.stamps_s.push(stamp_s);
                self.held.push(position);
                if self.stamps_s.len() < Self::STAMPS {
                    SourceNews::default()
                } else {
                    self.judge_held()
                }
            }
        };
        news.axis_warning = axis_warning;
        news
    }

    /// Where the stream ends: a change of speed still under way, and for a stream shorter than
    /// [`SourceWatch::STAMPS`] poses what its stamps and positions say at all (a stream shorter
    /// than [`AXIS_JUDGED_FROM_M`] is not judged for its axes).
    pub fn finish(&mut self) -> SourceNews {
        let mut news = match self.speed {
            Some(_) => SourceNews::default(),
            None => self.judge_held(),
        };
        news.speed_changes
            .extend(self.speed.as_mut().and_then(|(s, _)| s.finish()));
        news
    }

    /// Follows the motion until its axes are told wrong (from [`AXIS_JUDGED_FROM_M`] of path on)
    /// or [`AXIS_JUDGED_UNTIL_M`] of path have not told them so.
    fn follow_axes(&mut self, pose: &Pose3) -> Option<String> {
        let motion = self.axes.as_mut()?;
        motion.observe(pose);
        let path_m = motion.path_m();
        if path_m < AXIS_JUDGED_FROM_M {
            return None;
        }
        let warning = motion.warning(self.convention);
        if warning.is_some() || path_m >= AXIS_JUDGED_UNTIL_M {
            self.axes = None;
        }
        warning
    }

    /// Judges the held positions' speed at the rate their stamps say (or the set rate), at
    /// which it watches on.
    fn judge_held(&mut self) -> SourceNews {
        let rate_hz = rate_from_stamps(&self.stamps_s);
        let judged_hz = rate_hz.unwrap_or(self.set_rate_hz);
        let mut speed = SpeedWatch::new(judged_hz);
        let speed_changes = self.held.iter().filter_map(|&p| speed.observe(p)).collect();
        self.speed = Some((speed, judged_hz));
        (self.stamps_s, self.held) = (Vec::new(), Vec::new());
        SourceNews {
            rate_hz,
            speed_changes,
            ..SourceNews::default()
        }
    }

    /// How many poses `change` (told by this watch) lies before the last pose observed.
    pub fn poses_since(&self, change: &SpeedChange) -> usize {
        self.speed
            .as_ref()
            .map_or(0, |(s, _)| s.poses_since(change))
    }

    /// The rate (Hz) the speed is judged at: the stamps', or the set rate where they tell none;
    /// `None` while the stamps are still gathered.
    pub fn speed_rate_hz(&self) -> Option<f64> {
        self.speed.as_ref().map(|&(_, rate_hz)| rate_hz)
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
        let check = CHECK_CORRECT_SETUP;
        let refused = no_correction_warning(10, 4, 0, check).unwrap();
        assert!(refused.contains("4 attempts over 10 poses") && refused.contains("--frame"));
        let untried = no_correction_warning(10, 0, 0, check).unwrap();
        assert!(
            untried.contains("no alignment was tried in 10 poses"),
            "{untried}"
        );
        assert!(!untried.contains("--frame"), "{untried}");
        assert!(no_correction_warning(10, 4, 1, check).is_none());
        assert!(no_correction_warning(0, 0, 0, check).is_none());
    }

    /// A drive along x at 10 Hz whose speed (m/s) at each step `speed(step)` gives.
    fn drive(steps: usize, speed: impl Fn(usize) -> f64) -> Vec<[f64; 2]> {
        drive_at(10.0, steps, speed)
    }

    /// A drive along x at `rate_hz` whose speed (m/s) at each step `speed(step)` gives.
    fn drive_at(rate_hz: f64, steps: usize, speed: impl Fn(usize) -> f64) -> Vec<[f64; 2]> {
        let mut x = 0.0;
        let mut out = vec![[x, 0.0]];
        for k in 0..steps {
            x += speed(k) / rate_hz;
            out.push([x, 0.0]);
        }
        out
    }

    #[test]
    fn an_odometry_that_stalls_at_speed_is_noticed_and_hard_braking_is_not() {
        // 20 m/s for 10 s, then braking at 8 m/s^2 (0.8 g) to a stop: a car can.
        let braking = drive(200, |k| {
            if k < 100 {
                20.0
            } else {
                (20.0 - 0.8 * (k - 100) as f64).max(0.0)
            }
        });
        assert_eq!(speed_changes(&braking, 10.0), []);
        // The odometry falls from 20 m/s to 1 m/s in 0.4 s and stays there: no car can.
        let stalled = drive(200, |k| match k {
            0..100 => 20.0,
            100..104 => 20.0 - 4.75 * (k - 99) as f64,
            _ => 1.0,
        });
        let changes = speed_changes(&stalled, 10.0);
        assert_eq!(changes.len(), 1, "{changes:?}");
        let stall = changes[0];
        assert!((99..=105).contains(&stall.pose), "{stall:?}");
        assert!(stall.from_mps >= 15.0 && stall.to_mps <= 5.0, "{stall:?}");
        assert!(stall.acceleration_mps2() < -MAX_ACCELERATION_MPS2);
        let poses: Vec<Pose3> = stalled
            .iter()
            .map(|&[x, y]| Pose3::planar(x, y, 0.0, 0.0))
            .collect();
        let w = speed_change_warning(&poses, AxisConvention::Flu, 10.0).unwrap();
        assert!(
            w.contains(&format!("at 1 place: pose {}", stall.pose)),
            "{w}"
        );
        assert!(speed_change_warning(&poses[..100], AxisConvention::Flu, 10.0).is_none());
    }

    /// A source at 2 Hz set for 10 Hz: its speed is judged at the rate its stamps say, the
    /// positions held until they say it included, so that braking is not read as five times
    /// faster and five times steeper. A stall is told at that rate, where it lies, before and
    /// after the stamps have told.
    #[test]
    fn a_session_is_judged_at_the_rate_of_its_stamps() {
        let stamps: Vec<f64> = (0..200).map(|i| 100.0 + 0.5 * i as f64).collect();
        // Braking at 4 m/s^2 from 20 m/s to 4 m/s and speeding up as hard again, from pose 20
        // (held) and from pose 120.
        let braking = drive_at(2.0, 199, |k| match k % 100 {
            k @ 0..50 => (20.0 - 2.0 * k.saturating_sub(20) as f64).max(4.0),
            k => (4.0 + 2.0 * (k - 50) as f64).min(20.0),
        });
        assert!(
            !speed_changes(&braking, 10.0).is_empty(),
            "read at the set 10 Hz, the braking is 25 times steeper"
        );
        let mut watch = SourceWatch::new(10.0, AxisConvention::Flu);
        let news: Vec<SourceNews> = stamps
            .iter()
            .zip(&along_x(&braking))
            .map(|(&s, p)| watch.observe(s, p))
            .collect();
        let rates: Vec<f64> = news.iter().filter_map(|n| n.rate_hz).collect();
        assert_eq!(rates.len(), 1);
        assert!((rates[0] - 2.0).abs() < 1e-9, "{rates:?}");
        assert!(news[SourceWatch::STAMPS - 1].rate_hz.is_some());
        assert_eq!(watch.speed_rate_hz(), Some(2.0));
        let told: Vec<&SpeedChange> = news.iter().flat_map(|n| &n.speed_changes).collect();
        assert!(told.is_empty(), "{told:?}");
        // A stall from 20 to 0.5 m/s in one step at pose 30 (held), its recovery at 100 and the
        // same stall at 130.
        let stalled = along_x(&drive_at(
            2.0,
            199,
            |k| {
                if k % 100 < 30 {
                    20.0
                } else {
                    0.5
                }
            },
        ));
        let mut watch = SourceWatch::new(10.0, AxisConvention::Flu);
        let mut told = Vec::new();
        for (i, (&s, p)) in stamps.iter().zip(&stalled).enumerate() {
            for change in watch.observe(s, p).speed_changes {
                told.push(i - watch.poses_since(&change));
            }
        }
        assert_eq!(told.len(), 3, "{told:?}");
        for (at, pose) in [30, 100, 130].into_iter().zip(told) {
            assert!((at - 1..=at + 2).contains(&pose), "{pose} for {at}");
        }
        // A stream that ends in a stall, or before its stamps have told the rate, is told when
        // it ends.
        for poses in [32, 132] {
            let mut watch = SourceWatch::new(10.0, AxisConvention::Flu);
            let during: usize = stamps
                .iter()
                .zip(&stalled[..poses])
                .map(|(&s, p)| watch.observe(s, p).speed_changes.len())
                .sum();
            assert_eq!(during, if poses < 100 { 0 } else { 2 });
            let end = watch.finish();
            assert_eq!(end.speed_changes.len(), 1, "{poses}: {end:?}");
            let pose = poses - 1 - watch.poses_since(&end.speed_changes[0]);
            assert!((poses - 11..poses).contains(&pose), "{pose} of {poses}");
            assert_eq!(end.rate_hz.is_some(), poses < SourceWatch::STAMPS);
        }
        // Stamps that tell no rate leave it at the set rate.
        let mut watch = SourceWatch::new(10.0, AxisConvention::Flu);
        let news: Vec<SourceNews> = stalled.iter().map(|p| watch.observe(0.0, p)).collect();
        assert!(news.iter().all(|n| n.rate_hz.is_none()));
        assert_eq!(watch.speed_rate_hz(), Some(10.0));
    }

    /// Poses along x (planar `flu`, heading along x) at `positions`.
    fn along_x(positions: &[[f64; 2]]) -> Vec<Pose3> {
        positions
            .iter()
            .map(|&[x, y]| Pose3::planar(x, y, 0.0, 0.0))
            .collect()
    }

    /// A session's poses are checked for their axes from 60 m of path on: a camera's poses
    /// watched as `flu` are told once, with the convention that fits, also after standing still
    /// for longer than the rate takes to tell; watched as what they are, they are not. A drive
    /// that turns at once is told where its vertical share passes a third.
    #[test]
    fn a_session_in_the_wrong_axes_is_told_once() {
        let camera_of = |flu: &[Pose3]| -> Vec<Pose3> {
            flu.iter()
                .map(|p| AxisConvention::KittiCamera.from_planar(p))
                .collect()
        };
        let camera = camera_of(&along_x(&drive(399, |_| 10.0)));
        let parked_first: Vec<Pose3> = std::iter::repeat_n(camera[0], 100)
            .chain(camera.iter().copied())
            .collect();
        // 40 m along its start's right-hand axis (horizontal either way), then ahead.
        let turning = camera_of(
            &(0..400)
                .map(|i| {
                    let (x, y) = if i < 40 {
                        (0.0, -(i as f64))
                    } else {
                        ((i - 40) as f64, -40.0)
                    };
                    Pose3::planar(x, y, 0.0, 0.0)
                })
                .collect::<Vec<_>>(),
        );
        // The metres driven when the share of the path along the camera's forward axis (up,
        // read as `flu`) first passes a third: 60 for the straight drives, 60 for the turning
        // one (20 of 60 m).
        for (poses, told_at_m) in [(&camera, 60), (&parked_first, 60), (&turning, 60)] {
            for (convention, told) in [(AxisConvention::Flu, 1), (AxisConvention::KittiCamera, 0)] {
                let mut watch = SourceWatch::new(10.0, convention);
                let warnings: Vec<(usize, String)> = poses
                    .iter()
                    .enumerate()
                    .filter_map(|(i, p)| Some((i, watch.observe(0.1 * i as f64, p).axis_warning?)))
                    .collect();
                assert_eq!(warnings.len(), told, "{convention:?}: {warnings:?}");
                if let Some((i, w)) = warnings.first() {
                    assert!(w.contains("--frame kitti-camera"), "{w}");
                    assert_eq!(poses.len() - i, 400 - told_at_m, "after {told_at_m} m");
                }
                assert_eq!(watch.finish().axis_warning, None);
            }
        }
    }

    #[test]
    fn a_stall_is_noticed_at_any_rate_and_one_under_way_at_the_end_too() {
        for rate_hz in [1.0, 4.0, 25.0, 100.0, 1000.0] {
            // 20 m/s for 30 s, then 1 m/s, the change within one step.
            let n = (60.0 * rate_hz) as usize;
            let positions: Vec<[f64; 2]> = (0..n)
                .map(|i| {
                    let t = i as f64 / rate_hz;
                    [20.0 * t.min(30.0) + (t - 30.0).max(0.0), 0.0]
                })
                .collect();
            let changes = speed_changes(&positions, rate_hz);
            assert_eq!(changes.len(), 1, "{rate_hz} Hz: {changes:?}");
            let full = changes[0];
            let at_s = full.pose as f64 / rate_hz;
            assert!(
                (at_s - 30.0).abs() <= full.over_s / 2.0,
                "{rate_hz} Hz: {full:?}"
            );
            // Cut where the span after the change ends: it is still under way, and is told
            // when the poses end.
            let end = full.pose + (full.over_s * rate_hz).round() as usize + 1;
            let mut watch = SpeedWatch::new(rate_hz);
            assert!(positions[..end].iter().all(|&p| watch.observe(p).is_none()));
            let cut = watch.finish().unwrap();
            assert_eq!((cut.from_mps, cut.to_mps), (full.from_mps, full.to_mps));
            assert!((cut.pose as f64 - full.pose as f64).abs() <= full.over_s * rate_hz);
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(31), ..Default::default() })]

        /// Any positions (NaN, infinite, 1e308 m) at any rate: changes name poses of the input,
        /// with speeds that are numbers, one at most for every two spans.
        #[test]
        fn any_positions_give_changes_within_the_input(
            positions in proptest::collection::vec(
                (proptest::num::f64::ANY, proptest::num::f64::ANY), 0..300),
            rate_hz in proptest::prop_oneof![0.1f64..2000.0, proptest::num::f64::ANY],
        ) {
            let positions: Vec<[f64; 2]> = positions.into_iter().map(|(x, y)| [x, y]).collect();
            let changes = speed_changes(&positions, rate_hz);
            for c in &changes {
                proptest::prop_assert!(c.pose < positions.len(), "{c:?}");
                proptest::prop_assert!(!c.from_mps.is_nan() && !c.to_mps.is_nan(), "{c:?}");
            }
            proptest::prop_assert!(changes.len() <= positions.len() / 2 + 1);
        }
    }

    #[test]
    fn poses_missing_noise_and_bad_positions_are_no_change_of_speed() {
        // One step over five missing poses.
        let gap = drive(100, |k| if k == 50 { 120.0 } else { 20.0 });
        assert_eq!(speed_changes(&gap, 10.0), []);
        // 100 Hz with every position off by up to 2 cm (per-step speeds off by up to 4 m/s).
        let mut rng = crate::rng::Lcg(7);
        let noisy: Vec<[f64; 2]> = (0..2000)
            .map(|i| [0.2 * i as f64 + 0.04 * (rng.uniform() - 0.5), 0.0])
            .collect();
        assert_eq!(speed_changes(&noisy, 100.0), []);
        // A stretch of non-finite positions tells no speed.
        let mut holed = drive(100, |_| 20.0);
        holed[40..46].fill([f64::NAN, 0.0]);
        assert_eq!(speed_changes(&holed, 10.0), []);
        let stalled = drive(100, |k| if k < 50 { 20.0 } else { 0.0 });
        assert_eq!(speed_changes(&stalled, 10.0).len(), 1);
        // A rate that is no rate is taken as the presets'.
        assert_eq!(speed_changes(&stalled, 0.0), speed_changes(&stalled, 10.0));
        assert_eq!(
            speed_changes(&stalled, f64::NAN),
            speed_changes(&stalled, 10.0)
        );
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
    }
}
