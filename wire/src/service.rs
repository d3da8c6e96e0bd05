//! Where the payloads travel: a deployment's namespace, each source's services, the limits both
//! sides open them with, and the ports on them.
//!
//! Per source `NAME`: `lanealign/NAME/odom` (publish-subscribe of [`OdomPose`], clients to the
//! daemon), and per session `lanealign/NAME/session/SESSION` ([`CorrectedPose`], the daemon to
//! that session's client alone), each with an event service of the same name that is notified
//! after every sample. Buffers never overwrite: a sample that does not fit is not delivered, and
//! the sender sees it. A [`Namespace`] is an iceoryx2 file prefix: daemons and clients of
//! different namespaces never see each other.

use std::fmt;
use std::str::FromStr;

use iceoryx2::node::{Node, NodeBuilder, NodeCreationFailure, NodeState, NodeView};
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::port::listener::{Listener, ListenerCreateError};
use iceoryx2::port::notifier::{Notifier, NotifierCreateError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::prelude::SignalHandlingMode;
use iceoryx2::prelude::{
    CallbackProgression, FileName, NodeName, Path as IoxPath, SemanticString, ServiceName,
};
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event, publish_subscribe, PortFactory as _};
use iceoryx2::service::service_name::ServiceNameError;
use iceoryx2::service::Service;

use crate::payload::{CorrectedPose, OdomPose};

/// Samples a subscriber holds per publisher (twice [`crate::payload::MAX_IN_FLIGHT`]); a sample
/// that does not fit is not delivered rather than overwriting an older one.
pub const BUFFER_SIZE: usize = 1024;
/// Publishers of a source's pose service at most: its clients.
pub const MAX_POSE_PUBLISHERS: usize = 16;
/// Subscribers of a source's pose service at most: the daemon's worker (and a restarted
/// daemon's, while the dead one's port is not yet cleaned up).
pub const MAX_POSE_SUBSCRIBERS: usize = 4;
/// Publishers and subscribers of a session's answer service at most: the daemon and the
/// session's client (and a restarted daemon's port, and a monitor).
pub const MAX_SESSION_PORTS: usize = 4;
/// Nodes per service at most.
pub const MAX_NODES: usize = 64;
/// Notifiers and listeners of one event service at most.
pub const MAX_EVENT_PORTS: usize = 32;
/// Longest source name (characters).
pub const MAX_SOURCE_NAME_LEN: usize = 64;
/// Longest namespace (characters): the longest whose iceoryx2 event sockets always fit in a
/// Unix socket's path (below), however many ports a long-running daemon has made.
pub const MAX_NAMESPACE_LEN: usize = (SOCKET_PATH_MAX
    - NAMESPACES_FOLDER.len()
    - ROOT_PREFIX.len()
    - "/".len()
    - FILE_PREFIX.len()
    - "_".len()
    - EVENT_SOCKET_NAME_MAX)
    / 2;

/// The folder below which each namespace has its iceoryx2 folder: the shared-memory file
/// system ([`crate::shm::SHM_DIR`]), which age-based cleaners of temporary files (systemd-tmpfiles' stock rule for
/// `/tmp` removes what nobody touched for 10 days) leave alone, and which processes with a
/// private `/tmp` (systemd's `PrivateTmp=`) share with the daemon.
const NAMESPACES_FOLDER: &str = "/dev/shm/";
/// A namespace's folder is `lanealign-<namespace>/` in [`NAMESPACES_FOLDER`].
const ROOT_PREFIX: &str = "lanealign-";
/// A namespace's iceoryx2 files begin `lanealign_<namespace>_`.
const FILE_PREFIX: &str = "lanealign_";
/// The longest path of a Unix socket (bytes): `sun_path` holds 108 with its terminating NUL.
const SOCKET_PATH_MAX: usize = 107;
/// The longest name of an iceoryx2 event socket after the file prefix: a listener's id, a
/// `u128` in decimal (39 digits at most; it grows with the ports a process has made), and
/// `.event`. The socket lies in the namespace's folder.
const EVENT_SOCKET_NAME_MAX: usize = 39 + ".event".len();

/// A name that cannot be a source name or a namespace.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{what} '{name}': {problem}")]
pub struct NameError {
    /// `source name` or `namespace`.
    pub what: &'static str,
    /// The name given (at most 80 characters of it).
    pub name: String,
    /// What is wrong with it.
    pub problem: String,
}

