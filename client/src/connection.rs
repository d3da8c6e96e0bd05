//! A connection to one source of the daemon: one session, its poses out, its answers in, and
//! nothing lost on the way.
//!
//! The connection numbers the session's poses 1, 2, 3, ... and keeps every pose until its answer
//! arrives. It keeps at most [`MAX_IN_FLIGHT`] in flight (so no buffer on the way can overflow):
//! beyond that [`Connection::publish`] says the connection is full instead of blocking the odometry
//! thread. When the answers it waits for are silent for 100 ms, or come from another daemon run
//! than before, it checks which daemon is alive (iceoryx2 sees a killed process at once); when a
//! daemon comes back (or another replaces it) it sends every unanswered pose again, in order. The
//! daemon answers each pose of a session once and sends the same answer again for a pose sent
//! twice; answers the connection already has are dropped, so each pose is answered exactly once.

use std::collections::hash_map::RandomState;
use std::collections::BTreeMap;
use std::hash::{BuildHasher, Hasher};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierNotifyError};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{ReceiveError as PortReceiveError, SendError};
use lanealign_wire::clock::{deadline_after, monotonic_ns, time_left};
use lanealign_wire::payload::{
    CorrectedPose, OdomPose, StatusCode, FLAG_END_SESSION, FLAG_FRESH_START, MAX_IN_FLIGHT,
};
use lanealign_wire::service::{
    DaemonNode, NameError, Namespace, NodeCreateError, NodeListError, OtherWireError,
    PortCreateError, PoseServices, ServiceOpenError, SessionServices, SourceName, ThreadSafeIpc,
};
use lanealign_wire::shm::{self, ShmError};
use lanealign_wire::wait::WaitStrategy;

/// Shortest wait handed to iceoryx2: a shorter remainder is not waited for at all (a wait that
/// rounds to zero at the socket would block until the next event).
const MIN_WAIT: Duration = Duration::from_micros(10);
/// How long answers in flight may be silent before the daemon's liveness is checked, and how
/// often it is checked at most.
const LIVENESS_PERIOD: Duration = Duration::from_millis(100);

