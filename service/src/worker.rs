//! One worker thread per source: it owns the source's iceoryx2 node and ports, and one session
//! (corrector, answer service, journal) per client session; it waits (without polling) for
//! poses, answers each on its session's service, and reports.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use lanealign_core::corrector::{RejectReason, Status};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::Params;
use lanealign_core::plausibility::{MAX_ACCELERATION_MPS2, SPEED_SPAN_S};
use lanealign_core::report::error_line;
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::{CorrectedPose, OdomPose, ReasonCode, StatusCode, FLAG_END_SESSION};
use lanealign_wire::service::{
    Ipc, Namespace, NodeCreateError, PortCreateError, PoseServices, ServiceOpenError,
    SessionServices,
};
use lanealign_wire::shm::{self, ShmError};

use crate::config::ResolvedSource;
use crate::grid_loader::GridLoader;
use crate::metrics::{Outcome, SourceMetrics};
use crate::repeat_log::{RepeatLog, Untold, TOLD_EVERY};
use crate::session::{self, JournalFailure, PersistJob, Session, SessionSetup};
use crate::session_watch::{SessionNews, SessionWatch};

/// How long a worker waits for a pose before it checks for shutdown and idle sessions.
const WAKE_UP: Duration = Duration::from_millis(100);

/// A worker that could not start.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// Its node could not be created.
    #[error("source {name}")]
    Node {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: NodeCreateError,
    },
    /// Its services could not be opened.
    #[error("source {name}")]
    Service {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: ServiceOpenError,
    },
    /// A port could not be created.
    #[error("source {name}")]
    Port {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: PortCreateError,
    },
    /// Its wait strategy could not be applied.
    #[error("source {name}: wait strategy")]
    Wait {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: lanealign_wire::wait::WaitError,
    },
    /// Shared memory has no room for its ports.
    #[error("source {name}")]
    SharedMemory {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: ShmError,
    },
    /// Its journal folder could not be made.
    #[error("source {name}: creating the journal folder {dir}")]
    Journal {
        /// The source.
        name: String,
        /// The folder.
        dir: PathBuf,
        /// What failed.
        #[source]
        source: std::io::Error,
    },
}

/// What a worker did over its life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WorkerSummary {
    /// Poses received.
    pub received: u64,
    /// Answers published.
    pub published: u64,
    /// Answers no one received (the session's client was gone).
    pub undelivered: u64,
    /// Sessions restored from their journals at start.
    pub restored: u64,
}

/// The wire's status and reason for a corrector status: the one conversion between the two
/// models.
pub fn wire_status(status: &Status) -> (StatusCode, ReasonCode) {
    let code = match status {
        Status::WarmingUp { .. } => StatusCode::WarmingUp,
        Status::Accepted { .. } => StatusCode::Accepted,
        Status::Rejected { .. } => StatusCode::Rejected,
        Status::Reset { .. } => StatusCode::Reset,
        Status::InvalidInput => StatusCode::InvalidInput,
        Status::Carried { .. } => StatusCode::Carried,
        Status::OdometryJump { .. } => StatusCode::OdometryJump,
    };
    let reason = match status.reason() {
        None => ReasonCode::None,
        Some(RejectReason::TooFewMatches) => ReasonCode::TooFewMatches,
        Some(RejectReason::ResidualTooLarge) => ReasonCode::ResidualTooLarge,
    };
    (code, reason)
}

/// A lane map the daemon reloaded: new sessions use it.
pub struct Reload {
    /// The map (on a grid, the one sessions start with).
    pub map: Arc<LaneMap>,
    /// On a grid, the loader of the new grid.
    pub grid: Option<GridLoader>,
    /// The new journal fingerprint of the source.
    pub fingerprint: u64,
}