fn check_name(what: &'static str, s: &str, max: usize) -> Result<(), NameError> {
    let error = |problem: String| NameError {
        what,
        name: s.chars().take(80).collect(),
        problem,
    };
    if s.is_empty() {
        return Err(error("must not be empty".into()));
    }
    if s.chars().count() > max {
        return Err(error(format!("longer than {max} characters")));
    }
    if let Some(c) = s
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '-' || *c == '_'))
    {
        return Err(error(format!(
            "'{c}' is not allowed: use letters, digits, '-' and '_'"
        )));
    }
    Ok(())
}

/// An odometry source's name: 1 to 64 ASCII letters, digits, `-` and `_`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SourceName(String);

impl FromStr for SourceName {
    type Err = NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        check_name("source name", s, MAX_SOURCE_NAME_LEN)?;
        Ok(SourceName(s.to_string()))
    }
}

impl fmt::Display for SourceName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl SourceName {
    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The source's pose service, `lanealign/NAME/odom`.
    pub fn odom_service(&self) -> String {
        format!("lanealign/{}/odom", self.0)
    }

    /// The answer service of one session, `lanealign/NAME/session/SESSION` (16 hex digits).
    pub fn session_service(&self, session: u64) -> String {
        format!("lanealign/{}/session/{session:016x}", self.0)
    }

    /// The source whose pose service is `service`, if it is one.
    pub fn of_odom_service(service: &str) -> Option<SourceName> {
        service
            .strip_prefix("lanealign/")
            .and_then(|r| r.strip_suffix("/odom"))
            .and_then(|name| name.parse().ok())
    }
}

/// A deployment's namespace: 1 to [`MAX_NAMESPACE_LEN`] ASCII letters, digits, `-` and `_`;
/// `default` unless configured. Its iceoryx2 files live in a folder of its own,
/// `/dev/shm/lanealign-<namespace>/`, with the file prefix `lanealign_<namespace>_` in
/// `/dev/shm`: deployments of different users or purposes never share or see each other's
/// files.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Namespace(String);

impl Default for Namespace {
    fn default() -> Self {
        Namespace("default".into())
    }
}

impl FromStr for Namespace {
    type Err = NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        check_name("namespace", s, MAX_NAMESPACE_LEN)?;
        Ok(Namespace(s.to_string()))
    }
}

impl fmt::Display for Namespace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// An iceoryx2 node could not be created.
#[derive(Debug, thiserror::Error)]
#[error("creating an iceoryx2 node in namespace '{namespace}' failed{hint}")]
pub struct NodeCreateError {
    /// The namespace.
    pub namespace: String,
    /// What to check, when something can be said (permissions on the shared-memory files).
    pub hint: String,
    /// iceoryx2's error.
    #[source]
    pub source: NodeCreationFailure,
}

impl Namespace {
    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The iceoryx2 file prefix of this namespace.
    pub fn prefix(&self) -> String {
        format!("{FILE_PREFIX}{}_", self.0)
    }

    /// The namespace's iceoryx2 root folder (node and service records, event sockets):
    /// `/dev/shm/lanealign-<namespace>/`.
    pub fn root_path(&self) -> String {
        format!("{NAMESPACES_FOLDER}{ROOT_PREFIX}{}/", self.0)
    }

    /// The namespace's iceoryx2 files that exist: its root folder and its shared-memory files
    /// in `/dev/shm`, which iceoryx2 names by the [`Namespace::prefix`] and a 40-digit hex hash.
    /// The hash is checked too: names may hold `_`, so the prefix of namespace `a` begins the
    /// files of namespace `a_b` as well.
    pub fn files(&self) -> Vec<std::path::PathBuf> {
        let root = std::path::PathBuf::from(self.root_path());
        let prefix = self.prefix();
        let shm = std::fs::read_dir(crate::shm::SHM_DIR)
            .into_iter()
            .flatten()
            .flatten();
        root.exists()
            .then_some(root)
            .into_iter()
            .chain(
                shm.filter(|e| owns_shm_name(&prefix, &e.file_name().to_string_lossy()))
                    .map(|e| e.path()),
            )
            .collect()
    }

    /// The namespace's shared-memory files in `/dev/shm` that this process has mapped, from
    /// `/proc/self/maps`: the files it may write to, found without reading all of `/dev/shm`
    /// as [`Namespace::files`] does (3.5 ms with 20000 files of other software there, against
    /// 0.016 ms: `cargo bench -p lanealign-client --bench connect`). `None` when the process's
    /// mappings cannot be read.
    pub fn mapped_files(&self) -> Option<Vec<std::path::PathBuf>> {
        let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
        let dir = format!("{}/", crate::shm::SHM_DIR);
        let prefix = self.prefix();
        let mut files: Vec<std::path::PathBuf> = maps
            .lines()
            .filter_map(|line| line.split_once(&dir).map(|(_, name)| name))
            .filter(|name| !name.ends_with(" (deleted)") && owns_shm_name(&prefix, name))
            .map(|name| std::path::PathBuf::from(format!("{dir}{name}")))
            .collect();
        files.sort();
        files.dedup();
        Some(files)
    }

