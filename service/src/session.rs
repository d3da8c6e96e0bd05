//! One client session of a source: its corrector, the protocol of sequence numbers, the answers
//! it can send again, and its journal.
//!
//! The protocol (docs/wire.md, "Sessions"): poses are numbered 1, 2, 3, ... within a session.
//! The next expected number is used; a used number with the same pose gets its answer again
//! (a client re-sending what a killed daemon did not answer); a used number with another pose is
//! flagged; a number beyond the next is answered with a gap status naming the one expected.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::Sender;
use std::sync::Arc;

use lanealign_core::corrector::{MatchMode, Status, StepTiming};
use lanealign_core::grid::GridMaps;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::Params;
use lanealign_core::pose::Pose3;
use lanealign_core::source_corrector::{Placement, SourceCorrector};
use lanealign_wire::payload::{
    upper_triangle, CorrectedPose, OdomPose, ReasonCode, StatusCode, FLAG_FRESH_START,
    MAX_IN_FLIGHT,
};

use crate::grid_loader::{GridLoader, GridView};
use crate::journal::{
    recover_segment, segments, Header, JournalError, Record, SegmentCopier, SegmentWriter,
    Snapshot, SEGMENT_RECORDS,
};
use crate::metrics::Outcome;
use crate::session_watch::{SessionNews, SessionWatch};
use crate::worker::wire_status;

/// Work for the persistence thread: nothing a worker waits for.
pub enum PersistJob {
    /// Copy this segment's records to its synced copy every second.
    Track {
        /// The session's folder.
        dir: PathBuf,
        /// The open segment's copier.
        copier: SegmentCopier,
    },
    /// Write a snapshot durably, then delete the segments before `keep_from`.
    Snapshot {
        /// The session's folder.
        dir: PathBuf,
        /// The snapshot's bytes.
        bytes: Vec<u8>,
        /// The first segment to keep.
        keep_from: u64,
    },
    /// The session ended: remove its folder.
    Remove {
        /// The session's folder.
        dir: PathBuf,
    },
}

/// What a source's sessions share: how to build a corrector, and where journals go.
#[derive(Clone)]
pub struct SessionSetup {
    /// The lane map new sessions use (on a grid, the one they start with).
    pub map: Arc<LaneMap>,
    /// On a grid, the loader each session asks for the cells around it.
    pub grid: Option<GridLoader>,
    /// Corrector parameters.
    pub params: Params,
    /// Matching mode.
    pub mode: MatchMode,
    /// The source's placement.
    pub placement: Placement,
    /// The source's journal folder, when sessions are persisted.
    pub journal_dir: Option<PathBuf>,
    /// Identifies the configuration and tile the journals are written under.
    pub fingerprint: u64,
    /// The persistence thread.
    pub persistence: Option<Sender<PersistJob>>,
    /// The daemon's run (in every answer).
    pub daemon_epoch: u64,
}

/// A session's journal while it is written.
struct Journal {
    dir: PathBuf,
    segment: SegmentWriter,
}

/// The answer to one input, and what it means for the metrics.
pub struct Handled {
    /// What to publish.
    pub answer: CorrectedPose,
    /// What happened.
    pub outcome: Outcome,
    /// The corrector's time.
    pub timing: StepTiming,
    /// On a grid: neighbour queries of this pose that reached past the session's loaded cells
    /// (its answer may differ from the whole map's).
    pub uncovered_queries: u64,
    /// On a grid: the session moved to a newly assembled map before this pose.
    pub map_swapped: bool,
    /// On a grid: the session was behind and waited for the map it asked for (at most
    /// `grid_loader::CATCH_UP`) before this pose.
    pub map_waited: bool,
}