/// Everything a worker is started with.
pub struct WorkerSetup {
    /// The source.
    pub source: ResolvedSource,
    /// The daemon's namespace.
    pub namespace: Namespace,
    /// How new sessions are made, and where they are journaled.
    pub sessions: SessionSetup,
    /// Seconds between metrics reports.
    pub metrics_interval: Duration,
    /// A session with no pose for this long ends.
    pub session_timeout: Duration,
    /// Sessions with a corrector at most; a new one beyond ends one whose client is gone, or
    /// the least recently active if it has gone quiet ([`quiet_after`]), or else waits for a
    /// place.
    pub max_sessions: usize,
    /// Set to stop.
    pub shutdown: Arc<AtomicBool>,
    /// `CLOCK_MONOTONIC` of the worker's last loop (ns), for the watchdog.
    pub heartbeat: Arc<AtomicU64>,
    /// Tile reloads.
    pub reloads: Receiver<Reload>,
}

/// A live session and its answer ports. Pass-through sources keep no corrector, nor does a
/// session waiting for a place.
struct Live {
    session: Option<Session>,
    /// Whether it waits for a place among the source's `max_sessions`: its poses are answered
    /// `pass_through` with the reason `sessions_full` until it gets one.
    waiting: bool,
    // Ports before the services they belong to.
    publisher: Publisher<Ipc, CorrectedPose, ()>,
    notifier: Notifier<Ipc>,
    services: SessionServices<Ipc>,
    last_active: Instant,
    /// What the log told of the session's odometry jumps.
    jumps: RepeatLog,
    /// What the log told of the steps the session's corrector took for poses missing.
    poses_missing: RepeatLog,
}

/// How long a session has had no pose before a new session may take its place among the
/// source's `max_sessions`: three of the source's periods (`odometry_rate_hz`), at least a
/// second. Sessions that still stream keep their places; otherwise two clients of a source set
/// for one session ended each other's session with every pose, and neither was ever corrected.
pub fn quiet_after(params: &Params) -> Duration {
    Duration::from_secs_f64((3.0 / params.odometry_rate_hz).max(1.0))
}

struct Worker {
    name: String,
    setup: WorkerSetup,
    node: Node<Ipc>,
    sessions: HashMap<u64, Live>,
    metrics: SourceMetrics,
    summary: WorkerSummary,
    journal_warned: bool,
}

impl Worker {
    fn open_session(&self, id: u64, session: Option<Session>) -> Result<Live, String> {
        // Room first: iceoryx2 writes to the session's files as it makes them.
        shm::check_room("a session", shm::DAEMON_SESSION_BYTES).map_err(|e| error_line(&e))?;
        let services = SessionServices::open(&self.node, &self.setup.source.name, id)
            .map_err(|e| error_line(&e))?;
        let publisher = services.publisher().map_err(|e| error_line(&e))?;
        let notifier = services.notifier().map_err(|e| error_line(&e))?;
        shm::reserve(&self.setup.namespace).map_err(|e| error_line(&e))?;
        Ok(Live {
            session,
            waiting: false,
            publisher,
            notifier,
            services,
            last_active: Instant::now(),
            jumps: RepeatLog::default(),
            poses_missing: RepeatLog::default(),
        })
    }

    fn journal_failed(&mut self, failure: Option<JournalFailure>) {
        if let Some(JournalFailure(e)) = failure {
            self.metrics.journal_failures += 1;
            if !self.journal_warned {
                self.journal_warned = true;
                tracing::error!(source = %self.name, error = %error_line(&e), "journal write failed: sessions go on without crash recovery");
            }
        }
    }

    fn end_session(&mut self, id: u64, why: &str) {
        if let Some(mut live) = self.sessions.remove(&id) {
            if let Some(watch) = live.session.as_mut().map(|s| &mut s.watch) {
                let news = watch.finish();
                tell(&self.name, id, watch, news);
            }
            if let Some(untold) = live.jumps.finish() {
                tell_untold(&self.name, id, Repeat::Jump, untold);
            }
            if let Some(untold) = live.poses_missing.finish() {
                tell_untold(&self.name, id, Repeat::PosesMissing, untold);
            }
            tracing::info!(source = %self.name, session = format_args!("{id:016x}"), why, "session ended");
            let dir = live.session.as_ref().and_then(|s| s.journal_dir());
            if let (Some(dir), Some(p)) = (dir, &self.setup.sessions.persistence) {
                let _ = p.send(PersistJob::Remove {
                    dir: dir.to_path_buf(),
                });
            }
        }
    }