    /// Every file and folder of the namespace ([`Namespace::files`] and what its folder holds,
    /// at any depth), with its metadata (not following links). An entry that vanishes while
    /// being listed is left out.
    pub fn entries(&self) -> Vec<(std::path::PathBuf, std::fs::Metadata)> {
        let mut out = Vec::new();
        let mut stack = self.files();
        while let Some(path) = stack.pop() {
            let Ok(meta) = std::fs::symlink_metadata(&path) else {
                continue;
            };
            if meta.is_dir() {
                let entries = std::fs::read_dir(&path).into_iter().flatten().flatten();
                stack.extend(entries.map(|e| e.path()));
            }
            out.push((path, meta));
        }
        out
    }

    /// Removes the namespace's iceoryx2 files ([`Namespace::files`]). iceoryx2 keeps a
    /// namespace's management state after its last process has left, by design; a namespace
    /// made for one run (`lanealign demo`, `lanealign soak`, a test) should go with the run.
    /// Only for a namespace no process uses any more. Files already gone are no error; the
    /// first other failure is returned, after trying the rest.
    pub fn remove_files(&self) -> std::io::Result<()> {
        let mut result = Ok(());
        for path in self.files() {
            let removed = if path.is_dir() {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
            match removed {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => result = result.and(Err(e)),
                _ => {}
            }
        }
        result
    }

    /// iceoryx2's configuration for this namespace: its defaults with this namespace's root
    /// folder and file prefix.
    pub fn config(&self) -> iceoryx2::config::Config {
        let mut config = iceoryx2::config::Config::default();
        // Checked names are short and plain, so both are always valid.
        if let Ok(prefix) = FileName::new(self.prefix().as_bytes()) {
            config.global.prefix = prefix;
        }
        if let Ok(root) = IoxPath::new(self.root_path().as_bytes()) {
            config.global.set_root_path(&root);
        }
        config
    }

    /// A new, unnamed node in this namespace, of service variant `S` ([`Ipc`], [`ThreadSafeIpc`]).
    pub fn node<S: Service>(&self) -> Result<Node<S>, NodeCreateError> {
        self.named_node("")
    }
}

/// A source's service could not be opened or created.
#[derive(Debug, thiserror::Error)]
pub enum ServiceOpenError {
    /// The service name is not valid for iceoryx2.
    #[error("'{service}' is not a valid service name")]
    Name {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: ServiceNameError,
    },
    /// A publish-subscribe service exists with another payload type than this build's: the
    /// other side was built from another version of lanealign.
    #[error("publish-subscribe service '{service}' exists with another layout of its payload than this build's {type_name} ({size} bytes): a client and a daemon of different lanealign versions (docs/wire.md gives this version's layout; rebuild the older side)")]
    IncompatibleLayout {
        /// The service name.
        service: String,
        /// The payload's type name, as this build declares it.
        type_name: &'static str,
        /// The payload's size in this build (bytes).
        size: usize,
    },
    /// A publish-subscribe service could not be opened or created (for example because it
    /// exists with other settings).
    #[error("opening publish-subscribe service '{service}' failed")]
    PublishSubscribe {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    /// An event service could not be opened or created.
    #[error("opening event service '{service}' failed")]
    Event {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: EventOpenOrCreateError,
    },
}

/// A port could not be created on a source's service.
#[derive(Debug, thiserror::Error)]
pub enum PortCreateError {
    /// The source has as many clients as its pose service takes.
    #[error("source '{source_name}' has {MAX_POSE_PUBLISHERS} clients connected, the most one source takes: close one (the daemon frees a killed client's place within a second)")]
    SourceFull {
        /// The source.
        source_name: SourceName,
    },
    /// A publisher.
    #[error("creating a publisher on '{service}' failed")]
    Publisher {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: PublisherCreateError,
    },
    /// A subscriber.
    #[error("creating a subscriber on '{service}' failed")]
    Subscriber {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: SubscriberCreateError,
    },
    /// A notifier.
    #[error("creating a notifier on '{service}' failed")]
    Notifier {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: NotifierCreateError,
    },
    /// A listener.
    #[error("creating a listener on '{service}' failed")]
    Listener {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        #[source]
        source: ListenerCreateError,
    },
}

/// The daemon's iceoryx2 service variant: inter-process, each port used by the one thread that
/// owns it (a worker owns its ports).
pub type Ipc = iceoryx2::service::ipc::Service;
/// The clients' variant: [`Ipc`] with ports that may move to and be shared by other threads,
/// each behind a mutex of its own (on the client's side alone within the noise of a busy-spin
/// round trip; about a microsecond more with the daemon's ports on it too: docs/performance.md).
/// Its files and their layout are [`Ipc`]'s: either side may use either variant, and other
/// languages' bindings offer both.
pub type ThreadSafeIpc = iceoryx2::service::ipc_threadsafe::Service;

/// A publish-subscribe service of payload `T`, on service variant `S` ([`Ipc`],
/// [`ThreadSafeIpc`]).
pub type PubSubService<S, T> = publish_subscribe::PortFactory<S, T, ()>;
/// An event service on service variant `S`.
pub type EventService<S> = event::PortFactory<S>;

fn service_name(service: &str) -> Result<ServiceName, ServiceOpenError> {
    ServiceName::new(service).map_err(|source| ServiceOpenError::Name {
        service: service.to_string(),
        source,
    })
}

fn pubsub<S: Service, T: fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static>(
    node: &Node<S>,
    service: &str,
    (publishers, subscribers): (usize, usize),
) -> Result<PubSubService<S, T>, ServiceOpenError> {
    node.service_builder(&service_name(service)?)
        .publish_subscribe::<T>()
        .enable_safe_overflow(false)
        .subscriber_max_buffer_size(BUFFER_SIZE)
        .max_subscribers(subscribers)
        .max_publishers(publishers)
        .max_nodes(MAX_NODES)
        .open_or_create()
        .map_err(|source| match source {
            PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                PublishSubscribeOpenError::IncompatibleTypes,
            ) => ServiceOpenError::IncompatibleLayout {
                service: service.to_string(),
                type_name: std::any::type_name::<T>(),
                size: std::mem::size_of::<T>(),
            },
            source => ServiceOpenError::PublishSubscribe {
                service: service.to_string(),
                source,
            },
        })
}

fn events<S: Service>(node: &Node<S>, service: &str) -> Result<EventService<S>, ServiceOpenError> {
    node.service_builder(&service_name(service)?)
        .event()
        .max_nodes(MAX_NODES)
        .max_notifiers(MAX_EVENT_PORTS)
        .max_listeners(MAX_EVENT_PORTS)
        .open_or_create()
        .map_err(|source| ServiceOpenError::Event {
            service: service.to_string(),
            source,
        })
}

/// What the node names of every `lanealignd` begin with: clients find the daemon by it. A daemon
/// from before [`WIRE_VERSION`] was named this alone.
pub const DAEMON_NODE: &str = "lanealignd";

/// The version of this build's wire: the layout and meaning of the payloads on a source's and a
/// session's services (docs/wire.md). It grows by one with every change to either; a client and
/// a daemon exchange poses only when theirs are equal. 2: the answer of 288 bytes, with the
/// odometry's scale (2026-11-27). 3: a `pass_through` answer's reason may be `sessions_full`
/// (2026-11-29). 4: the answer of 296 bytes, with the session's warnings (2026-12-02). A daemon carries it in its nodes' names ([`daemon_node_name`]), so a client
/// knows the daemon's before it sends a pose.
pub const WIRE_VERSION: u32 = 4;

/// The name of this build's daemon nodes: [`DAEMON_NODE`], then ` wire `, then
/// [`WIRE_VERSION`].
pub fn daemon_node_name() -> String {
    format!("{DAEMON_NODE}{WIRE_TAG}{WIRE_VERSION}")
}

/// A program's version line: `package_version`, then this build's [`WIRE_VERSION`] (what
/// `lanealign --version` and `lanealignd --version` print), so that an operator can tell which
/// clients and daemons can talk.
pub fn version_line(package_version: &str) -> String {
    format!("{package_version} (wire {WIRE_VERSION})")
}

/// What separates [`DAEMON_NODE`] from the version in a daemon node's name.
const WIRE_TAG: &str = " wire ";

/// The wire version a daemon node's name says, if `name` is one: `Some(None)` for a daemon from
/// before versions were named (or one whose version this build cannot read), `None` for a node
/// that is not a daemon's.
fn daemon_wire_of(name: &str) -> Option<Option<u32>> {
    let rest = name.strip_prefix(DAEMON_NODE)?;
    if rest.is_empty() {
        return Some(None);
    }
    Some(rest.strip_prefix(WIRE_TAG)?.parse().ok())
}

/// The daemon node `state` is, if it is one and alive.
fn living_daemon(state: &NodeState<Ipc>) -> Option<DaemonNode> {
    let NodeState::Alive(view) = state else {
        return None;
    };
    let details = view.details().as_ref()?;
    Some(DaemonNode {
        id: view.id().value(),
        pid: details.process_id().value(),
        wire: daemon_wire_of(details.name().as_str())?,
    })
}

/// A node of a running daemon, as a client sees it (a daemon has one node per worker and one
/// for its supervisor, all in one process).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DaemonNode {
    /// The node's iceoryx2 id.
    pub id: u128,
    /// The daemon's process id: a restarted daemon has a new one.
    pub pid: i32,
    /// The daemon's [`WIRE_VERSION`], as its node's name says; `None` for a daemon from before
    /// versions were named (one of wire 1 or 2), or one whose name's version cannot be read.
    pub wire: Option<u32>,
}

