//! Talking to `lanealignd` from an odometry process: publish poses, receive corrections.
//!
//! ```no_run
//! use std::time::Duration;
//! use lanealign_client::connection::{monotonic_ns, Connection};
//! use lanealign_client::wire::OdomPose;
//!
//! let conn = Connection::connect("lidar")?;
//! let identity = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
//! conn.publish(&OdomPose { seq: 1, stamp_ns: 0, sent_mono_ns: monotonic_ns(), pose: identity })?;
//! if let Some(corrected) = conn.recv(Duration::from_millis(100))? {
//!     println!("seq {} corrected to {:?}", corrected.seq, corrected.pose);
//! }
//! # Ok::<(), lanealign_client::connection::ConnectionError>(())
//! ```

use std::time::Duration;

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::port_factory::PortFactory as _;

use crate::wire::{CorrectedPose, OdomPose};

/// Samples a subscriber can hold before the oldest is overwritten (per source and direction).
pub const BUFFER_SIZE: usize = 4096;
/// Subscribers of one source's corrected poses at most.
pub const MAX_SUBSCRIBERS: usize = 16;
/// Publishers of one service at most (a restarted process may briefly overlap its old ports).
pub const MAX_PUBLISHERS: usize = 4;
/// Shortest wait handed to iceoryx2: a shorter remainder is not waited for at all.
const MIN_WAIT: Duration = Duration::from_micros(10);

/// Nodes per service at most.
pub const MAX_NODES: usize = 32;

/// Something went wrong talking to the daemon.
#[derive(Debug, thiserror::Error)]
pub enum ConnectionError {
    /// The source name does not make a valid service name.
    #[error("source name '{0}' is not usable in a service name")]
    BadSourceName(String),
    /// An iceoryx2 node could not be created.
    #[error("creating the iceoryx2 node failed: {0}")]
    Node(String),
    /// A service could not be opened or created (for example with incompatible settings).
    #[error("opening service '{service}' failed: {message}")]
    Service {
        /// The service name.
        service: String,
        /// iceoryx2's message.
        message: String,
    },
    /// A port could not be created.
    #[error("creating a {port} on '{service}' failed: {message}")]
    Port {
        /// What kind of port.
        port: &'static str,
        /// The service name.
        service: String,
        /// iceoryx2's message.
        message: String,
    },
    /// A sample could not be sent.
    #[error("sending failed: {0}")]
    Send(String),
    /// Receiving failed.
    #[error("receiving failed: {0}")]
    Receive(String),
}

/// `CLOCK_MONOTONIC` now, in nanoseconds: comparable across the processes of one machine.
pub fn monotonic_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// The names of a source's services: `(odom, corrected)`.
pub fn service_names(source: &str) -> (String, String) {
    (
        format!("lanealign/{source}/odom"),
        format!("lanealign/{source}/corrected"),
    )
}

fn service_name(name: &str, source: &str) -> Result<ServiceName, ConnectionError> {
    ServiceName::new(name).map_err(|_| ConnectionError::BadSourceName(source.to_string()))
}

/// Opens (or creates) a publish-subscribe service with the settings both sides agree on.
pub fn pubsub_service<T: std::fmt::Debug + ZeroCopySend + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
    source: &str,
) -> Result<PortFactory<ipc::Service, T, ()>, ConnectionError> {
    node.service_builder(&service_name(name, source)?)
        .publish_subscribe::<T>()
        .subscriber_max_buffer_size(BUFFER_SIZE)
        .max_subscribers(MAX_SUBSCRIBERS)
        .max_publishers(MAX_PUBLISHERS)
        .max_nodes(MAX_NODES)
        .open_or_create()
        .map_err(|e| ConnectionError::Service {
            service: name.to_string(),
            message: format!("{e:?}"),
        })
}