    fn remove_journal(&self, dir: PathBuf) {
        if let Some(p) = &self.setup.sessions.persistence {
            let _ = p.send(PersistJob::Remove { dir });
        }
    }

    /// Restores every journaled session of the source (the newest journal of each); removes
    /// the journals that cannot be restored.
    fn restore_sessions(&mut self) {
        let Some(root) = self.setup.sessions.journal_dir.clone() else {
            return;
        };
        let started = Instant::now();
        let mut newest: HashMap<u64, Session> = HashMap::new();
        for entry in std::fs::read_dir(&root).into_iter().flatten().flatten() {
            let dir = entry.path();
            match session::restore(&dir, &self.setup.sessions) {
                Ok(session) => {
                    let older = match newest.get(&session.id) {
                        Some(kept) if kept.created_unix_ns >= session.created_unix_ns => {
                            Some(session)
                        }
                        _ => newest.insert(session.id, session),
                    };
                    if let Some(dir) = older.as_ref().and_then(|s| s.journal_dir()) {
                        self.remove_journal(dir.to_path_buf());
                    }
                }
                Err(e) => {
                    tracing::warn!(source = %self.name, dir = %dir.display(), error = %error_line(&e), "a journal was not restored; its session starts afresh");
                    self.remove_journal(dir);
                }
            }
        }
        for (id, session) in newest {
            let next = session.expected_seq();
            match self.open_session(id, Some(session)) {
                Ok(live) => {
                    tracing::info!(source = %self.name, session = format_args!("{id:016x}"), next_seq = next, "session restored");
                    self.sessions.insert(id, live);
                    self.summary.restored += 1;
                }
                Err(e) => {
                    tracing::warn!(source = %self.name, error = %e, "a restored session could not be served")
                }
            }
        }
        if self.summary.restored > 0 {
            tracing::info!(source = %self.name, sessions = self.summary.restored, restore_ms = started.elapsed().as_secs_f64() * 1e3, "sessions restored");
        }
    }

    /// Makes sure the input's session is live: started when it is new (at its first pose, 1)
    /// or when the client starts it afresh, given a corrector once a place frees when it waits
    /// for one (from the pose that finds the place). False when it cannot be answered at all.
    fn ensure_live(&mut self, input: &OdomPose) -> bool {
        let fresh = session::starts_afresh(input);
        if fresh {
            self.end_session(input.session, "the client started it afresh");
        }
        if let Some(waiting) = self.sessions.get(&input.session).map(|l| l.waiting) {
            if waiting && self.make_place() {
                let session = self.start_session(input.session, input.seq);
                if let Some(live) = self.sessions.get_mut(&input.session) {
                    (live.session, live.waiting) = (session, false);
                }
                tracing::info!(source = %self.name, session = format_args!("{:016x}", input.session), seq = input.seq, "a session that waited has a place: corrected from this pose on");
            }
            return true;
        }
        let placed = self.make_place();
        // The ports first: a session that cannot be answered starts no corrector or journal.
        let live = match self.open_session(input.session, None) {
            Ok(live) => live,
            Err(e) => {
                if self.metrics.unserved == 0 {
                    tracing::warn!(source = %self.name, session = format_args!("{:016x}", input.session), error = %e, "cannot answer a session (said once per metrics interval; `unserved` counts the poses)");
                }
                self.metrics.unserved += 1;
                return false;
            }
        };
        let live = if placed {
            let session = self.start_session(input.session, session::first_seq(input));
            Live { session, ..live }
        } else {
            tracing::warn!(source = %self.name, session = format_args!("{:016x}", input.session), max_sessions = self.setup.max_sessions, "a new session waits for a place: the source's max_sessions sessions all had a pose lately; its poses are answered uncorrected (pass_through, reason sessions_full) until one ends or goes quiet");
            Live {
                waiting: true,
                ..live
            }
        };
        self.sessions.insert(input.session, live);
        true
    }