impl DaemonNode {
    /// Whether this daemon speaks this build's wire: it can answer this build's clients.
    pub fn speaks_this_wire(&self) -> bool {
        self.wire == Some(WIRE_VERSION)
    }

    /// The daemon's process id, or an error unless it speaks this build's wire.
    pub fn checked_pid(&self) -> Result<i32, OtherWireError> {
        if self.speaks_this_wire() {
            return Ok(self.pid);
        }
        Err(OtherWireError {
            pid: self.pid,
            wire: self.wire,
        })
    }
}

/// The namespace's daemon speaks another wire than this build: it cannot answer this build's
/// poses (iceoryx2 connects no ports whose payloads differ), so nothing would come back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the daemon of this namespace (pid {pid}) speaks {}, this build wire {WIRE_VERSION}: a client and a daemon of different lanealign versions exchange nothing; upgrade them together (docs/wire.md)", wire_name(*.wire))]
pub struct OtherWireError {
    /// The daemon's process id.
    pub pid: i32,
    /// The daemon's [`WIRE_VERSION`]; `None` for a daemon from before versions were named.
    pub wire: Option<u32>,
}

/// How a daemon's wire version (a [`DaemonNode::wire`]) is named in messages.
pub fn wire_name(wire: Option<u32>) -> String {
    match wire {
        Some(wire) => format!("wire {wire}"),
        None => "a wire from before versions were named (1 or 2)".into(),
    }
}

