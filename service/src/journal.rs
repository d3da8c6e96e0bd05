//! A session's journal on disk: what lets a killed daemon come back with every session exactly
//! where it was.
//!
//! Per session, a folder `<state_dir>/<namespace>/<source>/<session>-<nonce>/` (a new nonce for
//! every journal, so an ended session's folder, removed in the background, is never reused)
//! holds:
//!
//! - `session`: who the session is, when its journal began, and what it was corrected with (a
//!   fingerprint of the source's configuration and the tile): a journal written under another
//!   configuration is not restored.
//! - `NNNNNNNN.log`: segments of [`SEGMENT_RECORDS`] records, one per pose the session used:
//!   the input and the answer, checksummed. A segment's file is allocated whole when it is
//!   created (zeros after its last record) and mapped into the worker's memory; the worker
//!   copies a record into it before it publishes the answer, so every answer a client can have
//!   seen is in the journal, even if the daemon is killed the next instant (the mapped pages are
//!   the kernel's page cache; a torn last record fails its checksum and was never answered).
//!   A copy costs a fraction of a microsecond where a `write` costs 10 us on a core that idled
//!   between poses; the page a record will go to is faulted in ahead
//!   ([`SegmentWriter::prefault_next`]), between poses.
//! - `NNNNNNNN.copy`: the same records, copied from the segment and synced to disk every second
//!   by the persistence thread ([`SegmentCopier`]), for a power loss. The mapped segment itself
//!   is never synced: a sync write-protects the pages it writes out, and the worker's next copy
//!   into the page it is filling would take that fault (and wait for the page's write-out) on
//!   the latency path, once a second (at 100 Hz 1 % of the poses, 9-15 us each on this project's
//!   machine, docs/performance.md). Restoring takes, per segment, the longer valid run of records
//!   of the two ([`recover_segment`]).
//! - `snapshot`: the corrector's exact state after the last full segment, written (atomically,
//!   by the persistence thread) each time a segment fills. Older segments are then deleted, but
//!   the last full one stays: with the open one it holds at least [`MAX_IN_FLIGHT`] answers to
//!   send again.
//!
//! Restoring loads the snapshot and replays the records after it through the corrector, checking
//! that every answer it computes again equals the one logged.

use std::fs::File;
use std::io::{Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use memmap2::MmapMut;

use lanealign_core::confidence::{is_covariance, is_joint_covariance};
use lanealign_core::continuity::{BeforeGlitch, Continuity};
use lanealign_core::corrector::CorrectorState;
use lanealign_core::params::{MAX_ODOMETRY_RATE_HZ, MIN_ODOMETRY_RATE_HZ};
use lanealign_core::plausibility::{
    AxisMotion, Pace, SourceWatchState, SpeedChange, SpeedHistory, PACE_STEPS,
};
use lanealign_core::pose::{AxisConvention, Pose3, MAX_COORDINATE_M};
use lanealign_core::scale::{ScaleEstimate, ScaledOdometry};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{Counts, SourceState};
use lanealign_core::stall::{Stall, StallState};
use lanealign_wire::payload::{CorrectedPose, OdomPose, MAX_IN_FLIGHT};
use xxhash_rust::xxh3::xxh3_64;

use crate::session_watch::SessionWatchState;

/// Records per segment: the last full segment alone holds [`MAX_IN_FLIGHT`] answers.
pub const SEGMENT_RECORDS: u64 = MAX_IN_FLIGHT;
/// Bytes of one record: input (136), answer (296), checksum (8).
pub const RECORD_LEN: usize = ODOM_LEN + ANSWER_LEN + 8;
const ODOM_LEN: usize = 136;
const ANSWER_LEN: usize = 296;
const SESSION_MAGIC: &[u8; 8] = b"LASESS03";
/// Journals whose answers were 288 bytes, before they carried the session's warnings: their
/// records cannot be appended to, so their sessions are not restored (they start afresh).
const SESSION_MAGIC_V2: &[u8; 8] = b"LASESS02";
/// Journals whose answers were 272 bytes, before they carried the odometry's scale: their
/// records cannot be appended to, so their sessions are not restored (they start afresh).
const SESSION_MAGIC_V1: &[u8; 8] = b"LASESS01";
const SNAPSHOT_MAGIC: &[u8; 8] = b"LASNAP12";
/// Snapshots before a glitch of the odometry (one pose off its drive) was told from a jump
/// (read with no pose before one: the pose after a snapshot taken between a glitch and the
/// pose after it is judged against the glitch, as before).
const SNAPSHOT_MAGIC_V11: &[u8; 8] = b"LASNAP11";
/// Snapshots before the session's watch judged the odometry's pace and kept the warnings it
/// raised (read with none gathered so far and none raised: a session restored from one judges
/// its pace on the steps after the restore, and raises what is told after it).
const SNAPSHOT_MAGIC_V10: &[u8; 8] = b"LASNAP10";
/// Snapshots before the session's watch followed how far the poses drove tilted (read with
/// none so far: a session restored while its first 300 m are followed judges its tilt on the
/// path after the restore only).
const SNAPSHOT_MAGIC_V9: &[u8; 8] = b"LASNAP09";
/// Snapshots before the session's watch for the daemon's warnings was kept (read with none: it
/// starts afresh after the replay, as it then did).
const SNAPSHOT_MAGIC_V8: &[u8; 8] = b"LASNAP08";
/// Snapshots before stalls of the odometry widened the covariance (read with the watch for them
/// starting afresh where the session's parameters have one).
const SNAPSHOT_MAGIC_V7: &[u8; 8] = b"LASNAP07";
/// Snapshots before the odometry's scale was estimated (read with the estimate at its start
/// when the session's parameters estimate it).
const SNAPSHOT_MAGIC_V6: &[u8; 8] = b"LASNAP06";
/// Snapshots before jumps of the odometry were told from motion (read with none so far and no
/// last pose: the pose after the restore cannot be judged a jump).
const SNAPSHOT_MAGIC_V5: &[u8; 8] = b"LASNAP05";
/// Snapshots before the match gate widened through steps that change nothing (read with the
/// gate closed at the last accepted step, as the corrector then had it).
const SNAPSHOT_MAGIC_V4: &[u8; 8] = b"LASNAP04";
/// Snapshots before poses could be carried between window poses (read with none carried: every
/// pose of their sources entered the window).
const SNAPSHOT_MAGIC_V3: &[u8; 8] = b"LASNAP03";
/// Snapshots before the inherited map error was kept (read with none: the published covariance
/// lacks it until the session's next accepted step).
const SNAPSHOT_MAGIC_V2: &[u8; 8] = b"LASNAP02";
/// The largest window a snapshot may hold (poses): the corrector's own limit.
const MAX_WINDOW: u64 = 1_000_000;
/// The farthest a position or offset in a snapshot may lie from its frame's origin (metres): a
/// hundred times the farthest a pose may ([`MAX_COORDINATE_M`]), beyond anything a run produces,
/// and near enough that no sum or product of a few of them overflows. A snapshot past it was
/// tampered with under its checksum: restored, its arithmetic reached infinities, and accepted
/// answers of NaN (found by the `snapshot` fuzz harness).
const MAX_POSITION_M: f64 = 100.0 * MAX_COORDINATE_M;
/// The most poses, stamps or speeds a snapshot's stall watch or session watch may hold (they
/// keep 64 and 16).
const MAX_WATCH_VALUES: u64 = 1024;

/// A journal that could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    /// A file could not be created, written, read or removed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A file's content is not a valid journal file.
    #[error("{path}: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> JournalError + '_ {
    move |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Little-endian encoding into a byte vector.
#[derive(Default)]
struct Encoder(Vec<u8>);

impl Encoder {
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }
    fn f64s(&mut self, v: &[f64]) -> &mut Self {
        for x in v {
            self.f64(*x);
        }
        self
    }
    /// A point that may be absent: a flag, then the point (zeros when absent).
    fn point(&mut self, p: Option<[f64; 2]>) -> &mut Self {
        self.u32(p.is_some() as u32).f64s(&p.unwrap_or_default())
    }
    fn se2(&mut self, t: &Se2) -> &mut Self {
        let (c, s) = t.rotation();
        let [x, y] = t.translation();
        self.f64s(&[c, s, x, y])
    }
}

/// Little-endian decoding with every read checked: a short or odd file is an error, not a panic.
struct Decoder<'a>(&'a [u8]);