/// Opens (or creates) the event service that goes with a publish-subscribe service.
pub fn event_service(
    node: &Node<ipc::Service>,
    name: &str,
    source: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, ConnectionError> {
    node.service_builder(&service_name(name, source)?)
        .event()
        .max_nodes(MAX_NODES)
        .max_notifiers(MAX_SUBSCRIBERS)
        .max_listeners(MAX_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| ConnectionError::Service {
            service: name.to_string(),
            message: format!("{e:?}"),
        })
}

/// An odometry process's connection to one source of the daemon. Not `Send`: create it on the
/// thread that uses it (iceoryx2 ports are bound to their thread).
pub struct Connection {
    // Ports first: they must be dropped before the node that owns them.
    publisher: Publisher<ipc::Service, OdomPose, ()>,
    notifier: Notifier<ipc::Service>,
    subscriber: Subscriber<ipc::Service, CorrectedPose, ()>,
    listener: Listener<ipc::Service>,
    corrected_service: PortFactory<ipc::Service, CorrectedPose, ()>,
    _node: Node<ipc::Service>,
}

impl Connection {
    /// Connects to source `source`: opens (or creates) its services, so it works whether the
    /// daemon is up yet or not, and keeps working across daemon restarts.
    pub fn connect(source: &str) -> Result<Self, ConnectionError> {
        let node = NodeBuilder::new()
            .create::<ipc::Service>()
            .map_err(|e| ConnectionError::Node(format!("{e:?}")))?;
        let (odom, corrected) = service_names(source);
        let port = |port: &'static str, service: &str| {
            let service = service.to_string();
            move |e: &dyn std::fmt::Debug| ConnectionError::Port {
                port,
                service,
                message: format!("{e:?}"),
            }
        };
        let odom_service = pubsub_service::<OdomPose>(&node, &odom, source)?;
        let publisher = odom_service
            .publisher_builder()
            .create()
            .map_err(|e| port("publisher", &odom)(&e))?;
        let notifier = event_service(&node, &odom, source)?
            .notifier_builder()
            .create()
            .map_err(|e| port("notifier", &odom)(&e))?;
        let corrected_service = pubsub_service::<CorrectedPose>(&node, &corrected, source)?;
        let subscriber = corrected_service
            .subscriber_builder()
            .create()
            .map_err(|e| port("subscriber", &corrected)(&e))?;
        let listener = event_service(&node, &corrected, source)?
            .listener_builder()
            .create()
            .map_err(|e| port("listener", &corrected)(&e))?;
        Ok(Connection {
            publisher,
            notifier,
            subscriber,
            listener,
            corrected_service,
            _node: node,
        })
    }

    /// True when a daemon serves this source: its worker creates the corrected-pose publisher
    /// after every port that receives, so poses published from now on are all seen.
    pub fn daemon_connected(&self) -> bool {
        self.corrected_service
            .dynamic_config()
            .number_of_publishers()
            > 0
    }

    /// Publishes a pose and wakes the daemon.
    pub fn publish(&self, pose: &OdomPose) -> Result<(), ConnectionError> {
        self.publisher
            .send_copy(*pose)
            .map_err(|e| ConnectionError::Send(format!("{e:?}")))?;
        self.notifier
            .notify()
            .map_err(|e| ConnectionError::Send(format!("{e:?}")))?;
        Ok(())
    }

    /// The next corrected pose if one is waiting.
    pub fn try_recv(&self) -> Result<Option<CorrectedPose>, ConnectionError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(*sample)),
            Ok(None) => Ok(None),
            Err(e) => Err(ConnectionError::Receive(format!("{e:?}"))),
        }
    }

    /// The next corrected pose, waiting (without polling) up to `timeout` for one.
    pub fn recv(&self, timeout: Duration) -> Result<Option<CorrectedPose>, ConnectionError> {
        if let Some(pose) = self.try_recv()? {
            return Ok(Some(pose));
        }
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            // A timeout that rounds to zero at the socket would mean "wait forever" there.
            if left < MIN_WAIT {
                return self.try_recv();
            }
            self.listener
                .timed_wait(|_| {}, left)
                .map_err(|e| ConnectionError::Receive(format!("{e:?}")))?;
            if let Some(pose) = self.try_recv()? {
                return Ok(Some(pose));
            }
        }
    }
}