/// Listing the namespace's nodes failed.
#[derive(Debug, thiserror::Error)]
#[error("listing the nodes of namespace '{namespace}' failed")]
pub struct NodeListError {
    /// The namespace.
    pub namespace: String,
    /// iceoryx2's error.
    #[source]
    pub source: iceoryx2::node::NodeListFailure,
}

impl Namespace {
    /// A new node in this namespace, named `name`. It handles no signal: iceoryx2's handlers
    /// (installed by a node's first wait) would replace the process's own for a dozen signals,
    /// and they keep one "last signal" for all, so that a SIGCONT after a SIGTERM (systemd's
    /// stop) erased the request. The daemon handles SIGINT and SIGTERM itself.
    pub fn named_node<S: Service>(&self, name: &str) -> Result<Node<S>, NodeCreateError> {
        self.node_with(&self.config(), name)
    }

    /// A node of the daemon ([`daemon_node_name`]), as [`Namespace::named_node`] but leaving
    /// the namespace's dead nodes to the daemon's supervisor, which removes them every half
    /// second. By default iceoryx2 looks at every node of the namespace whenever a node is made
    /// or dropped; with a worker's node per source, a daemon of 256 sources took 1.8-2.0 s from
    /// its tile to ready and 2.9-3.2 s from SIGTERM to exit, against 0.57-0.66 s and 0.69-0.75 s
    /// so (six pairs of runs, interleaved, 2026-11-29).
    pub fn daemon_node<S: Service>(&self) -> Result<Node<S>, NodeCreateError> {
        let mut config = self.config();
        config.global.node.cleanup_dead_nodes_on_creation = false;
        config.global.node.cleanup_dead_nodes_on_destruction = false;
        self.node_with(&config, &daemon_node_name())
    }

    /// A node named `name` (unnamed if it is not a valid node name) made with `config`.
    fn node_with<S: Service>(
        &self,
        config: &iceoryx2::config::Config,
        name: &str,
    ) -> Result<Node<S>, NodeCreateError> {
        let error = |source| NodeCreateError {
            namespace: self.0.clone(),
            hint: ownership_hint(self),
            source,
        };
        let builder = NodeBuilder::new()
            .config(config)
            .signal_handling_mode(SignalHandlingMode::Disabled);
        match NodeName::new(name) {
            Ok(n) => builder.name(&n).create::<S>().map_err(error),
            Err(_) => builder.create::<S>().map_err(error),
        }
    }