    /// Whether a session may start a corrector: fewer than `max_sessions` have one, or one of
    /// those lost its client (no one subscribes to its answers: the client died and what its
    /// node held was removed, by the daemon's supervisor within 500 ms or by iceoryx2 as soon as
    /// any process makes a node, as a new client does), or the least recently active of those
    /// has gone quiet ([`quiet_after`]); that one then ends.
    fn make_place(&mut self) -> bool {
        let placed = self.sessions.iter().filter(|(_, l)| !l.waiting);
        if placed.clone().count() < self.setup.max_sessions {
            return true;
        }
        let orphan = placed.clone().find(|(_, l)| l.services.subscribers() == 0);
        if let Some((&orphan, _)) = orphan {
            self.end_session(
                orphan,
                "its client is gone (more sessions than max_sessions)",
            );
            return true;
        }
        let Some((oldest, since)) = placed
            .map(|(&id, l)| (id, l.last_active))
            .min_by_key(|&(_, last_active)| last_active)
        else {
            return true;
        };
        if since.elapsed() < quiet_after(&self.setup.sessions.params) {
            return false;
        }
        self.end_session(oldest, "more sessions than max_sessions");
        true
    }

    /// The corrector (and journal) of a session that begins at `first_seq`; none for a
    /// pass-through source.
    fn start_session(&mut self, id: u64, first_seq: u64) -> Option<Session> {
        self.metrics.new_sessions += 1;
        if self.setup.source.pass_through {
            return None;
        }
        let (session, failure) = Session::start(id, first_seq, &self.setup.sessions);
        self.journal_failed(failure);
        Some(session)
    }

    /// Answers one pose (a goodbye, [`FLAG_END_SESSION`], ends its session instead); then
    /// readies its session for the next, and does the session's work ahead when `queued`
    /// (asked after publishing) says no pose waits. A session on a grid asks it too, while a
    /// map it asked for is pending (`GridView::arrived`).
    fn serve(&mut self, input: OdomPose, received: u64, queued: impl Fn() -> bool) {
        if input.flags & FLAG_END_SESSION != 0 {
            if self.sessions.contains_key(&input.session) {
                self.metrics.closed_sessions += 1;
                self.end_session(input.session, "closed by its client");
            }
            return;
        }
        self.summary.received += 1;
        if !self.ensure_live(&input) {
            return;
        }
        let setup = &self.setup.sessions;
        let Some(live) = self.sessions.get_mut(&input.session) else {
            return;
        };
        live.last_active = Instant::now();
        let (mut answer, outcome, timing, failure) = match &mut live.session {
            None => {
                let mut answer = session::pass_through(&input, received, setup.daemon_epoch);
                if live.waiting {
                    answer.reason = ReasonCode::SessionsFull as u32;
                    self.metrics.waiting += 1;
                }
                (answer, Outcome::PassThrough, Default::default(), None)
            }
            Some(session) => {
                let (handled, failure) = session.handle(&input, received, setup, &queued);
                self.metrics.uncovered_queries += handled.uncovered_queries;
                self.metrics.map_swaps += u64::from(handled.map_swapped);
                self.metrics.map_waits += u64::from(handled.map_waited);
                (handled.answer, handled.outcome, handled.timing, failure)
            }
        };
        answer.published_mono_ns = monotonic_ns();
        let in_daemon_ns = answer.published_mono_ns.saturating_sub(received);
        tracing::debug!(source = %self.name, session = format_args!("{:016x}", input.session), seq = input.seq, status = StatusCode::from_code(answer.status).map_or("", StatusCode::name), in_daemon_us = in_daemon_ns as f64 / 1e3, "pose");
        let delivered = match live.publisher.send_copy(answer) {
            Ok(0) => false,
            Ok(_) => {
                if let Err(e) = live.notifier.notify() {
                    tracing::warn!(source = %self.name, error = %error_line(&e), "notify failed");
                }
                true
            }
            Err(e) => {
                tracing::warn!(source = %self.name, seq = answer.seq, error = %error_line(&e), "publish failed");
                false
            }
        };
        if let Some(session) = live.session.as_mut() {
            if let Some(news) = session.watch_answered(&input, &outcome) {
                tell(&self.name, input.session, &session.watch, news);
            }
        }
        if let Outcome::Corrected(status) = outcome {
            let at = RepeatAt {
                source: &self.name,
                session: input.session,
                seq: input.seq,
                params: &setup.params,
            };
            if let Status::OdometryJump { .. } = status {
                at.tell(Repeat::Jump, &mut live.jumps);
            }
            if live
                .session
                .as_ref()
                .is_some_and(Session::took_poses_missing)
            {
                at.tell(Repeat::PosesMissing, &mut live.poses_missing);
            }
        }
        if delivered {
            self.summary.published += 1;
        } else {
            self.summary.undelivered += 1;
            self.metrics.undelivered += 1;
        }
        // Off the latency path: what the session's next pose needs, and its work ahead only
        // when no pose waits (while poses queue it would delay them).
        let prepare_failure = live.session.as_mut().and_then(|s| {
            let failure = s.prepare(setup);
            if !queued() {
                s.work_ahead();
            }
            failure
        });
        self.journal_failed(failure);
        self.journal_failed(prepare_failure);
        self.metrics.record(
            &outcome,
            answer.published_mono_ns.saturating_sub(input.sent_mono_ns),
            in_daemon_ns,
            &timing,
        );
    }