/// One session of a source.
pub struct Session {
    /// The session id.
    pub id: u64,
    /// When its journal began (ns since the Unix epoch; 0 without a journal).
    pub created_unix_ns: u64,
    corrector: SourceCorrector,
    /// The next sequence number the session expects.
    expected_seq: u64,
    /// The last answers (at most [`MAX_IN_FLIGHT`]), oldest first, to send again on request.
    recent: VecDeque<Record>,
    journal: Option<Journal>,
    grid: Option<GridView>,
    /// What its corrected poses have told so far, for the daemon's warnings
    /// ([`Session::watch_answered`] feeds it). Snapshots hold it.
    pub watch: SessionWatch,
}

/// A journal that failed: the session goes on without persistence, and the daemon says so.
pub struct JournalFailure(pub JournalError);

fn blank_answer(input: &OdomPose, received_mono_ns: u64, epoch: u64) -> CorrectedPose {
    CorrectedPose {
        daemon_epoch: epoch,
        expected_seq: 0,
        session: input.session,
        seq: input.seq,
        stamp_ns: input.stamp_ns,
        sent_mono_ns: input.sent_mono_ns,
        received_mono_ns,
        published_mono_ns: 0,
        pose: input.pose,
        map_from_odom: [f64::NAN; 3],
        residual_m: f64::NAN,
        match_ratio: f64::NAN,
        window_len: 0,
        status: StatusCode::PassThrough as u32,
        reason: ReasonCode::None as u32,
        applied_directions: 0,
        covariance: [f64::NAN; 6],
        anchor_yaw: f64::NAN,
        odometry_scale: f64::NAN,
        odometry_scale_sd: f64::NAN,
        warnings: 0,
    }
}

/// Whether `input` starts its session afresh: it says so ([`FLAG_FRESH_START`]) and its number
/// can be used. The last number cannot (it has no successor, and no pose is answered with it):
/// a fresh start there starts nothing, and its session, if one runs, goes on.
pub fn starts_afresh(input: &OdomPose) -> bool {
    input.flags & FLAG_FRESH_START != 0 && input.seq != u64::MAX
}

/// The first sequence number of a session that `input` starts: the input's own when it starts
/// the session afresh ([`starts_afresh`]), else 1.
pub fn first_seq(input: &OdomPose) -> u64 {
    if starts_afresh(input) {
        input.seq
    } else {
        1
    }
}

/// The answer to `input` for a pass-through source (no session state).
pub fn pass_through(input: &OdomPose, received_mono_ns: u64, epoch: u64) -> CorrectedPose {
    let mut a = blank_answer(input, received_mono_ns, epoch);
    a.expected_seq = input.seq.saturating_add(1);
    a
}

impl Session {
    /// A new session whose first pose is `first_seq`, with a new journal (in a folder of its
    /// own) when the source journals.
    pub fn start(
        id: u64,
        first_seq: u64,
        setup: &SessionSetup,
    ) -> (Session, Option<JournalFailure>) {
        let corrector =
            SourceCorrector::new(setup.map.clone(), setup.params, setup.mode, setup.placement);
        let mut session = Session {
            id,
            created_unix_ns: 0,
            corrector,
            expected_seq: first_seq,
            recent: VecDeque::new(),
            journal: None,
            grid: setup.grid.as_ref().map(|g| g.view(id)),
            watch: new_watch(setup),
        };
        let mut failure = None;
        if let Some(root) = &setup.journal_dir {
            let nonce = crate::new_nonce();
            let dir = root.join(format!("{id:016x}-{nonce:016x}"));
            let header = Header {
                session: id,
                created_unix_ns: unix_ns(),
                fingerprint: setup.fingerprint,
            };
            match create_journal(&dir, &header, setup) {
                Ok(journal) => {
                    session.created_unix_ns = header.created_unix_ns;
                    session.journal = Some(journal);
                }
                Err(e) => failure = Some(JournalFailure(e)),
            }
        }
        (session, failure)
    }

    /// The next sequence number the session expects.
    pub fn expected_seq(&self) -> u64 {
        self.expected_seq
    }