    /// The living daemons of this namespace (normally none or one).
    pub fn daemons(&self) -> Result<Vec<DaemonNode>, NodeListError> {
        let mut found = Vec::new();
        Node::<Ipc>::list(&self.config(), |state| {
            found.extend(living_daemon(&state));
            CallbackProgression::Continue
        })
        .map_err(|source| NodeListError {
            namespace: self.0.clone(),
            source,
        })?;
        Ok(found)
    }

    /// The sources a living daemon of this namespace serves (one of its nodes is attached to
    /// the source's pose service), in name order; for telling a client that names another one
    /// what there is. `None` when the namespace's services cannot be listed.
    pub fn served_sources(&self) -> Option<Vec<SourceName>> {
        let mut served = std::collections::BTreeSet::new();
        Ipc::list(&self.config(), |service| {
            let name = service.static_details.name().to_string();
            let by_daemon = service
                .dynamic_details
                .as_ref()
                .is_some_and(|d| d.nodes.iter().any(|node| living_daemon(node).is_some()));
            if let Some(source) = SourceName::of_odom_service(&name).filter(|_| by_daemon) {
                served.insert(source);
            }
            CallbackProgression::Continue
        })
        .ok()?;
        Some(served.into_iter().collect())
    }
}

/// Whether `name`, a file name in `/dev/shm`, is a shared-memory file of the namespace whose
/// iceoryx2 file prefix is `prefix`: the prefix, then a 40-digit hex hash. The hash is checked
/// too: names may hold `_`, so the prefix of namespace `a` begins the files of `a_b` as well.
fn owns_shm_name(prefix: &str, name: &str) -> bool {
    name.strip_prefix(prefix).is_some_and(|rest| {
        rest.len() >= 40 && rest.bytes().take(40).all(|b| b.is_ascii_hexdigit())
    })
}

/// Who owns `namespace`'s files ([`Namespace::files`], and everything in its root folder), when
/// it is not this process's user: what a permission error means, and what to do. Empty when
/// nothing can be said.
fn ownership_hint(namespace: &Namespace) -> String {
    let me = rustix::process::geteuid().as_raw();
    let owners: std::collections::BTreeSet<u32> = namespace
        .entries()
        .iter()
        .map(|(_, meta)| std::os::unix::fs::MetadataExt::uid(meta))
        .filter(|&uid| uid != me)
        .collect();
    if owners.is_empty() {
        return String::new();
    }
    let (root, prefix) = (namespace.root_path(), namespace.prefix());
    let names: Vec<String> = owners
        .iter()
        .map(|&uid| match user_name(uid) {
            Some(name) => format!("'{name}' (uid {uid})"),
            None => format!("uid {uid}"),
        })
        .collect();
    format!(
        ": the namespace's files ({root} and {prefix}* in /dev/shm) belong to {}, and this process runs as uid {me}: run it as that user (a deployment's daemon and clients share one user), or run a deployment of your own in another namespace (docs/operations.md, \"Access\")",
        names.join(", ")
    )
}

/// The user name of `uid`, from /etc/passwd.
fn user_name(uid: u32) -> Option<String> {
    let passwd = std::fs::read_to_string("/etc/passwd").ok()?;
    passwd.lines().find_map(|line| {
        let fields: Vec<&str> = line.split(':').collect();
        (fields.get(2)? == &uid.to_string().as_str()).then(|| fields[0].to_string())
    })
}

/// Where a client publishes a source's poses and the daemon takes them; ports of service
/// variant `S`.
pub struct PoseServices<S: Service> {
    source: SourceName,
    odom: PubSubService<S, OdomPose>,
    odom_events: EventService<S>,
}

impl<S: Service> PoseServices<S> {
    /// Opens or creates `source`'s pose services on `node`.
    pub fn open(node: &Node<S>, source: &SourceName) -> Result<Self, ServiceOpenError> {
        let odom = source.odom_service();
        Ok(PoseServices {
            source: source.clone(),
            odom: pubsub(node, &odom, (MAX_POSE_PUBLISHERS, MAX_POSE_SUBSCRIBERS))?,
            odom_events: events(node, &odom)?,
        })
    }

    /// The source.
    pub fn source(&self) -> &SourceName {
        &self.source
    }

    /// Subscribers of the poses (the daemon's worker, once it runs).
    pub fn subscribers(&self) -> usize {
        self.odom.dynamic_config().number_of_subscribers()
    }

