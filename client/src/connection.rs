//! A connection to one source of the daemon: one session, its poses out, its answers in.

use std::collections::hash_map::RandomState;
use std::hash::{BuildHasher, Hasher};
use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierNotifyError};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{ReceiveError as PortReceiveError, SendError};
use iceoryx2::prelude::ipc;
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::{CorrectedPose, OdomPose};
use lanealign_wire::service::{
    NameError, Namespace, NodeCreateError, PortCreateError, ServiceOpenError, SourceName,
    SourceServices,
};

/// Shortest wait handed to iceoryx2: a shorter remainder is not waited for at all (a wait that
/// rounds to zero at the socket would block until the next event).
const MIN_WAIT: Duration = Duration::from_micros(10);

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
}

/// Publishing a pose failed.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
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
}

/// A fresh session id: non-zero, random per call (from the standard library's per-process
/// random hasher keys), mixed with the process id and the clock.
pub fn new_session_id() -> u64 {
    let mut h = RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u64(monotonic_ns());
    h.finish().max(1)
}

/// An odometry process's connection to one source of the daemon, in one session: the daemon
/// runs a fresh corrector for a new session, and only this session's answers are returned.
/// Not `Send`: create it on the thread that uses it (iceoryx2 ports are bound to their thread).
pub struct Connection {
    session: u64,
    // Ports first: they must be dropped before the node that owns them.
    publisher: Publisher<ipc::Service, OdomPose, ()>,
    notifier: Notifier<ipc::Service>,
    subscriber: Subscriber<ipc::Service, CorrectedPose, ()>,
    listener: Listener<ipc::Service>,
    services: SourceServices,
    _node: Node<ipc::Service>,
}

impl Connection {
    /// Connects to `source` in the default namespace, in a new session.
    pub fn connect(source: &str) -> Result<Self, ConnectError> {
        Self::connect_in(&Namespace::default(), &source.parse()?, new_session_id())
    }

    /// Connects to `source` in `namespace`, in session `session` (a new one from
    /// [`new_session_id`], or an earlier one to resume its corrector). Works whether the daemon
    /// is up yet or not.
    pub fn connect_in(
        namespace: &Namespace,
        source: &SourceName,
        session: u64,
    ) -> Result<Self, ConnectError> {
        let node = namespace.node()?;
        let services = SourceServices::open(&node, source)?;
        Ok(Connection {
            session: session.max(1),
            publisher: services.odom_publisher()?,
            notifier: services.odom_notifier()?,
            subscriber: services.corrected_subscriber()?,
            listener: services.corrected_listener()?,
            services,
            _node: node,
        })
    }

    /// This connection's session id.
    pub fn session(&self) -> u64 {
        self.session
    }

    /// True when a daemon serves this source.
    pub fn daemon_connected(&self) -> bool {
        self.services.daemon_serving()
    }

    /// Publishes pose `seq` of this session (row-major 3x4 `[R | t]` in the source's axis
    /// convention, metres; `stamp_ns` the sensor time) and wakes the daemon.
    pub fn publish(&self, seq: u64, stamp_ns: i64, pose: &[f64; 12]) -> Result<(), PublishError> {
        self.publisher
            .send_copy(OdomPose {
                session: self.session,
                seq,
                stamp_ns,
                sent_mono_ns: monotonic_ns(),
                pose: *pose,
            })
            .map_err(PublishError::Send)?;
        self.notifier.notify().map_err(PublishError::Notify)?;
        Ok(())
    }

    /// The next answer of this session if one is waiting (answers of other sessions on the
    /// same source are skipped).
    pub fn try_recv(&self) -> Result<Option<CorrectedPose>, ReceiveError> {
        loop {
            match self.subscriber.receive().map_err(ReceiveError::Receive)? {
                Some(sample) if sample.session == self.session => return Ok(Some(*sample)),
                Some(_) => continue,
                None => return Ok(None),
            }
        }
    }

    /// The next answer of this session, waiting (without polling) up to `timeout` for one.
    pub fn recv(&self, timeout: Duration) -> Result<Option<CorrectedPose>, ReceiveError> {
        if let Some(pose) = self.try_recv()? {
            return Ok(Some(pose));
        }
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left < MIN_WAIT {
                return self.try_recv();
            }
            self.listener
                .timed_wait(|_| {}, left)
                .map_err(ReceiveError::Wait)?;
            if let Some(pose) = self.try_recv()? {
                return Ok(Some(pose));
            }
        }
    }
}