    /// Ends the sessions without a pose for the session timeout, and those waiting for a place
    /// that have gone quiet ([`quiet_after`]): their clients left, and a waiting session, which
    /// holds no corrector or journal to resume, keeps its ports no longer than that.
    fn end_idle_sessions(&mut self) {
        let timeout = self.setup.session_timeout;
        let quiet = quiet_after(&self.setup.sessions.params);
        let idle: Vec<(u64, &str)> = self
            .sessions
            .iter()
            .filter_map(|(&id, l)| {
                let since = l.last_active.elapsed();
                if since > timeout {
                    Some((id, "idle"))
                } else if l.waiting && since >= quiet {
                    Some((id, "waited for a place and went quiet"))
                } else {
                    None
                }
            })
            .collect();
        for (id, why) in idle {
            self.end_session(id, why);
        }
    }
}

/// What a session's odometry repeats that the log tells at most once every [`TOLD_EVERY`].
#[derive(Clone, Copy)]
enum Repeat {
    /// A jump (status `odometry_jump`).
    Jump,
    /// A step taken for poses missing.
    PosesMissing,
}

/// Where a repeat happened: the pose `seq` of session `session` of source `source`, corrected
/// under `params`.
struct RepeatAt<'a> {
    source: &'a str,
    session: u64,
    seq: u64,
    params: &'a Params,
}

impl RepeatAt<'_> {
    /// Logs `what` here when `log` (the session's log of it) is due to tell it, with the repeats
    /// it did not tell since.
    fn tell(&self, what: Repeat, log: &mut RepeatLog) {
        let Some(told) = log.repeated(self.seq, Instant::now()) else {
            return;
        };
        let RepeatAt {
            source,
            session,
            seq,
            params,
        } = *self;
        if let Some(untold) = told.untold_before {
            tell_untold(source, session, what, untold);
        }
        let every_s = TOLD_EVERY.as_secs();
        match what {
            Repeat::Jump => {
                tracing::warn!(source = %source, session = format_args!("{session:016x}"), seq, max_speed_mps = params.max_speed_mps, "the odometry jumped: it lies farther from its last pose than the vehicle can drive; its poses go on from where the vehicle was (status odometry_jump; this log tells one jump of a session in {every_s} s at most)")
            }
            Repeat::PosesMissing => {
                tracing::warn!(source = %source, session = format_args!("{session:016x}"), seq, max_speed_mps = params.max_speed_mps, odometry_rate_hz = params.odometry_rate_hz, "a step of the odometry was taken for poses missing: longer than max_speed_mps allows in one period of odometry_rate_hz, it drove on as the step before, and the stamps are no clock (they advance by less than half a period); a pose that glitched straight ahead reads the same, so its covariance covers that; real stamps have each step judged by its time (this log tells one such step of a session in {every_s} s at most)")
            }
        }
    }
}