    /// Client side: publishes poses.
    pub fn publisher(&self) -> Result<Publisher<S, OdomPose, ()>, PortCreateError> {
        self.odom
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|source| match source {
                PublisherCreateError::ExceedsMaxSupportedPublishers => {
                    PortCreateError::SourceFull {
                        source_name: self.source.clone(),
                    }
                }
                source => PortCreateError::Publisher {
                    service: self.source.odom_service(),
                    source,
                },
            })
    }

    /// Client side: wakes the daemon after a pose.
    pub fn notifier(&self) -> Result<Notifier<S>, PortCreateError> {
        self.odom_events
            .notifier_builder()
            .create()
            .map_err(|source| PortCreateError::Notifier {
                service: self.source.odom_service(),
                source,
            })
    }

    /// Daemon side: receives poses.
    pub fn subscriber(&self) -> Result<Subscriber<S, OdomPose, ()>, PortCreateError> {
        self.odom
            .subscriber_builder()
            .create()
            .map_err(|source| PortCreateError::Subscriber {
                service: self.source.odom_service(),
                source,
            })
    }

    /// Daemon side: waits for poses.
    pub fn listener(&self) -> Result<Listener<S>, PortCreateError> {
        self.odom_events
            .listener_builder()
            .create()
            .map_err(|source| PortCreateError::Listener {
                service: self.source.odom_service(),
                source,
            })
    }
}

/// Where the daemon answers one session of a source, and only that session's client listens;
/// ports of service variant `S`.
pub struct SessionServices<S: Service> {
    service: String,
    answers: PubSubService<S, CorrectedPose>,
    answer_events: EventService<S>,
}

impl<S: Service> SessionServices<S> {
    /// Opens or creates the answer services of `session` on `source`.
    pub fn open(
        node: &Node<S>,
        source: &SourceName,
        session: u64,
    ) -> Result<Self, ServiceOpenError> {
        let service = source.session_service(session);
        Ok(SessionServices {
            answers: pubsub(node, &service, (MAX_SESSION_PORTS, MAX_SESSION_PORTS))?,
            answer_events: events(node, &service)?,
            service,
        })
    }

    /// Publishers of the session's answers: the daemon's, once it has opened the session.
    pub fn publishers(&self) -> usize {
        self.answers.dynamic_config().number_of_publishers()
    }

    /// Subscribers to the session's answers: its client's, until the client closes the session
    /// or dies and its node's resources are removed.
    pub fn subscribers(&self) -> usize {
        self.answers.dynamic_config().number_of_subscribers()
    }

