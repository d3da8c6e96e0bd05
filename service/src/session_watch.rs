//! What a session's poses have told so far, for the daemon's warnings: the source's rate, axes,
//! pace and speed ([`SourceWatch`]), its jumps, and its alignments (to warn when none or few are
//! accepted). What it told is also raised as bits ([`Warning`]) that every later answer of the
//! session carries, so that the client knows without reading the daemon's log.
//!
//! It is part of a session's state like its corrector: a snapshot in the journal holds it, and
//! restoring replays the records after the snapshot through it, so that a session restored
//! after the daemon was killed warns as if the daemon had run on: a change of speed under way
//! at the kill is told once it ends, and what was told before is not told again.

use lanealign_core::corrector::Status;
use lanealign_core::params::Params;
use lanealign_core::plausibility::{
    rate_warning, refusals_warning, SourceNews, SourceWatch, SourceWatchState, SpeedChange,
    MIN_ATTEMPTS_JUDGED,
};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::Counts;
use lanealign_wire::payload::{OdomPose, Warning};

/// How many alignments a session tries before its watch warns that none, or fewer than one in
/// ten ([`MIN_ACCEPTED_SHARE`](lanealign_core::plausibility::MIN_ACCEPTED_SHARE)), were
/// accepted (the robust presets try one per metre of road: 100 m of driving; a session that
/// ends sooner is told when it ends, if none was).
pub const REFUSALS_TOLD: usize = MIN_ATTEMPTS_JUDGED;

/// What the daemon's log asks a session that few alignments were accepted in to check.
const CHECK_SOURCE_SETUP: &str =
    "the source's anchor and frame in this configuration and that the tile covers the drive";

/// What a session's corrected poses have told so far.
#[derive(Clone, Debug)]
pub struct SessionWatch {
    /// The source's parameters: the rate and speed its poses are judged against.
    params: Params,
    /// The session's stamps and poses, to warn once when the source is faster or slower than
    /// its corrector is set for or its poses move as no vehicle does in the source's frame, and
    /// when its speed changes faster than a car's can (an odometry that lost track).
    source: SourceWatch,
    /// The sequence number of the last pose `source` took (0 before the first).
    watched_seq: u64,
    /// The session's alignments so far.
    alignments: Counts,
    /// The poses it answered with a correction.
    corrected_poses: usize,
    /// The [`Warning`] bits raised so far.
    raised: u64,
}

/// What a [`SessionWatch`] has seen, to continue from later ([`SessionWatch::restore`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SessionWatchState {
    /// The source watch's.
    pub source: SourceWatchState,
    /// The sequence number of the last pose watched (0 before the first).
    pub watched_seq: u64,
    /// The alignments so far.
    pub alignments: Counts,
    /// The poses answered with a correction so far.
    pub corrected_poses: usize,
    /// The [`Warning`] bits raised so far.
    pub raised: u64,
}

/// What one pose, or a session's end, told a [`SessionWatch`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SessionNews {
    /// Warnings of the session's setup, each told once: the rate its stamps say, its axes, its
    /// pace, and its alignments refused.
    pub warnings: Vec<String>,
    /// The changes of speed no car makes that ended with the pose, oldest first.
    pub speed_changes: Vec<SpeedChange>,
}

impl SessionWatch {
    /// A watch for a new session of a source whose corrector has `params` and whose poses come
    /// in `convention`.
    pub fn new(params: &Params, convention: AxisConvention) -> Self {
        SessionWatch {
            params: *params,
            source: SourceWatch::new(params.odometry_rate_hz, params.max_speed_mps, convention),
            watched_seq: 0,
            alignments: Counts::default(),
            corrected_poses: 0,
            raised: 0,
        }
    }

    /// A watch for the same source that continues from `state`, exactly as the one it was
    /// saved from would.
    pub fn restore(params: &Params, convention: AxisConvention, state: SessionWatchState) -> Self {
        SessionWatch {
            params: *params,
            source: SourceWatch::restore(
                params.odometry_rate_hz,
                params.max_speed_mps,
                convention,
                state.source,
            ),
            watched_seq: state.watched_seq,
            alignments: state.alignments,
            corrected_poses: state.corrected_poses,
            raised: state.raised,
        }
    }