impl Decoder<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        if self.0.len() < n {
            return None;
        }
        let (head, rest) = self.0.split_at(n);
        self.0 = rest;
        Some(head)
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4)?.try_into().ok().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Option<u64> {
        self.take(8)?.try_into().ok().map(u64::from_le_bytes)
    }
    fn f64(&mut self) -> Option<f64> {
        self.u64().map(f64::from_bits)
    }
    fn f64s<const N: usize>(&mut self) -> Option<[f64; N]> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64()?;
        }
        Some(out)
    }
    fn se2(&mut self) -> Option<Se2> {
        let [c, s, x, y] = self.f64s::<4>()?;
        let norm = c.hypot(s);
        let finite = c.is_finite() && s.is_finite() && within_reach(&[x, y]);
        (finite && (norm - 1.0).abs() < 1e-9).then(|| Se2::from_rotation(c, s, x, y))
    }
}

fn encode_odom(e: &mut Encoder, p: &OdomPose) {
    e.u64(p.session)
        .u64(p.seq)
        .u64(p.stamp_ns as u64)
        .u64(p.sent_mono_ns)
        .f64s(&p.pose)
        .u32(p.flags)
        .u32(p.reserved);
}

fn decode_odom(d: &mut Decoder<'_>) -> Option<OdomPose> {
    Some(OdomPose {
        session: d.u64()?,
        seq: d.u64()?,
        stamp_ns: d.u64()? as i64,
        sent_mono_ns: d.u64()?,
        pose: d.f64s::<12>()?,
        flags: d.u32()?,
        reserved: d.u32()?,
    })
}

fn encode_answer(e: &mut Encoder, a: &CorrectedPose) {
    e.u64(a.daemon_epoch)
        .u64(a.expected_seq)
        .u64(a.session)
        .u64(a.seq)
        .u64(a.stamp_ns as u64)
        .u64(a.sent_mono_ns)
        .u64(a.received_mono_ns)
        .u64(a.published_mono_ns)
        .f64s(&a.pose)
        .f64s(&a.map_from_odom)
        .f64(a.residual_m)
        .f64(a.match_ratio)
        .u32(a.window_len)
        .u32(a.status)
        .u32(a.reason)
        .u32(a.applied_directions)
        .f64s(&a.covariance)
        .f64(a.anchor_yaw)
        .f64(a.odometry_scale)
        .f64(a.odometry_scale_sd)
        .u64(a.warnings);
}

fn decode_answer(d: &mut Decoder<'_>) -> Option<CorrectedPose> {
    Some(CorrectedPose {
        daemon_epoch: d.u64()?,
        expected_seq: d.u64()?,
        session: d.u64()?,
        seq: d.u64()?,
        stamp_ns: d.u64()? as i64,
        sent_mono_ns: d.u64()?,
        received_mono_ns: d.u64()?,
        published_mono_ns: d.u64()?,
        pose: d.f64s::<12>()?,
        map_from_odom: d.f64s::<3>()?,
        residual_m: d.f64()?,
        match_ratio: d.f64()?,
        window_len: d.u32()?,
        status: d.u32()?,
        reason: d.u32()?,
        applied_directions: d.u32()?,
        covariance: d.f64s::<6>()?,
        anchor_yaw: d.f64()?,
        odometry_scale: d.f64()?,
        odometry_scale_sd: d.f64()?,
        warnings: d.u64()?,
    })
}

/// One journal record: a pose the session used, and its answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// The input.
    pub input: OdomPose,
    /// The answer sent.
    pub answer: CorrectedPose,
}

impl Record {
    /// The record's bytes, checksum last.
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut e = Encoder(Vec::with_capacity(RECORD_LEN));
        self.encode_into(&mut e);
        let mut out = [0u8; RECORD_LEN];
        out.copy_from_slice(&e.0);
        out
    }

    /// Encodes the record into `e` (cleared first): a worker reuses one buffer for every pose,
    /// so that appending allocates nothing.
    fn encode_into(&self, e: &mut Encoder) {
        e.0.clear();
        encode_odom(e, &self.input);
        encode_answer(e, &self.answer);
        let sum = xxh3_64(&e.0);
        e.u64(sum);
    }

    /// A record from its bytes; `None` when the checksum or the layout is wrong.
    pub fn decode(bytes: &[u8]) -> Option<Record> {
        if bytes.len() != RECORD_LEN {
            return None;
        }
        let (body, sum) = bytes.split_at(RECORD_LEN - 8);
        if xxh3_64(body).to_le_bytes() != sum {
            return None;
        }
        let mut d = Decoder(body);
        Some(Record {
            input: decode_odom(&mut d)?,
            answer: decode_answer(&mut d)?,
        })
    }
}

/// A session's corrector state at a point of its journal.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// The last sequence number applied.
    pub last_seq: u64,
    /// The first segment whose records come after the snapshot.
    pub next_segment: u64,
    /// The source corrector's state.
    pub state: SourceState,
    /// The session's watch for the daemon's warnings; `None` in snapshots of the formats before
    /// it was kept.
    pub watch: Option<SessionWatchState>,
}

