//! The payloads on the wire.
//!
//! Both are `#[repr(C)]`, fixed size and free of pointers, so that any language can read and
//! write them in shared memory. Little-endian, natural alignment, no padding (every field is 8
//! bytes, or a pair of 4-byte fields). Times are nanoseconds: `*_mono_ns` on `CLOCK_MONOTONIC`
//! (shared by all processes of the machine), `stamp_ns` whatever the sensor uses. The layout is
//! pinned by this module's tests and documented in `docs/wire.md`.

use iceoryx2::prelude::ZeroCopySend;

/// The most poses a client keeps in flight (published, not yet answered) per session, counted as
/// the span of sequence numbers from its oldest unanswered pose: every buffer on the way holds
/// more, so nothing is overwritten, and the daemon keeps this many answers to send again.
pub const MAX_IN_FLIGHT: u64 = 512;

/// [`OdomPose::flags`]: start this session afresh at this pose (a new corrector), whatever the
/// daemon remembers of it. A client sets it when the daemon asks for poses it no longer has.
pub const FLAG_FRESH_START: u32 = 1;

/// [`OdomPose::flags`]: the session is over. Not a pose (the client sends its next sequence
/// number and a NaN pose, so that a daemon that does not know the flag flags it as invalid
/// input and corrects nothing with it): the daemon ends the session at once (its corrector, the
/// answers it keeps to send again, its journal) and answers nothing. A goodbye for a session the
/// daemon does not run changes nothing.
pub const FLAG_END_SESSION: u32 = 2;

/// A pose from an odometry source.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("lanealign::OdomPose")]
#[repr(C)]
pub struct OdomPose {
    /// The session the client chose (any value but 0): the daemon keeps one corrector per
    /// session and source, and answers on the session's own service.
    pub session: u64,
    /// 1, 2, 3, ... within a session. The daemon uses the next one; a number it already used,
    /// with the same pose, gets the same answer again; a different pose under a used number is
    /// flagged; a number beyond the next is answered with [`StatusCode::Gap`].
    pub seq: u64,
    /// The sensor time stamp (nanoseconds), echoed back.
    pub stamp_ns: i64,
    /// `CLOCK_MONOTONIC` when the client published (nanoseconds), echoed back.
    pub sent_mono_ns: u64,
    /// Row-major 3x4 pose `[R | t]` (`world_from_body`) in the source's axis convention
    /// (metres).
    pub pose: [f64; 12],
    /// [`FLAG_FRESH_START`], [`FLAG_END_SESSION`] or 0.
    pub flags: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

/// What the daemon did with a pose. Codes 0-4 and 9 are the corrector's statuses, with the same
/// names; the rest are the daemon's own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum StatusCode {
    /// Window still too short or too short a path: no matching yet.
    WarmingUp = 0,
    /// A correction was computed and applied.
    Accepted = 1,
    /// Matching ran, the correction was refused (see the reason).
    Rejected = 2,
    /// Too many failures: the window was cut back.
    Reset = 3,
    /// The pose was not finite: not used, state unchanged.
    InvalidInput = 4,
    /// The sequence number was already seen in this session: not used, state unchanged.
    DuplicateSeq = 5,
    /// The sequence number is older than one already seen in this session: not used, state
    /// unchanged.
    OutOfOrderSeq = 6,
    /// The source is configured as pass-through: echoed without correction.
    PassThrough = 7,
    /// The sequence number is beyond the next one the session expects: not used; send again
    /// from [`CorrectedPose::expected_seq`] on.
    Gap = 8,
    /// Answered with the correction in force, no alignment ran: the pose came between window
    /// poses of a source faster than its corrector's rate (`odometry_rate_hz`), or the vehicle
    /// stood still (`standstill_speed_mps`), or it came less than `alignment_spacing_m` of road
    /// after the last accepted alignment (the robust method's 1 m).
    Carried = 9,
    /// The odometry jumped (it moved farther than the vehicle can between two poses,
    /// `max_speed_mps`: a restart at its origin, a relocalisation): answered
    /// with the correction in force where the last motion leads; the poses after it continue from
    /// there, and `map_from_odom` carries the odometry's new frame.
    OdometryJump = 10,
}

impl StatusCode {
    /// Every code, in numeric order.
    pub const ALL: [StatusCode; 11] = [
        StatusCode::WarmingUp,
        StatusCode::Accepted,
        StatusCode::Rejected,
        StatusCode::Reset,
        StatusCode::InvalidInput,
        StatusCode::DuplicateSeq,
        StatusCode::OutOfOrderSeq,
        StatusCode::PassThrough,
        StatusCode::Gap,
        StatusCode::Carried,
        StatusCode::OdometryJump,
    ];

