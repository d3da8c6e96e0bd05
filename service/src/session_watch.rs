//! What a session's poses have told so far, for the daemon's warnings: the source's rate, axes,
//! pace and speed ([`SourceWatch`]), and its alignments (to warn when none is accepted).
//!
//! It is part of a session's state like its corrector: a snapshot in the journal holds it, and
//! restoring replays the records after the snapshot through it, so that a session restored
//! after the daemon was killed warns as if the daemon had run on: a change of speed under way
//! at the kill is told once it ends, and what was told before is not told again.

use lanealign_core::corrector::Status;
use lanealign_core::plausibility::{SourceNews, SourceWatch, SourceWatchState, SpeedChange};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::Counts;
use lanealign_wire::payload::OdomPose;

/// What a session's corrected poses have told so far.
#[derive(Clone, Debug)]
pub struct SessionWatch {
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
}

impl SessionWatch {
    /// A watch for a new session of a source whose corrector is set for `set_rate_hz` and
    /// `max_speed_mps` and whose poses come in `convention`.
    pub fn new(set_rate_hz: f64, max_speed_mps: f64, convention: AxisConvention) -> Self {
        SessionWatch {
            source: SourceWatch::new(set_rate_hz, max_speed_mps, convention),
            watched_seq: 0,
            alignments: Counts::default(),
            corrected_poses: 0,
        }
    }

    /// A watch for the same source that continues from `state`, exactly as the one it was
    /// saved from would.
    pub fn restore(
        set_rate_hz: f64,
        max_speed_mps: f64,
        convention: AxisConvention,
        state: SessionWatchState,
    ) -> Self {
        SessionWatch {
            source: SourceWatch::restore(set_rate_hz, max_speed_mps, convention, state.source),
            watched_seq: state.watched_seq,
            alignments: state.alignments,
            corrected_poses: state.corrected_poses,
        }
    }

    /// What the watch has seen (see [`SessionWatch::restore`]).
    pub fn state(&self) -> SessionWatchState {
        SessionWatchState {
            source: self.source.state(),
            watched_seq: self.watched_seq,
            alignments: self.alignments,
            corrected_poses: self.corrected_poses,
        }
    }

    /// Takes a pose the session answered with a correction (`status`, any but invalid input);
    /// returns what its source watch told with it.
    pub fn observe(&mut self, input: &OdomPose, status: &Status) -> SourceNews {
        let news = self
            .source
            .observe(input.stamp_s(), &Pose3::from_row_major(&input.pose));
        self.watched_seq = input.seq;
        self.alignments.add(status);
        self.corrected_poses = self.corrected_poses.saturating_add(1);
        news
    }

    /// What the source watch tells where the session ends (see [`SourceWatch::finish`]).
    pub fn finish(&mut self) -> SourceNews {
        self.source.finish()
    }

    /// The sequence number of the pose where `change` (told by this watch) lies.
    pub fn seq_of(&self, change: &SpeedChange) -> u64 {
        self.watched_seq
            .saturating_sub(self.source.poses_since(change) as u64)
    }

    /// The rate (Hz) the speed is judged at, once the stamps have told it.
    pub fn speed_rate_hz(&self) -> Option<f64> {
        self.source.speed_rate_hz()
    }

    /// The session's alignments so far.
    pub fn alignments(&self) -> Counts {
        self.alignments
    }

    /// The poses answered with a correction so far.
    pub fn corrected_poses(&self) -> usize {
        self.corrected_poses
    }
}