    /// What the watch has seen (see [`SessionWatch::restore`]).
    pub fn state(&self) -> SessionWatchState {
        SessionWatchState {
            source: self.source.state(),
            watched_seq: self.watched_seq,
            alignments: self.alignments,
            corrected_poses: self.corrected_poses,
            raised: self.raised,
        }
    }

    /// Takes a pose the session answered with a correction (`status`, any but invalid input),
    /// and whether its corrector took the step to it for poses missing (`took_poses_missing`:
    /// [`lanealign_core::source_corrector::SourceCorrector::took_poses_missing`]); returns what
    /// it told, and raises it.
    pub fn observe(
        &mut self,
        input: &OdomPose,
        status: &Status,
        took_poses_missing: bool,
    ) -> SessionNews {
        let source = self
            .source
            .observe(input.stamp_s(), &Pose3::from_row_major(&input.pose));
        self.watched_seq = input.seq;
        let attempts = self.alignments.attempts;
        self.alignments.add(status);
        self.corrected_poses = self.corrected_poses.saturating_add(1);
        // Judged once: by the alignment that makes the count (poses carried without one leave
        // it there).
        let judged = attempts < REFUSALS_TOLD && self.alignments.attempts == REFUSALS_TOLD;
        let refusals = self.refusals_warning().filter(|_| judged);
        let step = if matches!(status, Status::OdometryJump { .. }) {
            Some(Warning::Jumped)
        } else {
            took_poses_missing.then_some(Warning::PosesMissing)
        };
        self.raise(source, refusals, step)
    }

    /// What the watch tells where the session ends (see [`SourceWatch::finish`]), and, if it
    /// ended before [`REFUSALS_TOLD`] alignments, that none it tried was accepted.
    pub fn finish(&mut self) -> SessionNews {
        let source = self.source.finish();
        let refusals = self
            .refusals_warning()
            .filter(|_| self.alignments.attempts < REFUSALS_TOLD);
        self.raise(source, refusals, None)
    }

    /// Raises what `source` told, the `refusals` warning and what the step to the pose was
    /// (`step`: [`Warning::Jumped`], [`Warning::PosesMissing`], or `None` for motion), and
    /// returns them as news.
    fn raise(
        &mut self,
        source: SourceNews,
        refusals: Option<String>,
        step: Option<Warning>,
    ) -> SessionNews {
        let rate = source.rate_hz.and_then(|r| rate_warning(r, &self.params));
        for (raised, warning) in [
            (source.axis_warning.is_some(), Warning::Axes),
            (rate.is_some(), Warning::Rate),
            (source.pace_warning.is_some(), Warning::Pace),
            (refusals.is_some(), Warning::Refusals),
            (!source.speed_changes.is_empty(), Warning::LostTrack),
            (step == Some(Warning::Jumped), Warning::Jumped),
            (step == Some(Warning::PosesMissing), Warning::PosesMissing),
        ] {
            if raised {
                self.raised |= warning.bit();
            }
        }
        SessionNews {
            warnings: [rate, source.axis_warning, source.pace_warning, refusals]
                .into_iter()
                .flatten()
                .collect(),
            speed_changes: source.speed_changes,
        }
    }

    /// The warning that none of the session's alignments was accepted, if it tried any, or
    /// few of at least [`REFUSALS_TOLD`].
    fn refusals_warning(&self) -> Option<String> {
        let Counts {
            attempts, accepted, ..
        } = self.alignments;
        refusals_warning(self.corrected_poses, attempts, accepted, CHECK_SOURCE_SETUP)
            .filter(|_| attempts > 0)
    }

    /// The [`Warning`] bits raised so far.
    pub fn raised(&self) -> u64 {
        self.raised
    }

    /// The sequence number of the pose where `change` (told by this watch) lies.
    pub fn seq_of(&self, change: &SpeedChange) -> u64 {
        self.watched_seq
            .saturating_sub(self.source.poses_since(change) as u64)
    }