impl Snapshot {
    /// The snapshot's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let c = &self.state.corrector;
        let mut e = Encoder::default();
        e.0.extend_from_slice(SNAPSHOT_MAGIC);
        e.u64(self.last_seq)
            .u64(self.next_segment)
            .se2(&c.map_from_anchored)
            .f64(c.window_path_m)
            .u32(c.failures)
            .f64(c.travelled_m);
        for row in &c.covariance {
            e.f64s(row);
        }
        for row in &c.map_error {
            e.f64s(row);
        }
        e.u32(c.carried).f64(c.gate_travelled_m);
        e.point(c.last_position_in_anchored);
        match &self.state.smoothed {
            Some(t) => e.u32(1).se2(t),
            None => e.u32(0).se2(&Se2::IDENTITY),
        };
        let continuity = &self.state.continuity;
        e.se2(&continuity.continued_from_odom);
        match continuity.last {
            Some((pose, stamp_s)) => e.u32(1).se2(&pose).f64(stamp_s),
            None => e.u32(0).se2(&Se2::IDENTITY).f64(f64::NAN),
        };
        match continuity.last_motion {
            Some(motion) => e.u32(1).se2(&motion),
            None => e.u32(0).se2(&Se2::IDENTITY),
        };
        match c.scale {
            Some(scale) => e.u32(1).f64(scale.factor).f64(scale.variance),
            None => e.u32(0).f64(1.0).f64(0.0),
        };
        let scaled = &self.state.scaled;
        e.point(scaled.last_in_anchored);
        e.f64s(&scaled.offset);
        match &c.published_uncertainty {
            Some((covariance, cross)) => {
                e.u32(1);
                for row in covariance {
                    e.f64s(row);
                }
                e.f64s(cross)
            }
            None => e.u32(0).f64s(&[0.0; 12]),
        };
        match &self.state.stall {
            Some(stall) => encode_stall(e.u32(1), stall),
            None => {
                e.u32(0);
            }
        }
        match &self.watch {
            Some(watch) => encode_watch(e.u32(1), watch),
            None => {
                e.u32(0);
            }
        }
        match &continuity.before_glitch {
            Some(before) => {
                let (last, stamp_s) = before.last;
                e.u32(1)
                    .se2(&before.continued_from_odom)
                    .se2(&last)
                    .f64(stamp_s)
                    .se2(&before.last_motion);
            }
            None => {
                e.u32(0);
            }
        }
        e.u64(c.window.len() as u64);
        for p in &c.window {
            e.f64s(p);
        }
        e.u64(0);
        seal(&mut e.0);
        e.0
    }

    /// A snapshot from its bytes (this format or the one before); `None` for anything but a
    /// complete, valid snapshot.
    pub fn decode(bytes: &[u8]) -> Option<Snapshot> {
        let (body, sum) = bytes.split_at(bytes.len().checked_sub(8)?);
        if xxh3_64(body).to_le_bytes() != sum {
            return None;
        }
        let magic = body.get(..8)?;
        // Each format kept what the one before did and added a part.
        let version = match magic {
            m if m == SNAPSHOT_MAGIC => 12,
            m if m == SNAPSHOT_MAGIC_V11 => 11,
            m if m == SNAPSHOT_MAGIC_V10 => 10,
            m if m == SNAPSHOT_MAGIC_V9 => 9,
            m if m == SNAPSHOT_MAGIC_V8 => 8,
            m if m == SNAPSHOT_MAGIC_V7 => 7,
            m if m == SNAPSHOT_MAGIC_V6 => 6,
            m if m == SNAPSHOT_MAGIC_V5 => 5,
            m if m == SNAPSHOT_MAGIC_V4 => 4,
            m if m == SNAPSHOT_MAGIC_V3 => 3,
            m if m == SNAPSHOT_MAGIC_V2 => 2,
            _ => return None,
        };
        let has_map_error = version >= 3;
        let has_carried = version >= 4;
        let has_unanchored = version >= 5;
        let has_continuity = version >= 6;
        let has_scale = version >= 7;
        let has_stall = version >= 8;
        let has_watch = version >= 9;
        let has_tilt = version >= 10;
        let has_pace = version >= 11;
        let has_glitch = version >= 12;
        let mut d = Decoder(&body[8..]);
        let last_seq = d.u64()?;
        let next_segment = d.u64()?;
        let map_from_anchored = d.se2()?;
        let window_path_m = d.f64()?;
        let failures = d.u32()?;
        let travelled_m = d.f64()?;
        let covariance = [d.f64s::<3>()?, d.f64s::<3>()?, d.f64s::<3>()?];
        let map_error = if has_map_error {
            [d.f64s::<2>()?, d.f64s::<2>()?]
        } else {
            [[0.0; 2]; 2]
        };
        let carried = if has_carried { d.u32()? } else { 0 };
        let gate_travelled_m = if has_unanchored {
            d.f64()?
        } else {
            travelled_m
        };
        let last_position = (d.u32()?, d.f64s::<2>()?);
        let smoothed = (d.u32()?, d.se2()?);
        let flag = |f: u32| (f <= 1).then_some(f == 1);
        let mut continuity = if has_continuity {
            let continued_from_odom = d.se2()?;
            let last = (d.u32()?, d.se2()?, d.f64()?);
            Continuity {
                continued_from_odom,
                last: flag(last.0)?.then_some((last.1, last.2)),
                last_motion: {
                    let motion = (d.u32()?, d.se2()?);
                    flag(motion.0)?.then_some(motion.1)
                },
                before_glitch: None,
            }
        } else {
            Continuity::default()
        };
        let (scale, scaled, published_uncertainty) = if has_scale {
            let (flag_value, factor, variance) = (d.u32()?, d.f64()?, d.f64()?);
            let scale = flag(flag_value)?.then_some(ScaleEstimate { factor, variance });
            let last = (d.u32()?, d.f64s::<2>()?);
            let scaled = ScaledOdometry {
                last_in_anchored: flag(last.0)?.then_some(last.1),
                offset: d.f64s::<2>()?,
            };
            let published_flag = d.u32()?;
            let covariance = [d.f64s::<3>()?, d.f64s::<3>()?, d.f64s::<3>()?];
            let cross = d.f64s::<3>()?;
            let published = flag(published_flag)?.then_some((covariance, cross));
            (scale, scaled, published)
        } else {
            (None, ScaledOdometry::default(), None)
        };
        let stall = if has_stall && flag(d.u32()?)? {
            Some(decode_stall(&mut d)?)
        } else {
            None
        };
        let watch = if has_watch && flag(d.u32()?)? {
            Some(decode_watch(&mut d, has_tilt, has_pace)?)
        } else {
            None
        };
        if has_glitch && flag(d.u32()?)? {
            continuity.before_glitch = Some(BeforeGlitch {
                continued_from_odom: d.se2()?,
                last: (d.se2()?, d.f64()?),
                last_motion: d.se2()?,
            });
        }
        let n = d.u64()?;
        if n > MAX_WINDOW || d.0.len() as u64 != n * 16 {
            return None;
        }
        let window: Vec<[f64; 2]> = (0..n).map(|_| d.f64s::<2>()).collect::<Option<_>>()?;
        // Positions within reach, covariances ones a filter continues from, every other number
        // finite.
        let finite = window.iter().all(|p| within_reach(p))
            && within_reach(&last_position.1)
            && window_path_m.is_finite()
            && travelled_m.is_finite()
            && gate_travelled_m.is_finite()
            && is_covariance(&covariance)
            && is_covariance(&[
                [map_error[0][0], map_error[0][1], 0.0],
                [map_error[1][0], map_error[1][1], 0.0],
                [0.0; 3],
            ])
            && scale.is_none_or(|s| s.is_valid())
            && published_uncertainty.is_some() == scale.is_some()
            && published_uncertainty
                .is_none_or(|(c, x)| is_joint_covariance(&c, x, scale.map_or(0.0, |s| s.variance)))
            && within_reach(&scaled.offset)
            && scaled.last_in_anchored.is_none_or(|p| within_reach(&p));
        let state = SourceState {
            corrector: CorrectorState {
                map_from_anchored,
                window,
                window_path_m,
                failures,
                travelled_m,
                gate_travelled_m,
                last_position_in_anchored: flag(last_position.0)?.then_some(last_position.1),
                covariance,
                map_error,
                carried,
                scale,
                published_uncertainty,
            },
            smoothed: flag(smoothed.0)?.then_some(smoothed.1),
            continuity,
            scaled,
            stall,
        };
        finite.then_some(Snapshot {
            last_seq,
            next_segment,
            state,
            watch,
        })
    }
}

/// Writes the checksum of a snapshot's bytes (all but the last 8) into its last 8 bytes; bytes
/// shorter than that are left as they are. What [`Snapshot::encode`] ends with; a fuzz harness
/// reseals its mutants with it, so that they reach the decoding past the checksum.
pub fn seal(bytes: &mut [u8]) {
    if let Some(at) = bytes.len().checked_sub(8) {
        let sum = xxh3_64(&bytes[..at]);
        bytes[at..].copy_from_slice(&sum.to_le_bytes());
    }
}

/// Whether every value of a position, an offset, a distance or a speed is finite and within
/// [`MAX_POSITION_M`] (metres, or metres per second).
fn within_reach(values: &[f64]) -> bool {
    values
        .iter()
        .all(|v| v.is_finite() && v.abs() <= MAX_POSITION_M)
}

/// Appends a stall watch's state.
fn encode_stall(e: &mut Encoder, stall: &StallState) {
    e.u64(stall.held.len() as u64);
    for held in &stall.held {
        e.f64s(held);
    }
    encode_judged(e, &stall.judged);
    e.point(stall.last);
    match stall.open {
        Some(open) => e
            .u32(1)
            .f64(open.before_mps)
            .f64s(&open.heading)
            .f64(open.missed_m),
        None => e.u32(0).f64s(&[0.0; 4]),
    };
}

/// A stall watch's state ([`encode_stall`]); `None` unless every part is there, every number but
/// a held stamp (NaN without stamps) is finite and every position is within reach
/// ([`MAX_POSITION_M`]).
fn decode_stall(d: &mut Decoder<'_>) -> Option<StallState> {
    let flag = |f: u32| (f <= 1).then_some(f == 1);
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let held: Vec<[f64; 4]> = (0..count(d)?)
        .map(|_| {
            d.f64s::<4>()
                .filter(|h| within_reach(&[h[1], h[2]]) && h[3].is_finite())
        })
        .collect::<Option<_>>()?;
    let judged = decode_judged(d)?;
    let last = (d.u32()?, d.f64s::<2>()?);
    let open = (d.u32()?, d.f64()?, d.f64s::<2>()?, d.f64()?);
    // A stall under way: a speed and a distance missed within reach, and a unit heading.
    let heading_norm = open.2[0].hypot(open.2[1]);
    let open_valid = within_reach(&[open.1, open.3])
        && (open.0 == 0 || (open.1 >= 0.0 && open.3 >= 0.0 && (heading_norm - 1.0).abs() < 1e-9));
    (within_reach(&last.1) && finite(&open.2) && open_valid).then_some(())?;
    Some(StallState {
        held,
        judged,
        last: flag(last.0)?.then_some(last.1),
        open: flag(open.0)?.then_some(Stall {
            before_mps: open.1,
            heading: open.2,
            missed_m: open.3,
        }),
    })
}

