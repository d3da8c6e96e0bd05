//! Checks that catch a run set up wrongly: everything parses and nothing is invalid, but the
//! answer would mislead. Each check returns a warning that says what to try; callers print it and
//! carry on (the run's output is still what the corrector computed). By what they look at:
//! - a run's setup (`setup`): its anchor against the map, whether enough corrections were
//!   accepted, the odometry's jumps;
//! - the poses' axes (`axes`): whether they move and stand as a vehicle does in the set
//!   convention;
//! - the odometry's speed (`speed`): changes no car makes, where it lost track;
//! - the poses' stamps (`rate`): the rate the source runs at against the corrector's;
//! - a stream of poses as it comes (`source_watch`): the axes, the rate and the speed, pose by
//!   pose, for a daemon session.

mod axes;
mod rate;
mod setup;
mod source_watch;
mod speed;

pub use axes::{axes_warning, AxisMotion, MAX_TILTED_SHARE, MAX_TILT_DEG, MAX_VERTICAL_SHARE};
pub use rate::{judged_rate_hz, rate_from_stamps, rate_text, rate_warning, MAX_RATE_RATIO};
pub use setup::{
    anchor_warning, distance_to_lanes, odometry_jump_warning, poses_missing_warning,
    refusals_warning, too_far_from_lanes, CHECK_CORRECT_SETUP, MAX_START_TO_LANE_M,
    MIN_ACCEPTED_SHARE, MIN_ATTEMPTS_JUDGED,
};
pub use source_watch::{
    Pace, SourceNews, SourceWatch, SourceWatchState, AXIS_JUDGED_FROM_M, AXIS_JUDGED_UNTIL_M,
    PACE_STEPS,
};
pub use speed::{
    speed_change_warning, speed_changes, speed_warning, SpeedChange, SpeedHistory, SpeedWatch,
    MAX_ACCELERATION_MPS2, MAX_REPEATS, SPEED_SPAN_S,
};

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