    /// The rate (Hz) the speed is judged at: the one the stamps told, or the source's
    /// `odometry_rate_hz` until they have (no change of speed is told before).
    pub fn speed_rate_hz(&self) -> f64 {
        self.source
            .speed_rate_hz()
            .unwrap_or(self.params.odometry_rate_hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lanealign_core::corrector::RejectReason;
    use lanealign_core::params::Preset;

    /// A pose `x` metres along a straight road (planar `flu`), stamped `stamp_s`, numbered `seq`.
    fn pose(seq: u64, stamp_s: f64, x: f64) -> OdomPose {
        OdomPose {
            session: 1,
            seq,
            stamp_ns: (stamp_s * 1e9) as i64,
            sent_mono_ns: 0,
            pose: Pose3::planar(x, 0.0, 0.0, 0.0).to_row_major(),
            flags: 0,
            reserved: 0,
        }
    }

    fn rejected() -> Status {
        Status::Rejected {
            reason: RejectReason::TooFewMatches,
            residual_m: f64::INFINITY,
            match_ratio: 0.0,
            window_len: 150,
        }
    }

    /// None of 100 alignments accepted, each followed by a pose that tries none (the count of
    /// attempts stays at 100 over two poses): told once, raised from then on; told of no session
    /// that accepts one in ten.
    #[test]
    fn refusals_are_told_once_by_the_alignment_that_makes_the_count() {
        let params = Preset::KissIcp.robust_params();
        let mut watch = SessionWatch::new(&params, AxisConvention::Flu);
        let mut told = Vec::new();
        for i in 0..400u64 {
            let status = match i % 2 {
                0 => rejected(),
                _ => Status::Carried { window_len: 150 },
            };
            let news = watch.observe(&pose(i + 1, 0.1 * i as f64, i as f64), &status, false);
            if !news.warnings.is_empty() {
                told.push((i, news.warnings));
            }
        }
        assert_eq!(told.len(), 1, "{told:?}");
        assert_eq!(told[0].0, 198, "the 100th attempt");
        assert!(told[0].1[0].contains("no correction was accepted in 100 attempts"));
        assert_eq!(watch.raised(), Warning::Refusals.bit());
        assert_eq!(watch.finish(), SessionNews::default());
    }

    /// A session of 30 poses at 2 Hz whose source is set for 10 Hz ends before its stamps could
    /// tell the rate: told where it ends, with the rate its stamps say, and raised.
    #[test]
    fn a_short_session_is_told_its_rate_where_it_ends() {
        let params = Preset::KissIcp.robust_params();
        let mut watch = SessionWatch::new(&params, AxisConvention::Flu);
        for i in 0..30u64 {
            let news = watch.observe(
                &pose(i + 1, 0.5 * i as f64, 5.0 * i as f64),
                &rejected(),
                false,
            );
            assert_eq!(news, SessionNews::default(), "pose {i}");
        }
        let end = watch.finish();
        assert_eq!(end.warnings.len(), 2, "{end:?}");
        assert!(end.warnings[0].contains("about 2.0 Hz"), "{end:?}");
        assert!(
            end.warnings[1].contains("no correction was accepted"),
            "{end:?}"
        );
        assert_eq!(
            watch.raised(),
            Warning::Rate.bit() | Warning::Refusals.bit()
        );
    }

    /// A step the corrector took for poses missing raises its own bit, and a jump its own: a
    /// client that reads the answers knows that a pose may have been a glitch straight ahead
    /// (before 2026-12-02 only the daemon's log and the widened covariance said so). Neither is
    /// a warning in words: the worker's log tells those steps, rate-limited.
    #[test]
    fn a_step_over_poses_missing_raises_its_bit_and_a_jump_its_own() {
        let params = Preset::KissIcp.robust_params();
        let carried = Status::Carried { window_len: 150 };
        let mut watch = SessionWatch::new(&params, AxisConvention::Flu);
        for i in 0..20u64 {
            let news = watch.observe(&pose(i + 1, 0.1 * i as f64, i as f64), &carried, i == 12);
            assert_eq!(news, SessionNews::default(), "pose {i}");
            let expected = if i < 12 {
                0
            } else {
                Warning::PosesMissing.bit()
            };
            assert_eq!(watch.raised(), expected, "pose {i}");
        }
        let jump = Status::OdometryJump { window_len: 150 };
        watch.observe(&pose(21, 2.0, 20.0), &jump, false);
        assert_eq!(
            watch.raised(),
            Warning::PosesMissing.bit() | Warning::Jumped.bit()
        );
        let mut watch = SessionWatch::new(&params, AxisConvention::Flu);
        watch.observe(&pose(1, 0.0, 0.0), &jump, false);
        assert_eq!(watch.raised(), Warning::Jumped.bit());
    }
}