    /// Answers one input of this session. A used pose is journaled before its answer is
    /// returned (so before anyone can see it); a journal write that fails is reported and the
    /// session goes on unjournaled. `behind` says whether more poses are queued behind this
    /// one (asked only while a session on a grid waits for cells: see `GridView::arrived`).
    pub fn handle(
        &mut self,
        input: &OdomPose,
        received_mono_ns: u64,
        setup: &SessionSetup,
        behind: impl FnOnce() -> bool,
    ) -> (Handled, Option<JournalFailure>) {
        let epoch = setup.daemon_epoch;
        let mut answer = blank_answer(input, received_mono_ns, epoch);
        answer.warnings = self.watch.raised();
        let flagged = |mut answer: CorrectedPose, code: StatusCode, expected: u64| {
            answer.status = code as u32;
            answer.expected_seq = expected;
            Handled {
                answer,
                outcome: if code == StatusCode::Gap {
                    Outcome::Gap
                } else {
                    Outcome::Flagged
                },
                timing: StepTiming::default(),
                uncovered_queries: 0,
                map_swapped: false,
                map_waited: false,
            }
        };
        if input.seq > self.expected_seq {
            return (flagged(answer, StatusCode::Gap, self.expected_seq), None);
        }
        if input.seq == u64::MAX {
            // The last number has no successor: the session's numbers are used up.
            return (
                flagged(answer, StatusCode::OutOfOrderSeq, self.expected_seq),
                None,
            );
        }
        if input.seq < self.expected_seq {
            let earlier = self.recent.iter().find(|r| r.input.seq == input.seq);
            return match earlier {
                Some(r) if same_pose(&r.input.pose, &input.pose) => {
                    let mut again = r.answer;
                    again.daemon_epoch = epoch;
                    again.received_mono_ns = received_mono_ns;
                    again.sent_mono_ns = input.sent_mono_ns;
                    again.expected_seq = self.expected_seq;
                    let h = Handled {
                        answer: again,
                        outcome: Outcome::Resent,
                        timing: StepTiming::default(),
                        uncovered_queries: 0,
                        map_swapped: false,
                        map_waited: false,
                    };
                    (h, None)
                }
                _ => {
                    let code = if input.seq + 1 == self.expected_seq {
                        StatusCode::DuplicateSeq
                    } else {
                        StatusCode::OutOfOrderSeq
                    };
                    (flagged(answer, code, self.expected_seq), None)
                }
            };
        }
        let pose = Pose3::from_row_major(&input.pose);
        let (mut map_swapped, mut map_waited) = (false, false);
        if let Some(view) = &mut self.grid {
            let waits = view.waits();
            if let Some(map) = view.arrived(behind) {
                self.corrector.replace_map(map);
                map_swapped = true;
            }
            map_waited = view.waits() > waits;
            if pose.problem().is_none() {
                let next = self.corrector.predicted_position_in_map(&pose);
                view.request_if_needed(self.corrector.window(), next);
            }
        }
        // A segment filled by the last pose starts its successor now, before this pose moves
        // the corrector on (the daemon does it between poses, in `prepare`).
        let failure = self.roll_journal(setup).err();
        let uncovered_before = self.corrector.map().uncovered_queries();
        let (record, timing) = self.corrector.correct_at(&pose, input.stamp_s());
        let uncovered_queries = self.corrector.map().uncovered_queries() - uncovered_before;
        // The record of a pose that is no pose has NaN covariance and scale already; its
        // correction in force and the anchor stay NaN here, as docs/wire.md says of flagged
        // answers.
        if record.status != Status::InvalidInput {
            let [x, y] = record.map_from_odom.translation();
            answer.map_from_odom = [x, y, record.map_from_odom.yaw()];
            answer.anchor_yaw = self.corrector.anchor_yaw();
        }
        answer.covariance = upper_triangle(&record.covariance);
        answer.odometry_scale = record.odometry_scale;
        answer.odometry_scale_sd = record.odometry_scale_sd;
        answer.pose = record.pose.to_row_major();
        let (status, reason) = wire_status(&record.status);
        answer.status = status as u32;
        answer.reason = reason as u32;
        answer.residual_m = record.status.residual_m().unwrap_or(f64::NAN);
        answer.match_ratio = record.status.match_ratio().unwrap_or(f64::NAN);
        answer.window_len = record.status.window_len() as u32;
        answer.applied_directions = u32::from(record.status.applied_directions());
        self.expected_seq = input.seq + 1;
        answer.expected_seq = self.expected_seq;
        let entry = Record {
            input: *input,
            answer,
        };
        if self.recent.len() as u64 >= MAX_IN_FLIGHT {
            self.recent.pop_front();
        }
        self.recent.push_back(entry);
        if let Some(journal) = &mut self.journal {
            journal.segment.append(&entry);
        }
        let outcome = match record.status {
            Status::InvalidInput => Outcome::Flagged,
            status => Outcome::Corrected(status),
        };
        (
            Handled {
                answer,
                outcome,
                timing,
                uncovered_queries,
                map_swapped,
                map_waited,
            },
            failure,
        )
    }

