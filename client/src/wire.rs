//! The payloads on the wire: the contract between odometry processes and `lanealignd`.
//!
//! Both are `#[repr(C)]`, fixed size and free of pointers, so that any language can read and
//! write them in shared memory. Little-endian, natural alignment (every field is 8 bytes, or 4
//! followed by 4), no padding inside except where noted. Times are nanoseconds: `*_mono_ns` on
//! `CLOCK_MONOTONIC` (shared by all processes of the machine), `stamp_ns` whatever the sensor uses.
//!
//! Services per source `NAME`: `lanealign/NAME/odom` (publish-subscribe of [`OdomPose`], client to
//! daemon) and `lanealign/NAME/corrected` ([`CorrectedPose`], daemon to any subscriber), each with
//! an event service of the same name that is notified after every sample.

use iceoryx2::prelude::ZeroCopySend;
use lanealign_core::pose::Pose3;

/// A 3x4 pose as the wire's row-major `[f64; 12]`.
pub fn pose_to_wire(p: &Pose3) -> [f64; 12] {
    let mut out = [0.0; 12];
    for (i, row) in p.iter().enumerate() {
        out[i * 4..i * 4 + 4].copy_from_slice(row);
    }
    out
}

/// The wire's row-major `[f64; 12]` as a 3x4 pose.
pub fn pose_from_wire(v: &[f64; 12]) -> Pose3 {
    [
        [v[0], v[1], v[2], v[3]],
        [v[4], v[5], v[6], v[7]],
        [v[8], v[9], v[10], v[11]],
    ]
}

/// A pose from an odometry source.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("lanealign::OdomPose")]
#[repr(C)]
pub struct OdomPose {
    /// Strictly increasing per source; duplicates and older numbers are flagged, not used.
    pub seq: u64,
    /// The sensor time stamp (nanoseconds), echoed back.
    pub stamp_ns: i64,
    /// `CLOCK_MONOTONIC` when the client published (nanoseconds), echoed back.
    pub sent_mono_ns: u64,
    /// Row-major 3x4 pose `[R | t]` in the source's axis convention (metres).
    pub pose: [f64; 12],
}

/// What the daemon did with a pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum WireStatus {
    /// Window still too short or too short a path: no matching yet.
    WarmingUp = 0,
    /// A correction was computed and applied.
    Accepted = 1,
    /// Matching ran, the correction was refused (see `reason`).
    Rejected = 2,
    /// Too many failures: the window was cut back.
    Reset = 3,
    /// The pose was not finite: not used, state unchanged.
    InvalidInput = 4,
    /// The sequence number was already seen: not used, state unchanged.
    DuplicateSeq = 5,
    /// The sequence number is older than one already seen: not used, state unchanged.
    OutOfOrderSeq = 6,
    /// The source is configured as pass-through: echoed without correction.
    PassThrough = 7,
}

impl WireStatus {
    /// Decodes a status code.
    pub fn from_code(code: u32) -> Option<Self> {
        use WireStatus::*;
        [
            WarmingUp,
            Accepted,
            Rejected,
            Reset,
            InvalidInput,
            DuplicateSeq,
            OutOfOrderSeq,
            PassThrough,
        ]
        .into_iter()
        .find(|s| *s as u32 == code)
    }

    /// Lowercase name.
    pub fn name(self) -> &'static str {
        match self {
            WireStatus::WarmingUp => "warming_up",
            WireStatus::Accepted => "accepted",
            WireStatus::Rejected => "rejected",
            WireStatus::Reset => "reset",
            WireStatus::InvalidInput => "invalid_input",
            WireStatus::DuplicateSeq => "duplicate_seq",
            WireStatus::OutOfOrderSeq => "out_of_order_seq",
            WireStatus::PassThrough => "pass_through",
        }
    }
}

/// A corrected pose, with everything needed to use, audit and time it.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("lanealign::CorrectedPose")]
#[repr(C)]
pub struct CorrectedPose {
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
    /// lane map's plane.
    pub map_from_odom: [f64; 3],
    /// Mean ICP residual of the step (metres); NaN when no matching ran, infinite when too few
    /// poses matched.
    pub residual_m: f64,
    /// Matched fraction of the window; NaN when no matching ran.
    pub match_ratio: f64,
    /// Poses in the window after the step.
    pub window_len: u32,
    /// [`WireStatus`] code.
    pub status: u32,
    /// For rejected and reset steps: 1 too few matches, 2 residual too large; else 0.
    pub reason: u32,
    /// Reserved, zero (keeps the struct a multiple of 8 bytes).
    pub reserved: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{align_of, offset_of, size_of};

    /// The layout documented in docs/wire.md, which C++ and Python clients rely on.
    #[test]
    fn layout_is_the_documented_contract() {
        assert_eq!((size_of::<OdomPose>(), align_of::<OdomPose>()), (120, 8));
        assert_eq!(offset_of!(OdomPose, pose), 24);
        assert_eq!(
            (size_of::<CorrectedPose>(), align_of::<CorrectedPose>()),
            (192, 8)
        );
        assert_eq!(offset_of!(CorrectedPose, published_mono_ns), 32);
        assert_eq!(offset_of!(CorrectedPose, pose), 40);
        assert_eq!(offset_of!(CorrectedPose, map_from_odom), 136);
        assert_eq!(offset_of!(CorrectedPose, residual_m), 160);
        assert_eq!(offset_of!(CorrectedPose, match_ratio), 168);
        assert_eq!(offset_of!(CorrectedPose, window_len), 176);
        assert_eq!(offset_of!(CorrectedPose, status), 180);
        assert_eq!(offset_of!(CorrectedPose, reason), 184);
        assert_eq!(WireStatus::from_code(6), Some(WireStatus::OutOfOrderSeq));
        assert_eq!(WireStatus::from_code(8), None);
    }
}