    /// Daemon side: publishes the session's answers.
    pub fn publisher(&self) -> Result<Publisher<S, CorrectedPose, ()>, PortCreateError> {
        self.answers
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|source| PortCreateError::Publisher {
                service: self.service.clone(),
                source,
            })
    }

    /// Daemon side: wakes the client after an answer.
    pub fn notifier(&self) -> Result<Notifier<S>, PortCreateError> {
        self.answer_events
            .notifier_builder()
            .create()
            .map_err(|source| PortCreateError::Notifier {
                service: self.service.clone(),
                source,
            })
    }

    /// Client side: receives the session's answers.
    pub fn subscriber(&self) -> Result<Subscriber<S, CorrectedPose, ()>, PortCreateError> {
        self.answers
            .subscriber_builder()
            .create()
            .map_err(|source| PortCreateError::Subscriber {
                service: self.service.clone(),
                source,
            })
    }

    /// Client side: waits for answers.
    pub fn listener(&self) -> Result<Listener<S>, PortCreateError> {
        self.answer_events
            .listener_builder()
            .create()
            .map_err(|source| PortCreateError::Listener {
                service: self.service.clone(),
                source,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_daemon_nodes_name_carries_its_wire_version() {
        assert_eq!(
            daemon_node_name(),
            format!("lanealignd wire {WIRE_VERSION}")
        );
        assert_eq!(
            daemon_wire_of(&daemon_node_name()),
            Some(Some(WIRE_VERSION))
        );
        assert_eq!(daemon_wire_of("lanealignd wire 1"), Some(Some(1)));
        // A daemon from before versions were named, and one whose version cannot be read: both
        // daemons, of another wire than this build's.
        assert_eq!(daemon_wire_of("lanealignd"), Some(None));
        assert_eq!(daemon_wire_of("lanealignd wire x"), Some(None));
        for other in [
            "",
            "lanealign",
            "lanealignd-test",
            "replay",
            "lanealignd wire",
        ] {
            assert_eq!(daemon_wire_of(other), None, "{other}");
        }
        let node = |wire| DaemonNode {
            id: 1,
            pid: 7,
            wire,
        };
        assert!(node(Some(WIRE_VERSION)).checked_pid().is_ok());
        let older = node(Some(WIRE_VERSION - 1)).checked_pid().unwrap_err();
        assert_eq!(older.to_string(), format!("the daemon of this namespace (pid 7) speaks wire {}, this build wire {WIRE_VERSION}: a client and a daemon of different lanealign versions exchange nothing; upgrade them together (docs/wire.md)", WIRE_VERSION - 1));
    }

    #[test]
    fn a_namespace_removes_its_own_files_and_not_those_of_a_name_it_begins() {
        let name = format!("f{}", std::process::id());
        let (a, a_b): (Namespace, Namespace) =
            (name.parse().unwrap(), format!("{name}_b").parse().unwrap());
        let hash = "9204dd183d1c4d8e1ff592a30766ffa6765aa8b5";
        let fake = |n: &Namespace| {
            std::fs::create_dir_all(format!("{}nodes", n.root_path())).unwrap();
            let shm = std::path::PathBuf::from(format!("/dev/shm/{}{hash}_node", n.prefix()));
            std::fs::write(&shm, b"x").unwrap();
            shm
        };
        let (shm_a, shm_a_b) = (fake(&a), fake(&a_b));
        let root = |n: &Namespace| std::path::PathBuf::from(n.root_path());
        assert_eq!(a.files(), vec![root(&a), shm_a.clone()]);
        a.remove_files().unwrap();
        assert_eq!(a.files(), Vec::<std::path::PathBuf>::new());
        assert!(!shm_a.exists());
        assert_eq!(a_b.files(), vec![root(&a_b), shm_a_b.clone()]);
        a_b.remove_files().unwrap();
        assert!(!shm_a_b.exists() && !root(&a_b).exists());
        // Gone already: no error.
        a_b.remove_files().unwrap();
    }

    use iceoryx2::prelude::ZeroCopySend;

    /// The answer as a build before the odometry's scale was on the wire declared it.
    #[derive(Debug, ZeroCopySend)]
    #[type_name("lanealign::CorrectedPose")]
    #[repr(C)]
    struct AnswerOf272Bytes {
        fields: [u64; 34],
    }

    #[test]
    fn a_service_of_another_builds_layout_is_named_as_such() {
        let namespace: Namespace = format!("l{}", std::process::id()).parse().unwrap();
        let node = namespace.node::<Ipc>().unwrap();
        let service = "lanealign/lidar/session/00000000000000ab";
        let older = pubsub::<Ipc, AnswerOf272Bytes>(&node, service, (1, 1)).unwrap();
        let error = pubsub::<Ipc, CorrectedPose>(&node, service, (1, 1)).unwrap_err();
        let text = error.to_string();
        drop((older, node));
        namespace.remove_files().unwrap();
        assert!(
            matches!(
                error,
                ServiceOpenError::IncompatibleLayout { size: 296, .. }
            ),
            "{error:?}"
        );
        assert!(text.contains("different lanealign versions"), "{text}");
    }

    #[test]
    fn names_are_checked_and_map_to_services() {
        let s: SourceName = "lidar_front-1".parse().unwrap();
        assert_eq!(s.odom_service(), "lanealign/lidar_front-1/odom");
        assert_eq!(
            s.session_service(0xab),
            "lanealign/lidar_front-1/session/00000000000000ab"
        );
        assert_eq!(SourceName::of_odom_service(&s.odom_service()), Some(s));
        assert_eq!(SourceName::of_odom_service("lanealign/x/session/1"), None);
        assert!("".parse::<SourceName>().is_err());
        assert!("a/b".parse::<SourceName>().is_err());
        let long = "x".repeat(300);
        let e = long.parse::<SourceName>().unwrap_err().to_string();
        assert!(e.contains("longer than 64") && e.len() < 200, "{e}");
        assert_eq!(Namespace::default().prefix(), "lanealign_default_");
        assert!("a b".parse::<Namespace>().is_err());
    }

    /// The socket of an iceoryx2 listener whose id has as many digits as a `u128` can, in a
    /// namespace of the longest name, fits in a Unix socket's path; one character more would
    /// not, so the bound is the longest that always works.
    #[test]
    fn the_longest_namespace_fits_every_event_socket() {
        let socket = |n: &Namespace| format!("{}{}{}.event", n.root_path(), n.prefix(), u128::MAX);
        let longest: Namespace = "n".repeat(MAX_NAMESPACE_LEN).parse().unwrap();
        assert!(socket(&longest).len() <= 107, "{}", socket(&longest));
        let e = "n"
            .repeat(MAX_NAMESPACE_LEN + 1)
            .parse::<Namespace>()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(&format!("longer than {MAX_NAMESPACE_LEN}")),
            "{e}"
        );
        let beyond = Namespace("n".repeat(MAX_NAMESPACE_LEN + 1));
        assert!(socket(&beyond).len() > 107, "{}", socket(&beyond));
        // Kept off /tmp, which age-based cleaners empty.
        assert!(longest.root_path().starts_with("/dev/shm/lanealign-"));
    }
}