    /// Decodes a status code; `None` for a code this build does not know.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.get(code as usize).copied()
    }

    /// Lowercase name (the corrector's status names for its codes).
    pub fn name(self) -> &'static str {
        match self {
            StatusCode::WarmingUp => "warming_up",
            StatusCode::Accepted => "accepted",
            StatusCode::Rejected => "rejected",
            StatusCode::Reset => "reset",
            StatusCode::InvalidInput => "invalid_input",
            StatusCode::DuplicateSeq => "duplicate_seq",
            StatusCode::OutOfOrderSeq => "out_of_order_seq",
            StatusCode::PassThrough => "pass_through",
            StatusCode::Gap => "gap",
            StatusCode::Carried => "carried",
            StatusCode::OdometryJump => "odometry_jump",
        }
    }

    /// True for inputs the daemon refused to use (invalid, duplicate or out of order).
    pub fn is_flagged(self) -> bool {
        matches!(
            self,
            StatusCode::InvalidInput | StatusCode::DuplicateSeq | StatusCode::OutOfOrderSeq
        )
    }
}

/// Why a matching attempt failed (rejected and reset steps), or why a source that corrects
/// answered a pose uncorrected (`pass_through`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum ReasonCode {
    /// Not a failed attempt.
    None = 0,
    /// Too few window poses found a lane.
    TooFewMatches = 1,
    /// The ICP residual was too large.
    ResidualTooLarge = 2,
    /// With `pass_through`: the source's `max_sessions` sessions were all in use (each had a
    /// pose lately), so this session has no corrector yet; its poses come back uncorrected until
    /// one of them ends or goes quiet.
    SessionsFull = 3,
}

impl ReasonCode {
    /// Decodes a reason code.
    pub fn from_code(code: u32) -> Option<Self> {
        [
            ReasonCode::None,
            ReasonCode::TooFewMatches,
            ReasonCode::ResidualTooLarge,
            ReasonCode::SessionsFull,
        ]
        .get(code as usize)
        .copied()
    }

    /// Lowercase name (the corrector's reject reason names), empty for `None`.
    pub fn name(self) -> &'static str {
        match self {
            ReasonCode::None => "",
            ReasonCode::TooFewMatches => "too_few_matches",
            ReasonCode::ResidualTooLarge => "residual_too_large",
            ReasonCode::SessionsFull => "sessions_full",
        }
    }
}

/// What a session's poses have told of its setup or its odometry ([`CorrectedPose::warnings`]):
/// each is a bit, raised for the rest of the session once told. The daemon's log says each once,
/// in words (docs/operations.md, "Warnings").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u64)]
pub enum Warning {
    /// The poses move or stand as no vehicle does in the source's axis convention (another
    /// `frame`, or rotations made from quaternions read in another order).
    Axes = 1 << 0,
    /// The stamps say a rate far from the source's `odometry_rate_hz`.
    Rate = 1 << 1,
    /// The poses move faster than any vehicle (`max_speed_mps`): positions in other units than
    /// metres, or poses that come slower than the rate.
    Pace = 1 << 2,
    /// Fewer than 10 % of the session's first 100 alignments were accepted: a wrong anchor or
    /// frame, or a tile that misses the drive.
    Refusals = 1 << 3,
    /// The odometry's speed changed faster than a car's can: it lost track, and the poses after
    /// it may be off along the road.
    LostTrack = 1 << 4,
    /// The odometry jumped (an answer's status was `odometry_jump`).
    Jumped = 1 << 5,
    /// A step of the odometry was longer than the vehicle drives in one period, without stamps
    /// that time it: the corrector took it for poses missing from the input and drove on, and
    /// published that pose's covariance widened by the distance beyond one usual step (a pose
    /// that glitched straight ahead reads the same). Stamps would tell the two apart.
    PosesMissing = 1 << 6,
}

impl Warning {
    /// Every warning, by bit.
    pub const ALL: [Warning; 7] = [
        Warning::Axes,
        Warning::Rate,
        Warning::Pace,
        Warning::Refusals,
        Warning::LostTrack,
        Warning::Jumped,
        Warning::PosesMissing,
    ];

    /// Its bit in [`CorrectedPose::warnings`].
    pub fn bit(self) -> u64 {
        self as u64
    }