/// Logs the repeats of `what` in `session` that the log did not tell (see [`RepeatLog`]).
fn tell_untold(source: &str, session: u64, what: Repeat, untold: Untold) {
    let Untold {
        count,
        first_seq,
        last_seq,
    } = untold;
    match what {
        Repeat::Jump => {
            tracing::warn!(source = %source, session = format_args!("{session:016x}"), jumps = count, first_seq, last_seq, "the odometry jumped {count} more times since the last jump told (status odometry_jump; sequence numbers {first_seq} to {last_seq})")
        }
        Repeat::PosesMissing => {
            tracing::warn!(source = %source, session = format_args!("{session:016x}"), steps = count, first_seq, last_seq, "{count} more steps of the odometry were taken for poses missing since the last one told (sequence numbers {first_seq} to {last_seq})")
        }
    }
}

/// Logs what `watch` told of session `session` of source `source` (`news`): what is wrong with
/// its setup (the rate its stamps say when the source is set for another, its poses moving as no
/// vehicle does in the source's frame or faster than any, few alignments accepted), and each
/// change of speed no car makes, with its sequence number.
fn tell(source: &str, session: u64, watch: &SessionWatch, news: SessionNews) {
    for warning in news.warnings {
        tracing::warn!(source = %source, session = format_args!("{session:016x}"), "{warning}");
    }
    let rate_hz = watch.speed_rate_hz();
    for change in news.speed_changes {
        let seq = watch.seq_of(&change);
        tracing::warn!(source = %source, session = format_args!("{session:016x}"), seq, from_mps = change.from_mps, to_mps = change.to_mps, rate_hz, "the odometry's speed changed faster than a car's can (more than {MAX_ACCELERATION_MPS2} m/s^2 over {SPEED_SPAN_S} s, the poses taken to come at rate_hz: their stamps' rate, or odometry_rate_hz where they tell none): it probably lost track; where the lanes run straight the corrections cannot show how far the vehicle went meanwhile, and the poses after it may be off along the road; where the source watches stalls (watch_stalls), a fall restarts its window and widens the covariance along the road by the distance missed at the speed before it and the heading by what a car may turn there");
    }
}