/// Appends the rate a speed watch judges at and what it has seen, once the stamps told it.
fn encode_judged(e: &mut Encoder, judged: &Option<(f64, SpeedHistory)>) {
    match judged {
        Some((rate_hz, speed)) => {
            e.u32(1).f64(*rate_hz).u64(speed.seen as u64);
            e.point(speed.last).u64(speed.repeats as u64);
            e.u64(speed.speeds.len() as u64).f64s(&speed.speeds);
            e.u64(speed.ends.len() as u64);
            for &end in &speed.ends {
                e.u64(end as u64);
            }
            match speed.open {
                Some((change, last_as_steep)) => e
                    .u32(1)
                    .u64(change.pose as u64)
                    .f64s(&[change.from_mps, change.to_mps, change.over_s])
                    .u64(last_as_steep as u64),
                None => e.u32(0).u64(0).f64s(&[0.0; 3]).u64(0),
            };
        }
        None => {
            e.u32(0);
        }
    }
}

/// More poses than a speed watch in a snapshot may have seen: 2^62, at 1 kHz a hundred million
/// years of one session.
const MAX_POSES_SEEN: usize = 1 << 62;

/// A count of values that follow: at most [`MAX_WATCH_VALUES`].
fn count(d: &mut Decoder<'_>) -> Option<u64> {
    d.u64().filter(|&n| n <= MAX_WATCH_VALUES)
}

/// What [`encode_judged`] appended (`Some(None)`: not judged yet); `None` unless every part is
/// there, every number is finite, the rate one a corrector may be set for, and every pose it
/// names one it has seen.
fn decode_judged(d: &mut Decoder<'_>) -> Option<Option<(f64, SpeedHistory)>> {
    let flag = |f: u32| (f <= 1).then_some(f == 1);
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    if !flag(d.u32()?)? {
        return Some(None);
    }
    let (rate_hz, seen) = (d.f64()?, usize::try_from(d.u64()?).ok()?);
    let last = (d.u32()?, d.f64s::<2>()?);
    let repeats = usize::try_from(d.u64()?).ok()?;
    let speeds: Vec<f64> = (0..count(d)?).map(|_| d.f64()).collect::<Option<_>>()?;
    let ends: Vec<usize> = (0..count(d)?)
        .map(|_| d.u64().and_then(|v| usize::try_from(v).ok()))
        .collect::<Option<_>>()?;
    let change = (d.u32()?, d.u64()?, d.f64s::<3>()?, d.u64()?);
    // Every pose it names is one it has seen, and it has seen fewer than any session sends.
    let seen_pose = |pose: u64| pose < seen as u64;
    // A judged rate is a plausible stamped one or a corrector's setting: within the settings'.
    let valid = (MIN_ODOMETRY_RATE_HZ..=MAX_ODOMETRY_RATE_HZ).contains(&rate_hz)
        && finite(&last.1)
        && within_reach(&speeds)
        && ends.len() == speeds.len()
        && within_reach(&change.2)
        && seen < MAX_POSES_SEEN
        && ends.iter().all(|&end| seen_pose(end as u64))
        && (change.0 == 0 || (seen_pose(change.1) && seen_pose(change.3)));
    valid.then_some(())?;
    let open = flag(change.0)?.then_some((
        SpeedChange {
            pose: usize::try_from(change.1).ok()?,
            from_mps: change.2[0],
            to_mps: change.2[1],
            over_s: change.2[2],
        },
        usize::try_from(change.3).ok()?,
    ));
    let history = SpeedHistory {
        seen,
        last: flag(last.0)?.then_some(last.1),
        repeats,
        speeds,
        ends,
        open,
    };
    Some(Some((rate_hz, history)))
}

/// Appends a session watch's state.
fn encode_watch(e: &mut Encoder, watch: &SessionWatchState) {
    let source = &watch.source;
    match &source.axes {
        Some(axes) => {
            match &axes.last {
                Some(pose) => e.u32(1).u32(1).f64s(&pose.to_row_major()),
                None => e.u32(1).u32(0).f64s(&[0.0; 12]),
            };
            for &(vertical, path) in &axes.vertical_and_path_m {
                e.f64(vertical).f64(path);
            }
            e.f64s(&axes.tilted_m);
        }
        None => {
            e.u32(0);
        }
    }
    e.u64(source.stamps_s.len() as u64).f64s(&source.stamps_s);
    e.u64(source.held.len() as u64);
    for held in &source.held {
        e.f64s(held);
    }
    encode_judged(e, &source.speed);
    let Counts {
        attempts,
        accepted,
        resets,
    } = watch.alignments;
    e.u64(watch.watched_seq)
        .u64(attempts as u64)
        .u64(accepted as u64)
        .u64(resets as u64)
        .u64(watch.corrected_poses as u64);
    match &source.pace {
        Pace::Gathering {
            steps_m,
            last,
            changes,
        } => {
            e.u32(0)
                .u64(steps_m.len() as u64)
                .f64s(steps_m)
                .point(*last);
            e.u64(changes.len() as u64);
            for change in changes {
                e.u64(change.pose as u64)
                    .f64s(&[change.from_mps, change.to_mps, change.over_s]);
            }
        }
        Pace::Plausible => {
            e.u32(1);
        }
        Pace::TooFast => {
            e.u32(2);
        }
    }
    e.u64(watch.raised);
}

/// A stream's pace ([`encode_watch`]); `None` unless every part is there, every number is
/// finite, no more steps are held than are judged on, each of them moved, and every change of
/// speed lies among the poses the speed watch has seen (`seen`; none before it watches).
fn decode_pace(d: &mut Decoder<'_>, seen: Option<usize>) -> Option<Pace> {
    let flag = |f: u32| (f <= 1).then_some(f == 1);
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    match d.u32()? {
        0 => {}
        1 => return Some(Pace::Plausible),
        2 => return Some(Pace::TooFast),
        _ => return None,
    }
    let steps = d.u64().filter(|&n| n <= PACE_STEPS as u64)?;
    let steps_m: Vec<f64> = (0..steps)
        .map(|_| d.f64().filter(|s| s.is_finite() && *s > 0.0))
        .collect::<Option<_>>()?;
    let last = (d.u32()?, d.f64s::<2>().filter(|p| finite(p))?);
    let changes: Vec<SpeedChange> = (0..count(d)?)
        .map(|_| {
            let pose = usize::try_from(d.u64()?).ok()?;
            let [from_mps, to_mps, over_s] = d.f64s::<3>().filter(|v| finite(v))?;
            (pose < seen?).then_some(SpeedChange {
                pose,
                from_mps,
                to_mps,
                over_s,
            })
        })
        .collect::<Option<_>>()?;
    Some(Pace::Gathering {
        steps_m,
        last: flag(last.0)?.then_some(last.1),
        changes,
    })
}

/// A session watch's state ([`encode_watch`]; without the tilted path unless `has_tilt`, as
/// before format 10, and without the pace and the warnings raised unless `has_pace`, as before
/// format 11); `None` unless every part is there, every number but a stamp (any number a client
/// sent) is finite and every position is within reach ([`MAX_POSITION_M`]).
fn decode_watch(d: &mut Decoder<'_>, has_tilt: bool, has_pace: bool) -> Option<SessionWatchState> {
    let flag = |f: u32| (f <= 1).then_some(f == 1);
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let axes = if flag(d.u32()?)? {
        let last = (
            d.u32()?,
            d.f64s::<12>().filter(|p| {
                finite(p) && [3, 7, 11].iter().all(|&k| p[k].abs() <= MAX_POSITION_M)
            })?,
        );
        let mut vertical_and_path_m = [(0.0, 0.0); AxisConvention::ALL.len()];
        for pair in &mut vertical_and_path_m {
            *pair = (d.f64()?, d.f64()?);
            finite(&[pair.0, pair.1]).then_some(())?;
        }
        let tilted_m = match has_tilt {
            true => d.f64s().filter(|t| finite(t))?,
            false => Default::default(),
        };
        Some(AxisMotion {
            last: flag(last.0)?.then(|| Pose3::from_row_major(&last.1)),
            vertical_and_path_m,
            tilted_m,
        })
    } else {
        None
    };
    let stamps_s: Vec<f64> = (0..count(d)?).map(|_| d.f64()).collect::<Option<_>>()?;
    let held: Vec<[f64; 2]> = (0..count(d)?)
        .map(|_| d.f64s::<2>().filter(|p| within_reach(p)))
        .collect::<Option<_>>()?;
    let speed = decode_judged(d)?;
    let mut number = || d.u64().and_then(|v| usize::try_from(v).ok());
    let watched_seq = number()? as u64;
    let alignments = Counts {
        attempts: number()?,
        accepted: number()?,
        resets: number()?,
    };
    let corrected_poses = number()?;
    // What a session counts: every alignment accepted or reset was tried, and every one tried
    // was a pose answered with a correction.
    let counted = alignments.accepted <= alignments.attempts
        && alignments.resets <= alignments.attempts
        && alignments.attempts <= corrected_poses;
    counted.then_some(())?;
    let (pace, raised) = match has_pace {
        true => (
            decode_pace(d, speed.as_ref().map(|(_, history)| history.seen))?,
            d.u64()?,
        ),
        false => (Pace::default(), 0),
    };
    Some(SessionWatchState {
        source: SourceWatchState {
            axes,
            stamps_s,
            held,
            speed,
            pace,
        },
        watched_seq,
        alignments,
        corrected_poses,
        raised,
    })
}