    /// Lowercase name.
    pub fn name(self) -> &'static str {
        match self {
            Warning::Axes => "axes",
            Warning::Rate => "rate",
            Warning::Pace => "pace",
            Warning::Refusals => "refusals",
            Warning::LostTrack => "lost_track",
            Warning::Jumped => "jumped",
            Warning::PosesMissing => "poses_missing",
        }
    }

    /// What it says of the session, in a few words, and what to check.
    pub fn meaning(self) -> &'static str {
        match self {
            Warning::Axes => {
                "its poses move or stand as no vehicle does in the source's axis convention: \
                 check the source's frame and the order its quaternions are read in"
            }
            Warning::Rate => "its stamps say a rate far from the source's odometry_rate_hz",
            Warning::Pace => {
                "its poses move faster than any vehicle: are its positions in metres, and does \
                 it come at the source's odometry_rate_hz?"
            }
            Warning::Refusals => {
                "few of its alignments were accepted: check the source's anchor and frame and \
                 that the tile covers the drive"
            }
            Warning::LostTrack => {
                "its odometry's speed changed faster than a car's can: it lost track, and the \
                 poses after it may be off along the road"
            }
            Warning::Jumped => "its odometry jumped (status odometry_jump)",
            Warning::PosesMissing => {
                "a step of its odometry was longer than the vehicle drives in one period and was \
                 taken for poses missing from the input (a pose that glitched straight ahead \
                 reads the same): send the poses' stamps"
            }
        }
    }

    /// The warnings whose bits `bits` raises, in bit order (bits this build does not know are
    /// left out).
    pub fn raised(bits: u64) -> impl Iterator<Item = Warning> {
        Self::ALL.into_iter().filter(move |w| bits & w.bit() != 0)
    }
}

/// A corrected pose, with everything needed to use, audit and time it.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("lanealign::CorrectedPose")]
#[repr(C)]
pub struct CorrectedPose {
    /// The daemon's run: a random number drawn when it started (a client sees a restart as a
    /// new value).
    pub daemon_epoch: u64,
    /// The sequence number the session expects next (after this answer).
    pub expected_seq: u64,
    /// The input's session.
    pub session: u64,
    /// The input's sequence number.
    pub seq: u64,
    /// The input's sensor stamp.
    pub stamp_ns: i64,
    /// When the client published the input (`CLOCK_MONOTONIC`, ns).
    pub sent_mono_ns: u64,
    /// When the daemon received it (`CLOCK_MONOTONIC`, ns).
    pub received_mono_ns: u64,
    /// When the daemon published this (`CLOCK_MONOTONIC`, ns).
    pub published_mono_ns: u64,
    /// The corrected pose, row-major 3x4, in the source's frame and axis convention (metres).
    /// For flagged inputs (invalid, duplicate, out of order) the input pose unchanged.
    pub pose: [f64; 12],
    /// `map_from_odom` as x (m), y (m), yaw (rad): maps planar odometry coordinates onto the
    /// lane map's plane. NaN for flagged and pass-through inputs.
    pub map_from_odom: [f64; 3],
    /// Mean ICP residual of the step (metres); NaN when no matching ran, infinite when too few
    /// poses matched.
    pub residual_m: f64,
    /// Matched fraction of the window; NaN when no matching ran.
    pub match_ratio: f64,
    /// Poses in the window after the step.
    pub window_len: u32,
    /// [`StatusCode`].
    pub status: u32,
    /// [`ReasonCode`].
    pub reason: u32,
    /// On accepted steps, how many of the correction's three directions (two of position, one of
    /// heading) the map's evidence supported and were applied; otherwise 0.
    pub applied_directions: u32,
    /// The covariance of the corrected pose's error in the lane map's plane, upper triangle:
    /// `xx, xy, x_yaw, yy, y_yaw, yaw_yaw` (metres^2, metre-radians, radians^2). NaN for flagged,
    /// gap and pass-through answers.
    pub covariance: [f64; 6],
    /// The rotation of the source's anchor (radians): the planar odometry frame turned into the
    /// map plane before any correction (turns an error in the odometry frame into the map plane).
    /// NaN for flagged, gap and pass-through answers.
    pub anchor_yaw: f64,
    /// What the session multiplies the odometry's steps by after this pose: its estimate of the
    /// odometry's scale (a ratio; 1 where the source does not estimate it). NaN where
    /// `covariance` is.
    pub odometry_scale: f64,
    /// The standard deviation of `odometry_scale` (a ratio; 0 where the source does not estimate
    /// the scale). NaN where `covariance` is.
    pub odometry_scale_sd: f64,
    /// The [`Warning`]s the session's poses have raised before this one (bits; 0 for a source
    /// that passes its poses through, or a session that has none).
    pub warnings: u64,
}

impl OdomPose {
    /// The sensor stamp in seconds.
    pub fn stamp_s(&self) -> f64 {
        self.stamp_ns as f64 * 1e-9
    }
}

impl CorrectedPose {
    /// The status, if this build knows its code.
    pub fn status(&self) -> Option<StatusCode> {
        StatusCode::from_code(self.status)
    }