/// Connecting failed.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The source name or namespace is not usable.
    #[error(transparent)]
    Name(#[from] NameError),
    /// The iceoryx2 node could not be created.
    #[error(transparent)]
    Node(#[from] NodeCreateError),
    /// A service could not be opened.
    #[error(transparent)]
    Service(#[from] ServiceOpenError),
    /// A port could not be created.
    #[error(transparent)]
    Port(#[from] PortCreateError),
    /// Looking for the daemon failed.
    #[error(transparent)]
    Liveness(#[from] NodeListError),
    /// Shared memory has no room for a session.
    #[error(transparent)]
    SharedMemory(#[from] ShmError),
    /// The namespace's daemon is of another lanealign version: it could answer nothing.
    #[error(transparent)]
    OtherWire(#[from] OtherWireError),
}

/// Publishing a pose failed.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// [`MAX_IN_FLIGHT`] poses are unanswered: receive answers (or wait for the daemon) first.
    #[error("{in_flight} poses are waiting for answers: receive some before publishing more")]
    Full {
        /// Poses in flight.
        in_flight: u64,
    },
    /// The sample could not be sent.
    #[error("sending a pose failed")]
    Send(#[source] SendError),
    /// The daemon could not be woken.
    #[error("notifying the daemon failed")]
    Notify(#[source] NotifierNotifyError),
}

/// Receiving answers failed.
#[derive(Debug, thiserror::Error)]
pub enum ReceiveError {
    /// Taking a sample failed.
    #[error("receiving an answer failed")]
    Receive(#[source] PortReceiveError),
    /// Waiting for an answer failed.
    #[error("waiting for an answer failed")]
    Wait(#[source] ListenerWaitError),
    /// Sending unanswered poses again failed.
    #[error(transparent)]
    Resend(#[from] PublishError),
    /// Checking whether the daemon is alive failed.
    #[error(transparent)]
    Liveness(#[from] NodeListError),
    /// The daemon that serves the namespace now is of another lanealign version: it answers
    /// nothing of this connection's. Receiving again checks again, and goes on once a daemon of
    /// this version is back.
    #[error(transparent)]
    OtherWire(#[from] OtherWireError),
}

/// Closing a connection failed; each case keeps what the connection had: the answers that
/// arrived before the failure and the poses still unanswered ([`CloseError::closed`]).
#[derive(Debug, thiserror::Error)]
pub enum CloseError {
    /// Waiting for the answers in flight failed (no goodbye was sent).
    #[error(
        "waiting for the answers in flight failed ({} arrived before, {} unanswered)",
        closed.answers.len(),
        closed.unanswered.len()
    )]
    Receive {
        /// What failed.
        #[source]
        source: ReceiveError,
        /// What the connection had (no daemon told).
        closed: Closed,
    },
    /// The goodbye could not be sent.
    #[error("sending the session's end failed")]
    Send {
        /// What failed.
        #[source]
        source: SendError,
        /// What the connection had (no daemon told).
        closed: Closed,
    },
    /// The daemon could not be woken for the goodbye.
    #[error("notifying the daemon of the session's end failed")]
    Notify {
        /// What failed.
        #[source]
        source: NotifierNotifyError,
        /// What the connection had (no daemon told).
        closed: Closed,
    },
}

impl CloseError {
    /// What the connection had when closing failed: the answers that arrived while it closed
    /// and the poses still unanswered.
    pub fn closed(&self) -> &Closed {
        match self {
            CloseError::Receive { closed, .. }
            | CloseError::Send { closed, .. }
            | CloseError::Notify { closed, .. } => closed,
        }
    }
}

/// What a connection still had when it closed ([`Connection::close`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Closed {
    /// The answers that arrived while it waited, in arrival order: with those received before,
    /// every pose answered.
    pub answers: Vec<CorrectedPose>,
    /// The poses no answer came for within the timeout, oldest first.
    pub unanswered: Vec<u64>,
    /// Whether a daemon known to be alive took the goodbye (if none: the session ends at its
    /// `session_timeout_s`, or when a restarted daemon's `max_sessions` needs its place).
    pub daemon_told: bool,
}

/// What happened to a connection beyond plain answers: what a caller reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConnectionEvents {
    /// Times a daemon appeared for this connection after another (a restart): all unanswered
    /// poses were sent again.
    pub daemon_restarts: u64,
    /// Poses sent more than once.
    pub resent: u64,
    /// Gap answers (poses that reached a daemon before earlier ones did) followed.
    pub gaps: u64,
    /// Times the daemon no longer had the session and it was started afresh (its corrector
    /// from scratch) at the oldest unanswered pose.
    pub fresh_starts: u64,
    /// Answers received twice (dropped).
    pub duplicate_answers: u64,
    /// Times the connection listed the namespace's nodes to find its daemon: when it was made,
    /// when answers in flight were silent for 100 ms, when answers came from another daemon run
    /// than before (or the first), and for [`Connection::daemon_connected`] (at most every
    /// 100 ms).
    pub liveness_checks: u64,
}

/// A fresh session id: non-zero, random per call (from the standard library's per-process
/// random hasher keys), mixed with the process id and the clock.
pub fn new_session_id() -> u64 {
    let mut h = RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u64(monotonic_ns());
    h.finish().max(1)
}

/// A pose waiting for its answer.
#[derive(Clone, Copy)]
struct Pending {
    stamp_ns: i64,
    pose: [f64; 12],
}

/// Where a connection last resumed sending: at `from`, at `at_mono_ns`. The gap answers to poses
/// sent before then (a gap echoes its input's `sent_mono_ns`) need nothing more.
#[derive(Clone, Copy, Debug, Default)]
struct Rewind {
    from: u64,
    at_mono_ns: u64,
    /// Set when the rewind started the session afresh at `from` because the daemon run with this
    /// epoch had lost it.
    fresh_in_epoch: Option<u64>,
}

impl Rewind {
    /// Whether `gap` answers a pose sent before this rewind and asks for nothing it does not
    /// send: a pose from `from` on, or, after a fresh start, anything the same daemon run asks
    /// for (the fresh start answers it: the session begins again at `from`). Without the second
    /// case every pose in flight when a daemon lost its session would start it afresh again.
    fn covers(&self, gap: &CorrectedPose) -> bool {
        gap.sent_mono_ns < self.at_mono_ns
            && (gap.expected_seq >= self.from || self.fresh_in_epoch == Some(gap.daemon_epoch))
    }
}

/// An odometry process's connection to one source of the daemon, in one session: the daemon
/// runs a fresh corrector for a new session, and only this session's answers come here. It may
/// move to another thread, and be shared behind a lock; one thread may wait for answers while
/// another publishes ([`Connection::waiter`]).
pub struct Connection {
    namespace: Namespace,
    source: SourceName,
    session: u64,
    next_seq: u64,
    pending: BTreeMap<u64, Pending>,
    /// The oldest pending pose not (known to be) delivered: sending resumes there.
    unsent_from: u64,
    /// Send this pose with [`FLAG_FRESH_START`].
    fresh_at: Option<u64>,
    /// The highest pose ever delivered to a daemon.
    highest_sent: u64,
    /// The last rewind.
    rewound: Rewind,
    /// The living daemon's process, if one is (a daemon has several nodes, one process).
    daemon: Option<i32>,
    /// The last daemon process seen alive: a different one appearing is a restart.
    last_daemon: Option<i32>,
    last_check: Option<Instant>,
    /// When the last answer of this session arrived (or the connection was made).
    last_answer: Instant,
    /// The daemon run (`daemon_epoch`) the last answer came from.
    epoch: Option<u64>,
    /// Looking for the daemon after an answer from another daemon run failed: look again
    /// before the next wait.
    look_again: bool,
    events: ConnectionEvents,
    wait: WaitStrategy,
    ports: Arc<Ports>,
}

/// A connection's iceoryx2 side, shared with its [`AnswerWaiter`]s: they may outlive it.
struct Ports {
    // Ports first: they must be dropped before the services and the node that own them.
    publisher: Publisher<ThreadSafeIpc, OdomPose, ()>,
    notifier: Notifier<ThreadSafeIpc>,
    subscriber: Subscriber<ThreadSafeIpc, CorrectedPose, ()>,
    listener: Listener<ThreadSafeIpc>,
    poses: PoseServices<ThreadSafeIpc>,
    answers: SessionServices<ThreadSafeIpc>,
    _node: Node<ThreadSafeIpc>,
}

impl Ports {
    /// Waits until an answer may be waiting, for at most `timeout`, as `wait` says.
    fn wait(&self, wait: WaitStrategy, timeout: Duration) -> Result<(), ReceiveError> {
        if timeout < MIN_WAIT {
            return Ok(());
        }
        let (subscriber, listener) = (&self.subscriber, &self.listener);
        if wait.spins() {
            // Notifications the last spin did not sleep on: drop them while idle, before they
            // pile up.
            listener.try_wait(|_| {}).map_err(ReceiveError::Wait)?;
        }
        let mut failed = None;
        wait.wait(
            timeout,
            || subscriber.has_samples().unwrap_or(true),
            |left| {
                // An interrupted sleep is a wake-up: a signal the process handles, or the
                // process stopped and continued (SIGSTOP, SIGCONT: a debugger, Ctrl-Z).
                failed = listener
                    .timed_wait(|_| {}, left)
                    .err()
                    .filter(|e| !matches!(e, ListenerWaitError::InterruptSignal));
            },
        );
        failed.map_or(Ok(()), |e| Err(ReceiveError::Wait(e)))
    }
}

/// Waits for a connection's answers without holding the connection ([`Connection::waiter`]):
/// one thread waits while others publish on the connection, which they share behind a lock
/// taken only around [`Connection::poll`] and [`Connection::publish`]. It takes no answer;
/// `poll` does. Cheap to clone; it keeps the connection's shared memory open until dropped.
#[derive(Clone)]
pub struct AnswerWaiter {
    ports: Arc<Ports>,
    wait: WaitStrategy,
}

impl AnswerWaiter {
    /// Returns when an answer may be waiting (or a signal interrupted the wait), or after
    /// `timeout`; waits as the connection's [`WaitStrategy`] said when the waiter was made.
    pub fn wait(&self, timeout: Duration) -> Result<(), ReceiveError> {
        self.ports.wait(self.wait, timeout)
    }
}

impl Connection {
    /// Connects to `source` in the default namespace, in a new session.
    pub fn connect(source: &str) -> Result<Self, ConnectError> {
        Self::connect_in(&Namespace::default(), &source.parse()?, new_session_id())
    }

    /// Connects to `source` in `namespace`, in a new session `session` (from
    /// [`new_session_id`]), whose first pose is 1. Works whether the daemon is up yet or not.
    pub fn connect_in(
        namespace: &Namespace,
        source: &SourceName,
        session: u64,
    ) -> Result<Self, ConnectError> {
        Self::resume(namespace, source, session, 1)
    }

    /// Continues session `session` on `source` at pose `next_seq` (a process restarted after
    /// `next_seq - 1` answered poses: the daemon still has the session's corrector).
    pub fn resume(
        namespace: &Namespace,
        source: &SourceName,
        session: u64,
        next_seq: u64,
    ) -> Result<Self, ConnectError> {
        // Room first: iceoryx2 writes to a session's files as it makes them, and a write to a
        // full /dev/shm is a SIGBUS, not an error (`lanealign_wire::shm`).
        shm::check_room("a session", shm::SESSION_BYTES)?;
        let node = namespace.node()?;
        // Before the services: a daemon of another version may have made them in its layout.
        let daemon = namespace
            .daemons()?
            .first()
            .map(DaemonNode::checked_pid)
            .transpose()?;
        let poses = PoseServices::open(&node, source)?;
        let session = session.max(1);
        let answers = SessionServices::open(&node, source, session)?;
        let (publisher, notifier) = (poses.publisher()?, poses.notifier()?);
        let (subscriber, listener) = (answers.subscriber()?, answers.listener()?);
        shm::reserve(namespace)?;
        Ok(Connection {
            namespace: namespace.clone(),
            source: source.clone(),
            session,
            next_seq: next_seq.max(1),
            pending: BTreeMap::new(),
            unsent_from: next_seq.max(1),
            fresh_at: None,
            highest_sent: 0,
            rewound: Rewind::default(),
            daemon,
            last_daemon: daemon,
            last_check: Some(Instant::now()),
            last_answer: Instant::now(),
            epoch: None,
            look_again: false,
            events: ConnectionEvents {
                liveness_checks: 1,
                ..ConnectionEvents::default()
            },
            wait: WaitStrategy::Event,
            ports: Arc::new(Ports {
                publisher,
                notifier,
                subscriber,
                listener,
                poses,
                answers,
                _node: node,
            }),
        })
    }

    /// This connection's session id.
    pub fn session(&self) -> u64 {
        self.session
    }

    /// The sequence number the next pose gets.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Poses published and not answered yet, oldest first.
    pub fn in_flight(&self) -> Vec<u64> {
        self.pending.keys().copied().collect()
    }

    /// What happened beyond plain answers.
    pub fn events(&self) -> ConnectionEvents {
        self.events
    }

    /// True when the daemon has opened this session (it has a publisher of the session's
    /// answers). A daemon that serves the source but cannot open a session (no room in shared
    /// memory) says why in its log (`cannot answer a session`).
    pub fn session_opened(&self) -> bool {
        self.ports.answers.publishers() > 0
    }

    /// Why no daemon serves this connection's source, for a person: no daemon runs in the
    /// namespace, or the one that runs serves other sources (named), or it has the source and
    /// has not taken its poses yet, or its sources cannot be listed.
    pub fn why_unserved(&self) -> String {
        let (namespace, source) = (&self.namespace, &self.source);
        let daemons = match namespace.daemons() {
            Ok(daemons) => daemons,
            Err(e) => return format!("the namespace's daemons cannot be listed: {e}"),
        };
        if daemons.is_empty() {
            return format!("no daemon runs in namespace '{namespace}': start lanealignd, or name the namespace its configuration sets");
        }
        match namespace.served_sources() {
            Some(served) if !served.contains(source) => {
                let names: Vec<String> = served.iter().map(|s| format!("'{s}'")).collect();
                let serves = if names.is_empty() {
                    "no source yet".to_string()
                } else {
                    names.join(", ")
                };
                format!("the daemon of namespace '{namespace}' serves {serves}, not '{source}': check the source's name, or add it to the daemon's configuration (a restart)")
            }
            Some(_) => format!(
                "the daemon of namespace '{namespace}' serves '{source}' but has not taken its poses yet"
            ),
            None => format!(
                "a daemon runs in namespace '{namespace}', but which sources it serves cannot be listed"
            ),
        }
    }

    /// True when a living daemon serves this source.
    pub fn daemon_connected(&mut self) -> bool {
        let _ = self.check_daemon();
        self.daemon.is_some() && self.ports.poses.subscribers() > 0
    }

    /// Publishes the session's next pose (row-major 3x4 `[R | t]` in the source's axis
    /// convention, metres; `stamp_ns` the sensor time) and returns its sequence number. The
    /// pose is kept until its answer arrives and sent again if the daemon restarts.
    pub fn publish(&mut self, stamp_ns: i64, pose: &[f64; 12]) -> Result<u64, PublishError> {
        let oldest = self.pending.keys().next().copied().unwrap_or(self.next_seq);
        if self.next_seq - oldest >= MAX_IN_FLIGHT {
            return Err(PublishError::Full {
                in_flight: self.pending.len() as u64,
            });
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        self.pending.insert(
            seq,
            Pending {
                stamp_ns,
                pose: *pose,
            },
        );
        self.flush()?;
        Ok(seq)
    }

    /// Sends the pending poses not yet delivered, in order; stops at the first no daemon took.
    fn flush(&mut self) -> Result<(), PublishError> {
        let mut woke = false;
        let unsent: Vec<(u64, Pending)> = self
            .pending
            .range(self.unsent_from..)
            .map(|(&s, &p)| (s, p))
            .collect();
        for (seq, p) in unsent {
            let flags = if self.fresh_at == Some(seq) {
                FLAG_FRESH_START
            } else {
                0
            };
            let delivered = self
                .ports
                .publisher
                .send_copy(OdomPose {
                    session: self.session,
                    seq,
                    stamp_ns: p.stamp_ns,
                    sent_mono_ns: monotonic_ns(),
                    pose: p.pose,
                    flags,
                    reserved: 0,
                })
                .map_err(PublishError::Send)?;
            if delivered == 0 {
                break;
            }
            if flags != 0 {
                self.fresh_at = None;
            }
            if seq <= self.highest_sent {
                self.events.resent += 1;
            }
            self.highest_sent = self.highest_sent.max(seq);
            self.unsent_from = seq + 1;
            woke = true;
        }
        if woke {
            self.ports.notifier.notify().map_err(PublishError::Notify)?;
        }
        Ok(())
    }

    /// Sends again from pose `from` on (everything unanswered from there); `fresh_in_epoch`:
    /// the session starts afresh at `from` because the daemon run with this epoch lost it.
    fn rewind(&mut self, from: u64, fresh_in_epoch: Option<u64>) {
        self.unsent_from = self.unsent_from.min(from);
        self.rewound = Rewind {
            from,
            at_mono_ns: monotonic_ns(),
            fresh_in_epoch,
        };
    }

    /// Checks which daemon is alive when there is reason to: an answer from another daemon run
    /// than before, or poses in flight and no answer for [`LIVENESS_PERIOD`] (a daemon killed
    /// holding them). While answers come the daemon is alive, and listing the namespace's nodes
    /// is file-system work (a few hundred microseconds to milliseconds per call here) that
    /// delayed the answers arriving meanwhile.
    fn check_daemon_if_due(&mut self) -> Result<(), ReceiveError> {
        if std::mem::take(&mut self.look_again) {
            return self.look_for_daemon();
        }
        if self.pending.is_empty() || self.last_answer.elapsed() < LIVENESS_PERIOD {
            return Ok(());
        }
        self.check_daemon()
    }

    /// [`Connection::look_for_daemon`], at most every 100 ms.
    fn check_daemon(&mut self) -> Result<(), ReceiveError> {
        if self
            .last_check
            .is_some_and(|t| t.elapsed() < LIVENESS_PERIOD)
        {
            return Ok(());
        }
        self.look_for_daemon()
    }

    /// Checks which daemon is alive; when one appeared or replaced another, everything
    /// unanswered goes to it again. A daemon of another version is an error, and nothing is
    /// sent to it.
    fn look_for_daemon(&mut self) -> Result<(), ReceiveError> {
        self.last_check = Some(Instant::now());
        self.events.liveness_checks += 1;
        let now = self
            .namespace
            .daemons()?
            .first()
            .map(DaemonNode::checked_pid)
            .transpose()?;
        if now.is_some() && now != self.daemon {
            if self.last_daemon.is_some() && now != self.last_daemon {
                self.events.daemon_restarts += 1;
            }
            self.last_daemon = now;
            let oldest = self.pending.keys().next().copied().unwrap_or(self.next_seq);
            self.rewind(oldest, None);
        }
        self.daemon = now;
        Ok(())
    }

    /// The next answer of this session if one is waiting.
    pub fn try_recv(&mut self) -> Result<Option<CorrectedPose>, ReceiveError> {
        loop {
            let Some(sample) = self
                .ports
                .subscriber
                .receive()
                .map_err(ReceiveError::Receive)?
            else {
                return Ok(None);
            };
            let answer = *sample;
            drop(sample);
            if answer.session != self.session {
                continue;
            }
            self.last_answer = Instant::now();
            // Another daemon run answers (or the first): did it replace the one that had the
            // poses in flight? For a gap before acting on it; for an answer once it is taken.
            let new_run = self.epoch.replace(answer.daemon_epoch) != Some(answer.daemon_epoch);
            if answer.status() == Some(StatusCode::Gap) {
                if new_run {
                    self.look_for_daemon()?;
                }
                self.events.gaps += 1;
                if self.rewound.covers(&answer) {
                    // Sent before the last rewind, which already covers what it asks for.
                    continue;
                }
                match self.pending.keys().next().copied() {
                    // The daemon needs a pose this connection still has: send from there.
                    Some(o) if answer.expected_seq >= o => self.rewind(answer.expected_seq, None),
                    // It needs one already answered: it lost the session; start it afresh.
                    Some(o) => {
                        self.events.fresh_starts += 1;
                        self.fresh_at = Some(o);
                        self.rewind(o, Some(answer.daemon_epoch));
                    }
                    None => {}
                }
                self.flush()?;
                continue;
            }
            let answered = self.pending.remove(&answer.seq).is_some();
            if new_run {
                // Before anything more is sent. A failed look is tried again (and reported)
                // before the next wait: the answer is not lost to it.
                self.look_again = self.look_for_daemon().is_err();
            }
            if answered {
                return Ok(Some(answer));
            }
            self.events.duplicate_answers += 1;
        }
    }

    /// The next answer of this session, waiting up to `timeout` for one as the connection's
    /// [`WaitStrategy`] says (by default without polling).
    /// While waiting it checks the daemon's liveness and sends unanswered poses again when a
    /// daemon comes back.
    pub fn recv(&mut self, timeout: Duration) -> Result<Option<CorrectedPose>, ReceiveError> {
        let deadline = deadline_after(timeout);
        loop {
            if let Some(answer) = self.poll()? {
                return Ok(Some(answer));
            }
            let left = time_left(deadline);
            if left < MIN_WAIT {
                return self.try_recv();
            }
            self.ports.wait(self.wait, left.min(LIVENESS_PERIOD))?;
        }
    }

    /// What [`Connection::recv`] does between its waits: the next answer if one is waiting;
    /// if none, checks the daemon's liveness when due and sends unanswered poses again to a
    /// daemon that came back. A loop of `poll` and [`AnswerWaiter::wait`] (at most 100 ms a
    /// wait, so that liveness is checked) is `recv` with the connection free between them.
    pub fn poll(&mut self) -> Result<Option<CorrectedPose>, ReceiveError> {
        if let Some(answer) = self.try_recv()? {
            return Ok(Some(answer));
        }
        self.check_daemon_if_due()?;
        self.flush()?;
        Ok(None)
    }

    /// Waits for this connection's answers without borrowing it, as its [`WaitStrategy`] says
    /// now: for a thread that waits while others publish.
    pub fn waiter(&self) -> AnswerWaiter {
        AnswerWaiter {
            ports: Arc::clone(&self.ports),
            wait: self.wait,
        }
    }

    /// Ends the session: waits up to `timeout` for the answers of the poses in flight (returned,
    /// so none is lost), then tells the daemon the session is over, and it forgets the session
    /// at once (its corrector, its journal) instead of after `session_timeout_s`. A connection
    /// dropped without closing leaves its session to be resumed ([`Connection::resume`]) until
    /// then.
    pub fn close(mut self, timeout: Duration) -> Result<Closed, CloseError> {
        let deadline = deadline_after(timeout);
        let mut answers = Vec::new();
        while !self.pending.is_empty() {
            // `recv` comes back empty only at its deadline.
            match self.recv(time_left(deadline)) {
                Ok(Some(answer)) => answers.push(answer),
                Ok(None) => break,
                Err(source) => {
                    let closed = self.closed_with(answers);
                    return Err(CloseError::Receive { source, closed });
                }
            }
        }
        // A killed daemon's subscriber takes samples until its node is cleaned up: ask which
        // daemon lives (a failed look tells no one).
        let looked = self.look_for_daemon().is_ok();
        let mut closed = self.closed_with(answers);
        let goodbye = OdomPose {
            session: self.session,
            seq: self.next_seq,
            stamp_ns: 0,
            sent_mono_ns: monotonic_ns(),
            pose: [f64::NAN; 12],
            flags: FLAG_END_SESSION,
            reserved: 0,
        };
        let taken = match self.ports.publisher.send_copy(goodbye) {
            Ok(receivers) => receivers > 0,
            Err(source) => return Err(CloseError::Send { source, closed }),
        };
        if taken {
            if let Err(source) = self.ports.notifier.notify() {
                return Err(CloseError::Notify { source, closed });
            }
        }
        closed.daemon_told = taken && looked && self.daemon.is_some();
        Ok(closed)
    }

    /// What the connection has when it closes: `answers` and the poses still unanswered, no
    /// daemon told yet.
    fn closed_with(&self, answers: Vec<CorrectedPose>) -> Closed {
        Closed {
            answers,
            unanswered: self.pending.keys().copied().collect(),
            daemon_told: false,
        }
    }

    /// How [`Connection::recv`] waits for answers (default: sleeps until notified). A strategy
    /// that names a core does not pin the caller: call [`WaitStrategy::pin_current_thread`] on
    /// the thread that receives.
    pub fn set_wait_strategy(&mut self, wait: WaitStrategy) {
        self.wait = wait;
    }
}