/// What a session's journal was written under: refused on restore when it differs from now.
pub fn fingerprint(parts: &[&str]) -> u64 {
    xxh3_64(parts.join("\u{1f}").as_bytes())
}

/// Writes `bytes` to `path` atomically and durably: a temporary file, fsync, rename, fsync of
/// the folder.
pub fn write_durably(path: &Path, bytes: &[u8]) -> Result<(), JournalError> {
    let mut tmp_name = path.as_os_str().to_owned();
    tmp_name.push(".tmp");
    let tmp = PathBuf::from(tmp_name);
    let mut f = File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(bytes).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))?;
    if let Some(dir) = path.parent() {
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(io(dir))?;
    }
    Ok(())
}

/// What a session folder's `session` file says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// The session id.
    pub session: u64,
    /// When the journal began (ns since the Unix epoch): the newest of a session's journals is
    /// the one to restore.
    pub created_unix_ns: u64,
    /// The configuration and tile it was written under.
    pub fingerprint: u64,
}

impl Header {
    /// The file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut e = Encoder::default();
        e.0.extend_from_slice(SESSION_MAGIC);
        e.u64(self.session)
            .u64(self.created_unix_ns)
            .u64(self.fingerprint);
        let sum = xxh3_64(&e.0);
        e.u64(sum);
        e.0
    }

    /// Whether the file's bytes are a session file of an earlier journal format (whose records
    /// this daemon does not read).
    pub fn is_older_format(bytes: &[u8]) -> bool {
        bytes.starts_with(SESSION_MAGIC_V1) || bytes.starts_with(SESSION_MAGIC_V2)
    }

    /// A header from the file's bytes.
    pub fn decode(bytes: &[u8]) -> Option<Header> {
        if bytes.len() != 40 || &bytes[..8] != SESSION_MAGIC {
            return None;
        }
        if xxh3_64(&bytes[..32]).to_le_bytes() != bytes[32..] {
            return None;
        }
        let mut d = Decoder(&bytes[8..32]);
        Some(Header {
            session: d.u64()?,
            created_unix_ns: d.u64()?,
            fingerprint: d.u64()?,
        })
    }
}

/// The path of segment `n` in `dir`.
pub fn segment_path(dir: &Path, n: u64) -> PathBuf {
    dir.join(format!("{n:08}.log"))
}

/// The synced copy of the segment at `segment`: beside it, `NNNNNNNN.copy`.
pub fn copy_of(segment: &Path) -> PathBuf {
    segment.with_extension("copy")
}

/// Removes segment `n` in `dir` and its synced copy (a segment may have none yet).
pub fn remove_segment(dir: &Path, n: u64) -> Result<(), JournalError> {
    let path = segment_path(dir, n);
    std::fs::remove_file(&path).map_err(io(&path))?;
    let copy = copy_of(&path);
    match std::fs::remove_file(&copy) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(&copy)(e)),
        _ => Ok(()),
    }
}

/// The segments present in `dir`, in order.
pub fn segments(dir: &Path) -> Result<Vec<u64>, JournalError> {
    let mut found: Vec<u64> = std::fs::read_dir(dir)
        .map_err(io(dir))?
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            name.strip_suffix(".log")?.parse().ok()
        })
        .collect();
    found.sort_unstable();
    Ok(found)
}

/// The valid records of a segment file, in order, stopping at the first one that is torn,
/// damaged or not yet written (a crash mid-copy leaves at most one torn record; the space after
/// the last record is zeros).
pub fn read_segment(path: &Path) -> Result<Vec<Record>, JournalError> {
    Ok(valid_records(&segment_bytes(path)?))
}