    /// When the journal's segment is full: hands a snapshot of the state after its last record
    /// to the persistence thread and starts the next segment. A journal that fails is dropped
    /// (the session goes on without crash recovery).
    fn roll_journal(&mut self, setup: &SessionSetup) -> Result<(), JournalFailure> {
        let Some(journal) = &mut self.journal else {
            return Ok(());
        };
        if !journal.segment.is_full() {
            return Ok(());
        }
        let snapshot = Snapshot {
            last_seq: self.expected_seq - 1,
            next_segment: journal.segment.number + 1,
            state: self.corrector.state(),
            watch: Some(self.watch.state()),
        };
        let result = roll(journal, snapshot, setup);
        if result.is_err() {
            self.journal = None;
        }
        result.map_err(JournalFailure)
    }

    /// Readies what the session's next pose needs, off the latency path: call it after
    /// publishing an answer. Starts the journal's next segment when this one is full, faults in
    /// the journal page the next record goes to, and grows the corrector's buffers
    /// ([`lanealign_core::corrector::Corrector::prepare`]).
    pub fn prepare(&mut self, setup: &SessionSetup) -> Option<JournalFailure> {
        let failure = self.roll_journal(setup).err();
        if let Some(journal) = &mut self.journal {
            journal.segment.prefault_next();
        }
        self.corrector.prepare();
        failure
    }

    /// Feeds the session's watch `input` if its answer was a correction (`outcome`, from
    /// [`Session::handle`]); returns what the watch told with it. The worker calls it after
    /// publishing the answer, off the latency path.
    pub fn watch_answered(&mut self, input: &OdomPose, outcome: &Outcome) -> Option<SessionNews> {
        match outcome {
            Outcome::Corrected(status) => Some(self.watch.observe(
                input,
                status,
                self.corrector.took_poses_missing(),
            )),
            _ => None,
        }
    }

    /// Does the corrector's work that needs no pose, off the latency path: call it when no pose
    /// waits to be answered ([`lanealign_core::corrector::Corrector::work_ahead`]).
    pub fn work_ahead(&mut self) {
        self.corrector.work_ahead();
    }

    /// Poses in the corrector's window.
    pub fn window_len(&self) -> usize {
        self.corrector.window_len()
    }

    /// Whether the last pose the corrector took was a step it took for poses missing
    /// ([`lanealign_core::source_corrector::SourceCorrector::took_poses_missing`]).
    pub fn took_poses_missing(&self) -> bool {
        self.corrector.took_poses_missing()
    }

    /// The corrector's state (what a snapshot holds).
    pub fn state(&self) -> lanealign_core::source_corrector::SourceState {
        self.corrector.state()
    }

    /// The session's journal folder, when it has one.
    pub fn journal_dir(&self) -> Option<&Path> {
        self.journal.as_ref().map(|j| j.dir.as_path())
    }
}

/// Whether two row-major poses are the same bit for bit: a pose of NaNs sent or answered again
/// is the same pose, though a NaN equals nothing, itself included.
fn same_pose(a: &[f64; 12], b: &[f64; 12]) -> bool {
    a.map(f64::to_bits) == b.map(f64::to_bits)
}