    /// The warnings the session had raised before this pose ([`CorrectedPose::warnings`]).
    pub fn warnings(&self) -> impl Iterator<Item = Warning> {
        Warning::raised(self.warnings)
    }
}

/// The upper triangle of a symmetric 3x3 covariance over (x, y, yaw) (metres^2, metre-radians,
/// radians^2), in the order of [`CorrectedPose::covariance`]: `xx, xy, x_yaw, yy, y_yaw,
/// yaw_yaw`.
pub fn upper_triangle(covariance: &[[f64; 3]; 3]) -> [f64; 6] {
    let c = covariance;
    [c[0][0], c[0][1], c[0][2], c[1][1], c[1][2], c[2][2]]
}

/// The symmetric 3x3 covariance over (x, y, yaw) whose [`upper_triangle`] is `upper`.
pub fn from_upper_triangle(upper: &[f64; 6]) -> [[f64; 3]; 3] {
    let [xx, xy, xt, yy, yt, tt] = *upper;
    [[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{align_of, offset_of, size_of};

    /// The layout documented in docs/wire.md, which C++ and Python clients rely on. A change here
    /// is a new wire: [`crate::service::WIRE_VERSION`] grows with it, so that clients and daemons
    /// of different layouts name each other instead of exchanging nothing.
    #[test]
    fn layout_is_the_documented_contract() {
        assert_eq!(
            crate::service::WIRE_VERSION,
            4,
            "the version of this layout and meaning"
        );
        assert_eq!((size_of::<OdomPose>(), align_of::<OdomPose>()), (136, 8));
        assert_eq!(offset_of!(OdomPose, seq), 8);
        assert_eq!(offset_of!(OdomPose, pose), 32);
        assert_eq!(offset_of!(OdomPose, flags), 128);
        assert_eq!(
            (size_of::<CorrectedPose>(), align_of::<CorrectedPose>()),
            (296, 8)
        );
        assert_eq!(offset_of!(CorrectedPose, expected_seq), 8);
        assert_eq!(offset_of!(CorrectedPose, session), 16);
        assert_eq!(offset_of!(CorrectedPose, published_mono_ns), 56);
        assert_eq!(offset_of!(CorrectedPose, pose), 64);
        assert_eq!(offset_of!(CorrectedPose, map_from_odom), 160);
        assert_eq!(offset_of!(CorrectedPose, residual_m), 184);
        assert_eq!(offset_of!(CorrectedPose, match_ratio), 192);
        assert_eq!(offset_of!(CorrectedPose, window_len), 200);
        assert_eq!(offset_of!(CorrectedPose, status), 204);
        assert_eq!(offset_of!(CorrectedPose, reason), 208);
        assert_eq!(offset_of!(CorrectedPose, applied_directions), 212);
        assert_eq!(offset_of!(CorrectedPose, covariance), 216);
        assert_eq!(offset_of!(CorrectedPose, anchor_yaw), 264);
        assert_eq!(offset_of!(CorrectedPose, odometry_scale), 272);
        assert_eq!(offset_of!(CorrectedPose, odometry_scale_sd), 280);
        assert_eq!(offset_of!(CorrectedPose, warnings), 288);
    }

    #[test]
    fn codes_decode_to_themselves() {
        for s in StatusCode::ALL {
            assert_eq!(StatusCode::from_code(s as u32), Some(s));
        }
        assert_eq!(StatusCode::from_code(11), None);
        assert_eq!(ReasonCode::from_code(2), Some(ReasonCode::ResidualTooLarge));
        assert_eq!(ReasonCode::from_code(3), Some(ReasonCode::SessionsFull));
        assert_eq!(ReasonCode::from_code(4), None);
        for (i, w) in Warning::ALL.into_iter().enumerate() {
            assert_eq!(w.bit(), 1 << i, "{}", w.name());
        }
        let raised: Vec<Warning> = Warning::raised(u64::MAX).collect();
        assert_eq!(raised, Warning::ALL);
        let raised: Vec<Warning> = Warning::raised(0b10_0100 | 1 << 40).collect();
        assert_eq!(raised, [Warning::Pace, Warning::Jumped]);
    }

    /// The order docs/wire.md documents, and back to the same symmetric matrix.
    #[test]
    fn the_covariance_travels_as_its_upper_triangle() {
        let covariance = [[0.5, 0.1, 1e-3], [0.1, 0.7, -2e-3], [1e-3, -2e-3, 1e-4]];
        let upper = upper_triangle(&covariance);
        assert_eq!(upper, [0.5, 0.1, 1e-3, 0.7, -2e-3, 1e-4]);
        assert_eq!(from_upper_triangle(&upper), covariance);
    }
}