/// A segment file's bytes (at most a segment's and one more, so that a longer file is caught).
fn segment_bytes(path: &Path) -> Result<Vec<u8>, JournalError> {
    let mut bytes = Vec::new();
    File::open(path)
        .map_err(io(path))?
        .take(SEGMENT_BYTES as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(io(path))?;
    Ok(bytes)
}

/// The records at the start of `bytes` up to the first that is torn, damaged or not written.
fn valid_records(bytes: &[u8]) -> Vec<Record> {
    bytes.chunks(RECORD_LEN).map_while(Record::decode).collect()
}

/// The valid records of segment `n` in `dir`: the longer run of the segment and its synced copy
/// (after a power loss the segment may lack the pages the kernel had not written out, which the
/// copy holds). When the copy holds more, the segment is repaired from it (written and synced),
/// so that appending to it continues after them.
pub fn recover_segment(dir: &Path, n: u64) -> Result<Vec<Record>, JournalError> {
    let path = segment_path(dir, n);
    let records = read_segment(&path)?;
    let copy = copy_of(&path);
    if !copy.exists() {
        return Ok(records);
    }
    let bytes = segment_bytes(&copy)?;
    let copied = valid_records(&bytes);
    if copied.len() <= records.len() {
        return Ok(records);
    }
    let file = std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .map_err(io(&path))?;
    file.write_all_at(&bytes[..copied.len() * RECORD_LEN], 0)
        .map_err(io(&path))?;
    file.sync_data().map_err(io(&path))?;
    Ok(copied)
}

/// Bytes of a full segment.
const SEGMENT_BYTES: usize = SEGMENT_RECORDS as usize * RECORD_LEN;

/// An open segment a worker appends records to, mapped into memory.
pub struct SegmentWriter {
    file: File,
    map: MmapMut,
    path: PathBuf,
    /// The segment's number.
    pub number: u64,
    /// Records written to it.
    pub records: u64,
    /// Records written to it, for the persistence thread's copier.
    appended: Arc<AtomicU64>,
    /// The record being appended, encoded (room for one, reused).
    encoded: Encoder,
}

impl SegmentWriter {
    /// Creates segment `number` in `dir` (no records; its space allocated).
    pub fn create(dir: &Path, number: u64) -> Result<Self, JournalError> {
        Self::open(dir, number, 0, true)
    }

    /// Opens segment `number` in `dir` to append after its first `records` valid records (a
    /// torn record after them is cleared).
    pub fn reopen(dir: &Path, number: u64, records: u64) -> Result<Self, JournalError> {
        Self::open(dir, number, records, false)
    }

    fn open(dir: &Path, number: u64, records: u64, new: bool) -> Result<Self, JournalError> {
        let path = segment_path(dir, number);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(new)
            .open(&path)
            .map_err(io(&path))?;
        let written = records.min(SEGMENT_RECORDS) * RECORD_LEN as u64;
        // Zeros after the valid records (cutting a torn one), then the whole segment's space
        // allocated now: a copy into a mapped page that needs disk space it cannot get would
        // kill the process (SIGBUS) where a `write` returns an error.
        file.set_len(written).map_err(io(&path))?;
        file.set_len(SEGMENT_BYTES as u64).map_err(io(&path))?;
        match rustix::fs::fallocate(
            &file,
            rustix::fs::FallocateFlags::empty(),
            0,
            SEGMENT_BYTES as u64,
        ) {
            Ok(()) => {}
            // A file system that cannot allocate ahead (rare on Linux) still works: its full
            // disk then ends the daemon instead of only the journal.
            Err(e) if e == rustix::io::Errno::OPNOTSUPP => {}
            Err(e) => return Err(io(&path)(e.into())),
        }
        // SAFETY: the file is this session's own segment in the daemon's state folder, which the
        // instance lock gives to one daemon; nothing else writes or truncates it while mapped.
        let map = unsafe { MmapMut::map_mut(&file) }.map_err(io(&path))?;
        let mut writer = SegmentWriter {
            file,
            map,
            path,
            number,
            records: records.min(SEGMENT_RECORDS),
            appended: Arc::new(AtomicU64::new(records.min(SEGMENT_RECORDS))),
            encoded: Encoder(Vec::with_capacity(RECORD_LEN)),
        };
        writer.prefault_next();
        Ok(writer)
    }

    /// Appends one record: a copy into the mapped segment, which must not be full (see
    /// [`SegmentWriter::is_full`]).
    pub fn append(&mut self, record: &Record) {
        let at = self.records as usize * RECORD_LEN;
        record.encode_into(&mut self.encoded);
        self.map[at..at + RECORD_LEN].copy_from_slice(&self.encoded.0);
        self.records += 1;
        // Release: the copier reads the records this count covers.
        self.appended.store(self.records, Ordering::Release);
    }

    /// Faults in the page the next record ends on by writing the zero that is already there,
    /// so that the append does not take the fault (the page it starts on is the last one's,
    /// or was faulted in by the call before). Nothing when the segment is full.
    pub fn prefault_next(&mut self) {
        let end = (self.records as usize + 1) * RECORD_LEN;
        if end <= self.map.len() {
            self.map[end - 1] = 0;
        }
    }

    /// True when the segment holds [`SEGMENT_RECORDS`] records.
    pub fn is_full(&self) -> bool {
        self.records >= SEGMENT_RECORDS
    }

    /// What copies this segment's records to its synced copy (on the persistence thread).
    pub fn copier(&self) -> Result<SegmentCopier, JournalError> {
        Ok(SegmentCopier {
            segment: self.file.try_clone().map_err(io(&self.path))?,
            appended: self.appended.clone(),
            path: copy_of(&self.path),
            copy: None,
            copied: 0,
        })
    }
}

/// Copies a segment's records, as the worker appends them, to the segment's synced copy
/// (`NNNNNNNN.copy`) and syncs it: the journal's defence against a power loss, without ever
/// syncing the segment the worker writes to (see the module's documentation).
pub struct SegmentCopier {
    /// A handle on the segment, read through the page cache the worker's mapping writes.
    segment: File,
    appended: Arc<AtomicU64>,
    path: PathBuf,
    /// Created at the first sync with records to copy.
    copy: Option<File>,
    /// Records in the copy (a reopened segment is copied again from its start).
    copied: u64,
}

impl SegmentCopier {
    /// Copies the records appended since the last call and syncs the copy; nothing when there
    /// are none.
    pub fn sync(&mut self) -> Result<(), JournalError> {
        let appended = self.appended.load(Ordering::Acquire);
        if appended <= self.copied {
            return Ok(());
        }
        let (from, to) = (
            self.copied as usize * RECORD_LEN,
            appended as usize * RECORD_LEN,
        );
        let mut bytes = vec![0; to - from];
        self.segment
            .read_exact_at(&mut bytes, from as u64)
            .map_err(io(&self.path))?;
        let copy = match &mut self.copy {
            Some(copy) => copy,
            None => {
                let copy = std::fs::OpenOptions::new()
                    .write(true)
                    .create(true)
                    .truncate(false)
                    .open(&self.path)
                    .map_err(io(&self.path))?;
                if let Some(dir) = self.path.parent() {
                    // The copy's name reaches the disk with it.
                    File::open(dir)
                        .and_then(|d| d.sync_all())
                        .map_err(io(dir))?;
                }
                self.copy.insert(copy)
            }
        };
        copy.write_all_at(&bytes, from as u64)
            .map_err(io(&self.path))?;
        copy.sync_data().map_err(io(&self.path))?;
        self.copied = appended;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session_watch::SessionWatch;
    use lanealign_core::stall::StallWatch;
    use lanealign_wire::payload::Warning;

    fn record(seq: u64) -> Record {
        let input = OdomPose {
            session: 7,
            seq,
            stamp_ns: -3,
            sent_mono_ns: 99,
            pose: [seq as f64; 12],
            flags: 0,
            reserved: 0,
        };
        let answer = CorrectedPose {
            daemon_epoch: 5,
            expected_seq: seq + 1,
            session: 7,
            seq,
            stamp_ns: -3,
            sent_mono_ns: 99,
            received_mono_ns: 100,
            published_mono_ns: 101,
            pose: [0.5; 12],
            map_from_odom: [1.0, 2.0, 0.1],
            residual_m: f64::NAN,
            match_ratio: f64::INFINITY,
            window_len: 3,
            status: 1,
            reason: 0,
            applied_directions: 2,
            covariance: [0.5, 0.1, 1e-3, 0.7, -2e-3, 1e-4],
            anchor_yaw: 1.04,
            odometry_scale: 1.03,
            odometry_scale_sd: 0.004,
            warnings: Warning::Rate.bit(),
        };
        Record { input, answer }
    }

    #[test]
    fn records_round_trip_and_damage_is_caught() {
        let r = record(42);
        let bytes = r.encode();
        let back = Record::decode(&bytes).unwrap();
        assert_eq!(back.input, r.input);
        assert_eq!(back.answer.residual_m.to_bits(), f64::NAN.to_bits());
        assert_eq!(back.answer.pose, r.answer.pose);
        assert_eq!(
            (back.answer.odometry_scale, back.answer.odometry_scale_sd),
            (1.03, 0.004)
        );
        for at in [0, 100, RECORD_LEN - 1] {
            let mut bad = bytes;
            bad[at] ^= 1;
            assert!(Record::decode(&bad).is_none(), "flip at {at}");
        }
        assert!(Record::decode(&bytes[..RECORD_LEN - 1]).is_none());
    }

    #[test]
    fn snapshots_round_trip_exactly_and_refuse_damage() {
        let snap = Snapshot {
            last_seq: 1234,
            next_segment: 3,
            state: SourceState {
                corrector: CorrectorState {
                    map_from_anchored: Se2::new(0.3, 1.0, -2.0),
                    window: (0..500)
                        .map(|i| [i as f64 * 1.1, 0.1 / (i + 1) as f64])
                        .collect(),
                    window_path_m: 549.9000000000001,
                    failures: 3,
                    travelled_m: 12.5,
                    gate_travelled_m: 40.25,
                    last_position_in_anchored: Some([5.0, 6.0]),
                    covariance: [[0.5, 0.1, 1e-3], [0.1, 0.7, -2e-3], [1e-3, -2e-3, 1e-4]],
                    map_error: [[0.4, -0.1], [-0.1, 0.3]],
                    carried: 7,
                    scale: Some(ScaleEstimate {
                        factor: 0.985,
                        variance: 2.5e-4,
                    }),
                    published_uncertainty: Some((
                        [[0.6, 0.1, 1e-3], [0.1, 0.9, -2e-3], [1e-3, -2e-3, 2e-4]],
                        [0.005, -0.002, 1e-6],
                    )),
                },
                smoothed: None,
                continuity: Continuity {
                    continued_from_odom: Se2::new(-2.0, 300.0, 40.0),
                    last: Some((Se2::new(1.0, 7.0, 8.0), 12.5)),
                    last_motion: Some(Se2::new(0.01, 1.5, 0.0)),
                    before_glitch: Some(BeforeGlitch {
                        continued_from_odom: Se2::new(-1.5, 250.0, 30.0),
                        last: (Se2::new(1.0, 5.5, 8.0), 12.4),
                        last_motion: Se2::new(0.02, 1.4, 0.0),
                    }),
                },
                scaled: ScaledOdometry {
                    last_in_anchored: Some([310.5, -20.25]),
                    offset: [-4.5, 0.75],
                },
                stall: Some(StallState {
                    held: Vec::new(),
                    judged: Some((
                        10.0,
                        SpeedHistory {
                            seen: 812,
                            last: Some([300.5, -19.5]),
                            repeats: 2,
                            speeds: vec![19.0, 18.5, 2.0, 0.5, 0.25],
                            ends: vec![805, 806, 807, 809, 810],
                            open: Some((
                                SpeedChange {
                                    pose: 806,
                                    from_mps: 19.0,
                                    to_mps: 1.5,
                                    over_s: 0.5,
                                },
                                808,
                            )),
                        },
                    )),
                    last: Some([310.5, -20.25]),
                    open: Some(Stall {
                        before_mps: 19.0,
                        heading: [0.6, -0.8],
                        missed_m: 42.5,
                    }),
                }),
            },
            watch: Some(SessionWatchState {
                source: SourceWatchState {
                    axes: Some(AxisMotion {
                        last: Some(Pose3::planar(310.5, -20.25, 0.3, 2.0)),
                        vertical_and_path_m: [(3.5, 250.25), (240.0, 250.5)],
                        tilted_m: [12.5, 250.5],
                    }),
                    stamps_s: vec![f64::NAN, 1.5],
                    held: vec![[1.0, 2.0], [3.0, 4.5]],
                    speed: Some((
                        10.0,
                        SpeedHistory {
                            seen: 811,
                            last: Some([300.0, -19.5]),
                            repeats: 1,
                            speeds: vec![19.0, 2.0],
                            ends: vec![806, 808],
                            open: None,
                        },
                    )),
                    pace: Pace::Gathering {
                        steps_m: vec![1.25, 0.5, 2.0],
                        last: Some([300.0, -19.5]),
                        changes: vec![SpeedChange {
                            pose: 806,
                            from_mps: 19.0,
                            to_mps: 1.5,
                            over_s: 0.5,
                        }],
                    },
                },
                watched_seq: 1234,
                alignments: Counts {
                    attempts: 600,
                    accepted: 550,
                    resets: 2,
                },
                corrected_poses: 1200,
                raised: Warning::Pace.bit() | Warning::Jumped.bit(),
            }),
        };
        let bytes = snap.encode();
        // NaN stamps (no stamps at all) compare unequal: compare the bytes decoded again.
        let decoded = Snapshot::decode(&bytes).expect("decodes");
        assert_eq!(decoded.encode(), bytes);
        let stamps = |s: &Snapshot| s.watch.as_ref().map(|w| w.source.stamps_s[1]);
        assert_eq!(stamps(&decoded), Some(1.5));
        let without_stamps = |mut s: Snapshot| {
            if let Some(w) = &mut s.watch {
                w.source.stamps_s.clear();
            }
            s
        };
        assert_eq!(without_stamps(decoded), without_stamps(snap.clone()));
        // A session watch that has seen nothing, whose stamps have told the rate and whose axes
        // are judged, and none (the format before).
        let mut told = snap.watch.clone().unwrap();
        (told.source.axes, told.source.stamps_s, told.source.held) = (None, vec![], vec![]);
        let params = lanealign_core::params::Preset::KissIcp.robust_params();
        let fresh = SessionWatch::new(&params, AxisConvention::Flu).state();
        let judged = |pace: Pace| {
            let mut watch = told.clone();
            watch.source.pace = pace;
            Some(watch)
        };
        let (plausible, too_fast) = (judged(Pace::Plausible), judged(Pace::TooFast));
        for watch in [Some(fresh), Some(told), plausible, too_fast, None] {
            let mut other = snap.clone();
            other.watch = watch;
            assert_eq!(Snapshot::decode(&other.encode()), Some(other));
        }
        // A session without a stall watch (the paper's method), and one whose watch has seen
        // nothing.
        for stall in [None, Some(StallWatch::new(10.0).state())] {
            let mut other = snap.clone();
            other.watch = None;
            other.state.stall = stall;
            assert_eq!(Snapshot::decode(&other.encode()), Some(other));
        }
        // Where the map error starts; the count of carried poses follows it, the odometry's
        // continuity (112 bytes) comes after the last position and the smoothed correction, and
        // the scale estimate, the scaled odometry and the published uncertainty (156 bytes)
        // after that, then the stall watch (176 bytes and its 5 speeds and the 5 poses they
        // ended at), then the session watch.
        let at = 8 + 8 + 8 + 32 + 8 + 4 + 8 + 72;
        let (continuity_at, scale_at, stall_at) = (at + 100, at + 212, at + 368);
        let watch_at = stall_at + 176 + 5 * 16;
        let mut unwatched = snap.clone();
        unwatched.watch = None;
        // The pose before a glitch (its flag, two transforms, a stamp and a third) follows the
        // session watch, and the window follows it.
        let glitch_at = watch_at + 4 + bytes.len() - unwatched.encode().len();
        let window_at = glitch_at + 4 + 32 + 32 + 8 + 32;
        let frame = |magic: &[u8; 8], parts: &[std::ops::Range<usize>]| {
            let mut v = magic.to_vec();
            for part in parts {
                v.extend_from_slice(&bytes[part.clone()]);
            }
            v.extend_from_slice(&xxh3_64(&v).to_le_bytes());
            v
        };
        let tail = window_at..bytes.len() - 8;
        // The format before: no pose before a glitch, read as none.
        let v11 = frame(SNAPSHOT_MAGIC_V11, &[8..glitch_at, tail.clone()]);
        let mut old = snap.clone();
        old.state.continuity.before_glitch = None;
        let decoded_v11 = Snapshot::decode(&v11).expect("the format before decodes");
        assert_eq!(without_stamps(decoded_v11), without_stamps(old.clone()));
        // The format before: the session watch without its pace (its tag, 3 steps, the last
        // position, 1 change) and the warnings raised, which end it, read as none gathered and
        // none raised so far.
        let pace_at = glitch_at - (4 + 8 + 3 * 8 + 4 + 16 + 8 + 32 + 8);
        let v10 = frame(SNAPSHOT_MAGIC_V10, &[8..pace_at, tail.clone()]);
        let watch = old.watch.as_mut().expect("the example has a watch");
        (watch.source.pace, watch.raised) = (Pace::default(), 0);
        let decoded_v10 = Snapshot::decode(&v10).expect("the format before decodes");
        assert_eq!(without_stamps(decoded_v10), without_stamps(old.clone()));
        // The one before: the session watch's axes without the tilted path, read as none so
        // far. Its flag, the axes' flag, the last pose's (its flag and 12 numbers) and the
        // vertical and whole path in both conventions come before.
        let tilted_at = watch_at + 4 + 4 + 4 + 96 + 32;
        let v9 = frame(
            SNAPSHOT_MAGIC_V9,
            &[8..tilted_at, tilted_at + 16..pace_at, tail.clone()],
        );
        let axes = old.watch.as_mut().and_then(|w| w.source.axes.as_mut());
        axes.expect("the example has axes").tilted_m = [0.0; 2];
        let decoded_v9 = Snapshot::decode(&v9).expect("the format before decodes");
        assert_eq!(without_stamps(decoded_v9), without_stamps(old.clone()));
        // The one before: no session watch, read as none (it starts afresh after the replay).
        old.watch = None;
        let v8 = frame(SNAPSHOT_MAGIC_V8, &[8..watch_at, tail.clone()]);
        assert_eq!(Snapshot::decode(&v8), Some(old.clone()));
        // The one before: no stall watch, read as none (it starts afresh).
        old.state.stall = None;
        let v7 = frame(SNAPSHOT_MAGIC_V7, &[8..stall_at, tail.clone()]);
        assert_eq!(Snapshot::decode(&v7), Some(old.clone()));
        // The one before: no scale estimate, read as none.
        old.state.corrector.scale = None;
        old.state.corrector.published_uncertainty = None;
        old.state.scaled = ScaledOdometry::default();
        let v6 = frame(SNAPSHOT_MAGIC_V6, &[8..scale_at, tail.clone()]);
        assert_eq!(Snapshot::decode(&v6), Some(old.clone()));
        // The one before: no continuity, read as no jump so far and no last pose.
        old.state.continuity = Continuity::default();
        let v5 = frame(SNAPSHOT_MAGIC_V5, &[8..continuity_at, tail.clone()]);
        assert_eq!(Snapshot::decode(&v5), Some(old.clone()));
        let older = |magic: &[u8; 8], keep: std::ops::Range<usize>| {
            frame(magic, &[keep, at + 44..continuity_at, tail.clone()])
        };
        // The one before: no distance the gate widens by (8 bytes fewer), read as the distance
        // since the last accepted step.
        old.state.corrector.gate_travelled_m = old.state.corrector.travelled_m;
        let v4 = older(SNAPSHOT_MAGIC_V4, 8..at + 36);
        assert_eq!(Snapshot::decode(&v4), Some(old.clone()));
        // Before that: no carried count (4 bytes fewer), read as none carried.
        old.state.corrector.carried = 0;
        let v3 = older(SNAPSHOT_MAGIC_V3, 8..at + 32);
        assert_eq!(Snapshot::decode(&v3), Some(old.clone()));
        // And before: no map error either (32 bytes fewer), read as none.
        old.state.corrector.map_error = [[0.0; 2]; 2];
        let v2 = older(SNAPSHOT_MAGIC_V2, 8..at);
        assert_eq!(Snapshot::decode(&v2), Some(old));
        for cut in [0, 8, 100, bytes.len() - 1] {
            assert!(Snapshot::decode(&bytes[..cut]).is_none(), "cut at {cut}");
        }
        let mut bad = bytes.clone();
        bad[50] ^= 4;
        assert!(Snapshot::decode(&bad).is_none());
        // A stall watch with a speed that is no number is refused, checksum and all.
        let mut nan = snap.clone();
        if let Some(stall) = &mut nan.state.stall {
            if let Some((_, speed)) = &mut stall.judged {
                speed.speeds[2] = f64::NAN;
            }
        }
        assert!(Snapshot::decode(&nan.encode()).is_none());
        // So is a session watch that counts more alignments accepted than tried, or more tried
        // than poses.
        for (accepted, attempts) in [(601, 600), (550, 1201)] {
            let mut miscounted = snap.clone();
            if let Some(watch) = &mut miscounted.watch {
                (watch.alignments.accepted, watch.alignments.attempts) = (accepted, attempts);
            }
            assert!(Snapshot::decode(&miscounted.encode()).is_none());
        }
        // So is a session watch with a position that is no number.
        let mut nan = snap.clone();
        if let Some(watch) = &mut nan.watch {
            watch.source.held[1][0] = f64::INFINITY;
        }
        assert!(Snapshot::decode(&nan.encode()).is_none());
        // So is a pace that holds a step that did not move, more steps than it judges on, or a
        // change of speed at a pose its speed watch has not seen.
        let gathering = |steps_m: Vec<f64>, change_at: usize| {
            let mut other = snap.clone();
            if let Some(watch) = &mut other.watch {
                // No NaN stamp: the snapshot compares equal to itself.
                watch.source.stamps_s.clear();
                watch.source.pace = Pace::Gathering {
                    steps_m,
                    last: None,
                    changes: vec![SpeedChange {
                        pose: change_at,
                        from_mps: 19.0,
                        to_mps: 1.5,
                        over_s: 0.5,
                    }],
                };
            }
            other
        };
        let other = gathering(vec![1.0; PACE_STEPS], 810);
        assert_eq!(Snapshot::decode(&other.encode()), Some(other));
        for bad in [
            gathering(vec![1.0, 0.0], 806),
            gathering(vec![1.0; PACE_STEPS + 1], 806),
            gathering(vec![1.0], 811),
        ] {
            assert!(Snapshot::decode(&bad.encode()).is_none(), "{bad:?}");
        }
    }

    fn seqs(records: &[Record]) -> Vec<u64> {
        records.iter().map(|r| r.input.seq).collect()
    }

    #[test]
    fn the_copier_copies_what_was_appended_and_a_power_loss_is_recovered_from_it() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = SegmentWriter::create(dir.path(), 0).unwrap();
        let mut copier = w.copier().unwrap();
        // Nothing appended: no copy yet.
        copier.sync().unwrap();
        assert!(!copy_of(&segment_path(dir.path(), 0)).exists());
        for seq in 1..=3 {
            w.append(&record(seq));
        }
        copier.sync().unwrap();
        for seq in 4..=5 {
            w.append(&record(seq));
        }
        copier.sync().unwrap();
        assert_eq!(
            seqs(&read_segment(&copy_of(&segment_path(dir.path(), 0))).unwrap()),
            [1, 2, 3, 4, 5]
        );
        // Appended after the last sync: in the segment only.
        w.append(&record(6));
        drop(w);
        assert_eq!(
            seqs(&recover_segment(dir.path(), 0).unwrap()),
            [1, 2, 3, 4, 5, 6]
        );
        // A power loss: the segment's pages from the third record on were never written out.
        let path = segment_path(dir.path(), 0);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[2 * RECORD_LEN..].fill(0);
        std::fs::write(&path, bytes).unwrap();
        // The synced copy has what the last sync copied; the segment is repaired from it, and
        // appending continues after it.
        assert_eq!(
            seqs(&recover_segment(dir.path(), 0).unwrap()),
            [1, 2, 3, 4, 5]
        );
        assert_eq!(seqs(&read_segment(&path).unwrap()), [1, 2, 3, 4, 5]);
        let mut w = SegmentWriter::reopen(dir.path(), 0, 5).unwrap();
        w.append(&record(6));
        let mut copier = w.copier().unwrap();
        copier.sync().unwrap();
        assert_eq!(
            seqs(&read_segment(&copy_of(&segment_path(dir.path(), 0))).unwrap()),
            [1, 2, 3, 4, 5, 6]
        );
    }

    #[test]
    fn a_torn_last_record_is_cut_and_appending_continues() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = SegmentWriter::create(dir.path(), 0).unwrap();
        for seq in 1..=5 {
            w.append(&record(seq));
        }
        drop(w);
        // The segment is allocated whole: zeros after the records.
        let path = segment_path(dir.path(), 0);
        let mut bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), SEGMENT_BYTES);
        assert!(bytes[5 * RECORD_LEN..].iter().all(|&b| b == 0));
        // A crash mid-copy: part of a record after them.
        bytes[5 * RECORD_LEN..5 * RECORD_LEN + 100].copy_from_slice(&record(6).encode()[..100]);
        std::fs::write(&path, bytes).unwrap();
        let read = read_segment(&path).unwrap();
        assert_eq!(read.len(), 5);
        let mut w = SegmentWriter::reopen(dir.path(), 0, 5).unwrap();
        w.append(&record(6));
        let seqs: Vec<u64> = read_segment(&path)
            .unwrap()
            .iter()
            .map(|r| r.input.seq)
            .collect();
        assert_eq!(seqs, vec![1, 2, 3, 4, 5, 6]);
        assert_eq!(segments(dir.path()).unwrap(), vec![0]);
    }

    #[test]
    fn reopening_clears_what_follows_the_valid_records() {
        // Whatever a crash left after the valid records (a torn one) is zeros again, so that
        // reading stops where the appends stopped.
        let dir = tempfile::tempdir().unwrap();
        let mut w = SegmentWriter::create(dir.path(), 0).unwrap();
        w.append(&record(1));
        w.append(&record(2));
        drop(w);
        let path = segment_path(dir.path(), 0);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[RECORD_LEN..2 * RECORD_LEN].copy_from_slice(&[0xAB; RECORD_LEN]);
        std::fs::write(&path, bytes).unwrap();
        drop(SegmentWriter::reopen(dir.path(), 0, 1).unwrap());
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), SEGMENT_BYTES);
        assert!(bytes[RECORD_LEN..].iter().all(|&b| b == 0));
    }

    #[test]
    fn a_full_segment_reads_back_whole() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = SegmentWriter::create(dir.path(), 3).unwrap();
        for seq in 1..=SEGMENT_RECORDS {
            assert!(!w.is_full());
            w.append(&record(seq));
        }
        assert!(w.is_full());
        let read = read_segment(&segment_path(dir.path(), 3)).unwrap();
        assert_eq!(read.len() as u64, SEGMENT_RECORDS);
        assert_eq!(read.last().map(|r| r.input.seq), Some(SEGMENT_RECORDS));
        assert!(
            SegmentWriter::create(dir.path(), 3).is_err(),
            "never over an existing one"
        );
    }

    #[test]
    fn headers_round_trip() {
        let h = Header {
            session: 0xdead,
            created_unix_ns: 17,
            fingerprint: fingerprint(&["a", "b"]),
        };
        let bytes = h.encode();
        assert_eq!(Header::decode(&bytes), Some(h));
        assert_ne!(fingerprint(&["ab", ""]), fingerprint(&["a", "b"]));
        assert!(Header::decode(&bytes[..39]).is_none());
        assert!(!Header::is_older_format(&bytes));
        for magic in [SESSION_MAGIC_V1, SESSION_MAGIC_V2] {
            let mut older = bytes.clone();
            older[..8].copy_from_slice(magic);
            assert!(Header::is_older_format(&older));
            assert!(Header::decode(&older).is_none());
        }
    }
}