/// Nanoseconds since the Unix epoch (0 if the clock is before it).
fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn create_journal(
    dir: &Path,
    header: &Header,
    setup: &SessionSetup,
) -> Result<Journal, JournalError> {
    std::fs::create_dir_all(dir).map_err(|source| JournalError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    crate::journal::write_durably(&dir.join("session"), &header.encode())?;
    let segment = SegmentWriter::create(dir, 0)?;
    track(setup, dir, &segment)?;
    Ok(Journal {
        dir: dir.to_path_buf(),
        segment,
    })
}

fn track(setup: &SessionSetup, dir: &Path, segment: &SegmentWriter) -> Result<(), JournalError> {
    if let Some(p) = &setup.persistence {
        // A persistence thread that is gone only means no synced copies.
        let _ = p.send(PersistJob::Track {
            dir: dir.to_path_buf(),
            copier: segment.copier()?,
        });
    }
    Ok(())
}

/// Starts the segment after the journal's full one, and hands `snapshot` (the session's state
/// after the full one's last record) to the persistence thread.
fn roll(
    journal: &mut Journal,
    snapshot: Snapshot,
    setup: &SessionSetup,
) -> Result<(), JournalError> {
    let next = snapshot.next_segment;
    journal.segment = SegmentWriter::create(&journal.dir, next)?;
    track(setup, &journal.dir, &journal.segment)?;
    if let Some(p) = &setup.persistence {
        // The last full segment stays for answers to send again.
        let _ = p.send(PersistJob::Snapshot {
            dir: journal.dir.clone(),
            bytes: snapshot.encode(),
            keep_from: next - 1,
        });
    }
    Ok(())
}

/// Why a journal was not restored.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// Reading it failed.
    #[error(transparent)]
    Journal(#[from] JournalError),
    /// It belongs to another session id, configuration or tile.
    #[error("written under another configuration or tile")]
    Stale,
    /// It was written by an earlier daemon in a journal format this one does not append to.
    #[error("written in an earlier journal format (answers without the odometry's scale)")]
    OlderFormat,
    /// Its content is inconsistent (a missing record, an answer that does not replay).
    #[error("{0}")]
    Inconsistent(String),
}

/// Moves a corrector being restored on a grid to the cells its window and `next` (metres, map
/// plane) need, loading them on this thread.
fn follow_grid(
    cells: &mut Option<GridMaps>,
    corrector: &mut SourceCorrector,
    next: [f64; 2],
) -> Result<(), RestoreError> {
    let Some(cells) = cells else {
        return Ok(());
    };
    let map = cells
        .update(corrector.window(), next)
        .map_err(|e| RestoreError::Inconsistent(format!("loading grid cells: {e}")))?;
    if let Some(map) = map {
        corrector.replace_map(Arc::new(map));
    }
    Ok(())
}

/// A watch for a new session of `setup`'s source.
fn new_watch(setup: &SessionSetup) -> SessionWatch {
    SessionWatch::new(&setup.params, setup.placement.convention)
}

/// Restores the session journaled in `dir`: its snapshot, then every later record replayed
/// through the corrector, each answer computed again and checked against the one logged, and
/// through the session's watch (what it told then was told before the daemon went down).
pub fn restore(dir: &Path, setup: &SessionSetup) -> Result<Session, RestoreError> {
    let io = |source| JournalError::Io {
        path: dir.join("session"),
        source,
    };
    let header = std::fs::read(dir.join("session")).map_err(io)?;
    if Header::is_older_format(&header) {
        return Err(RestoreError::OlderFormat);
    }
    let header = Header::decode(&header)
        .ok_or(RestoreError::Inconsistent("unreadable session file".into()))?;
    if header.fingerprint != setup.fingerprint {
        return Err(RestoreError::Stale);
    }
    let snapshot = match std::fs::read(dir.join("snapshot")) {
        Ok(bytes) => Some(
            Snapshot::decode(&bytes)
                .ok_or(RestoreError::Inconsistent("unreadable snapshot".into()))?,
        ),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => {
            return Err(JournalError::Io {
                path: dir.join("snapshot"),
                source: e,
            }
            .into())
        }
    };
    let mut corrector = match &snapshot {
        Some(s) => SourceCorrector::restore(
            setup.map.clone(),
            setup.params,
            setup.mode,
            setup.placement,
            s.state.clone(),
        ),
        None => SourceCorrector::new(setup.map.clone(), setup.params, setup.mode, setup.placement),
    };
    // A snapshot of a format without the watch leaves it to start afresh after the replay.
    let mut watch = match &snapshot {
        Some(s) => s
            .watch
            .clone()
            .map(|state| SessionWatch::restore(&setup.params, setup.placement.convention, state)),
        None => Some(new_watch(setup)),
    };
    // On a grid, the replay loads the cells each pose needs right here (nothing is served yet),
    // so that it runs on the maps the session had.
    let mut cells = setup
        .grid
        .as_ref()
        .map(|g| GridMaps::new(g.grid().clone(), g.policy()));
    if let Some(&newest) = corrector.window().last() {
        follow_grid(&mut cells, &mut corrector, newest)?;
    }
    let (mut last_seq, first_segment) = snapshot
        .as_ref()
        .map_or((None, 0), |s| (Some(s.last_seq), s.next_segment));
    let mut recent: VecDeque<Record> = VecDeque::new();
    let numbers = segments(dir)?;
    let mut open: Option<(u64, u64)> = None;
    for &n in &numbers {
        let records = recover_segment(dir, n)?;
        for r in &records {
            if n >= first_segment {
                if let Some(last) = last_seq {
                    if last.checked_add(1) != Some(r.input.seq) {
                        return Err(RestoreError::Inconsistent(format!(
                            "segment {n}: seq {} after {last}",
                            r.input.seq
                        )));
                    }
                }
                let pose = Pose3::from_row_major(&r.input.pose);
                if pose.problem().is_none() {
                    let next = corrector.predicted_position_in_map(&pose);
                    follow_grid(&mut cells, &mut corrector, next)?;
                }
                let (again, _) = corrector.correct_at(&pose, r.input.stamp_s());
                let (status, _) = wire_status(&again.status);
                if !same_pose(&again.pose.to_row_major(), &r.answer.pose)
                    || status as u32 != r.answer.status
                {
                    return Err(RestoreError::Inconsistent(format!(
                        "segment {n}: the answer to seq {} does not replay",
                        r.input.seq
                    )));
                }
                if let Some(watch) = watch
                    .as_mut()
                    .filter(|_| again.status != Status::InvalidInput)
                {
                    watch.observe(&r.input, &again.status, corrector.took_poses_missing());
                }
                last_seq = Some(r.input.seq);
            }
            if recent.len() as u64 >= MAX_IN_FLIGHT {
                recent.pop_front();
            }
            recent.push_back(*r);
        }
        open = Some((n, records.len() as u64));
    }
    // No pose is answered with the last number (it has no successor), so a journal that used
    // it was not written by a daemon.
    let expected_seq = last_seq
        .map_or(Some(1), |s| s.checked_add(1))
        .ok_or_else(|| RestoreError::Inconsistent("its sequence numbers are used up".into()))?;
    let segment = match open {
        Some((n, records)) if records < SEGMENT_RECORDS => SegmentWriter::reopen(dir, n, records)?,
        Some((n, _)) => SegmentWriter::create(dir, n + 1)?,
        None => SegmentWriter::create(dir, first_segment)?,
    };
    track(setup, dir, &segment)?;
    Ok(Session {
        id: header.session,
        created_unix_ns: header.created_unix_ns,
        corrector,
        expected_seq,
        recent,
        grid: setup.grid.as_ref().map(|g| g.view(header.session)),
        journal: Some(Journal {
            dir: dir.to_path_buf(),
            segment,
        }),
        watch: watch.unwrap_or_else(|| new_watch(setup)),
    })
}