/// Runs a source until `shutdown` is set. Tells `ready` once its ports exist and its sessions
/// are restored (or why it could not start) before serving.
pub fn run(setup: WorkerSetup, ready: Sender<Result<(), WorkerError>>) -> WorkerSummary {
    let name = setup.source.name.to_string();
    let start = || -> Result<_, WorkerError> {
        if let Some(dir) = &setup.sessions.journal_dir {
            std::fs::create_dir_all(dir).map_err(|source| WorkerError::Journal {
                name: name.clone(),
                dir: dir.clone(),
                source,
            })?;
        }
        // Room first: iceoryx2 writes to the source's files as it makes them.
        let no_room = |source| WorkerError::SharedMemory {
            name: name.clone(),
            source,
        };
        shm::check_room("a source", shm::SOURCE_BYTES).map_err(no_room)?;
        let node = setup
            .namespace
            .daemon_node()
            .map_err(|source| WorkerError::Node {
                name: name.clone(),
                source,
            })?;
        let services = PoseServices::open(&node, &setup.source.name).map_err(|source| {
            WorkerError::Service {
                name: name.clone(),
                source,
            }
        })?;
        let port = |source| WorkerError::Port {
            name: name.clone(),
            source,
        };
        let subscriber = services.subscriber().map_err(port)?;
        let listener = services.listener().map_err(port)?;
        shm::reserve(&setup.namespace).map_err(no_room)?;
        Ok((node, services, subscriber, listener))
    };
    let (node, _services, subscriber, listener) = match start() {
        Ok(ports) => ports,
        Err(e) => {
            // The daemon is waiting for this; if it is gone, there is no one left to tell.
            let _ = ready.send(Err(e));
            return WorkerSummary::default();
        }
    };
    let mut worker = Worker {
        name: name.clone(),
        setup,
        node,
        sessions: HashMap::new(),
        metrics: SourceMetrics::default(),
        summary: WorkerSummary::default(),
        journal_warned: false,
    };
    let wait = worker.setup.source.wait;
    if let Err(e) = wait.pin_current_thread() {
        let _ = ready.send(Err(WorkerError::Wait { name, source: e }));
        return WorkerSummary::default();
    }
    worker.restore_sessions();
    let _ = ready.send(Ok(()));
    let s = &worker.setup.source;
    tracing::info!(source = %name, method = s.corrector.method.name(), preset = s.corrector.preset.name(), pass_through = s.pass_through, wait = %wait, "worker started");
    let mut next_report = Instant::now() + worker.setup.metrics_interval;
    loop {
        worker
            .setup
            .heartbeat
            .store(monotonic_ns(), Ordering::Relaxed);
        // On shutdown, answer what is already queued once more, then stop.
        let stopping = worker.setup.shutdown.load(Ordering::Relaxed);
        if !stopping {
            // An interrupted wait (a signal) is a wake-up like any other; a failed look for
            // samples too (the receive below reports it).
            wait.wait(
                WAKE_UP,
                || subscriber.has_samples().unwrap_or(true),
                |left| {
                    let _ = listener.timed_wait(|_| {}, left);
                },
            );
        }
        while let Ok(reload) = worker.setup.reloads.try_recv() {
            worker.setup.sessions.map = reload.map;
            worker.setup.sessions.grid = reload.grid;
            worker.setup.sessions.fingerprint = reload.fingerprint;
            tracing::info!(source = %name, running_sessions = worker.sessions.len(), "new sessions use the reloaded tile; running sessions keep theirs");
        }
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(sample)) => sample,
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(source = %name, error = %error_line(&e), "receive failed");
                    break;
                }
            };
            let received = monotonic_ns();
            let input = *sample;
            drop(sample);
            worker.serve(input, received, || {
                subscriber.has_samples().unwrap_or(false)
            });
        }
        if wait.spins() {
            // Notifications this loop did not sleep on: drop them before they pile up.
            let _ = listener.try_wait(|_| {});
        }
        if stopping {
            break;
        }
        worker.end_idle_sessions();
        if Instant::now() >= next_report {
            worker.metrics.sessions = worker.sessions.len() as u64;
            worker.metrics.report(&name);
            next_report += worker.setup.metrics_interval;
        }
    }
    worker.metrics.sessions = worker.sessions.len() as u64;
    worker.metrics.report(&name);
    let summary = worker.summary;
    tracing::info!(source = %name, received = summary.received, published = summary.published, undelivered = summary.undelivered, "worker stopped");
    summary
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_statuses_carry_the_correctors_names() {
        let statuses = [
            Status::WarmingUp { window_len: 3 },
            Status::Accepted {
                residual_m: 0.1,
                applied_directions: 3,
                match_ratio: 0.9,
                window_len: 200,
            },
            Status::Rejected {
                reason: RejectReason::TooFewMatches,
                residual_m: f64::INFINITY,
                match_ratio: 0.1,
                window_len: 199,
            },
            Status::Reset {
                reason: RejectReason::ResidualTooLarge,
                residual_m: 3.0,
                match_ratio: 0.8,
                window_len: 149,
            },
            Status::InvalidInput,
            Status::Carried { window_len: 150 },
            Status::OdometryJump { window_len: 150 },
        ];
        assert_eq!(statuses.len(), Status::NAMES.len());
        for s in statuses {
            let (code, reason) = wire_status(&s);
            assert_eq!(code.name(), s.name());
            assert_eq!(reason.name(), s.reason().map_or("", RejectReason::name));
        }
    }
}
