//! The daemon: checks the configuration and the tile ([`prepare`], which `lanealignd check`
//! runs too), takes its namespace's instance lock, holds the CPU wake-up latency the
//! configuration asks for ([`crate::cpu_latency`]), starts a worker per source (each restoring
//! its journaled sessions) and stops if any cannot start, tells systemd it is ready and alive,
//! cleans up after dead processes, watches for poses sent to unknown sources, reloads the tile
//! on SIGHUP for new sessions, and shuts down cleanly on SIGINT or SIGTERM.

use std::collections::BTreeSet;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::tile_watch::TileWatch;
use iceoryx2::node::{NodeListFailure, NodeView};
use iceoryx2::prelude::*;
use lanealign_core::grid::{self, Grid};
use lanealign_core::input::InputError;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::plausibility::too_far_from_lanes;
use lanealign_core::report::error_line;
use lanealign_core::source_corrector::Placement;
use lanealign_core::tile::{self, TileInfo};
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::service::{
    wire_name, Ipc, Namespace, NodeCreateError, NodeListError, SourceName, WIRE_VERSION,
};

use crate::config::{Config, ConfigError, ResolvedSource};
use crate::cpu_latency::{self, CpuLatencyError, CpuLatencyRequest};
use crate::grid_loader::{load_trusted, GridLoader};
use crate::journal::fingerprint;
use crate::served_map::{ServedMap, ServedMapError};
use crate::session::SessionSetup;
use crate::worker::{self, Reload, WorkerError, WorkerSetup, WorkerSummary};

/// How often the supervisor looks for dead nodes and unknown sources.
const SUPERVISION_PERIOD: Duration = Duration::from_millis(500);

/// How often a request to stop is looked for while the workers start.
const STARTUP_POLL: Duration = Duration::from_millis(20);

/// The daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The configuration is not usable.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The grid could not be opened, or holds no usable lanes near a source's anchor.
    #[error("grid {path}: {message}")]
    Grid {
        /// The grid's folder.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The grid loader thread could not be started.
    #[error("starting the grid loader thread: {0}")]
    GridLoader(std::io::Error),
    /// The tile could not be loaded.
    #[error("{source}{hint}")]
    Tile {
        /// What failed.
        source: tile::TileError,
        /// How to make the tile, when it does not exist.
        hint: String,
    },
    /// The supervisor's node could not be created.
    #[error(transparent)]
    Node(#[from] NodeCreateError),
    /// A worker thread could not be started.
    #[error("starting the worker of source {name}: {error}")]
    Spawn {
        /// The source.
        name: String,
        /// The error.
        error: std::io::Error,
    },
    /// A worker could not set up its ports: the daemon does not run with a source missing.
    #[error(transparent)]
    Worker(#[from] WorkerError),
    /// Another daemon serves the namespace.
    #[error("another lanealignd serves namespace '{namespace}'{detail}: stop it first, or give this deployment its own namespace")]
    AlreadyRunning {
        /// The namespace.
        namespace: String,
        /// What is known of the other daemon.
        detail: String,
    },
    /// The state folder or its lock could not be set up.
    #[error("{path}: {source} (state_dir holds the sessions' journals and the daemon's lock: set one this user may write, or journal = false)")]
    State {
        /// The folder or file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// Listing the namespace's nodes failed.
    #[error(transparent)]
    NodeList(#[from] NodeListError),
    /// The persistence thread could not be started.
    #[error("starting the persistence thread: {0}")]
    Persistence(std::io::Error),
    /// The CPU wake-up latency the configuration asks for cannot be requested.
    #[error(transparent)]
    CpuLatency(#[from] CpuLatencyError),
    /// The map is older than the newest this namespace's daemon has served, or that record
    /// cannot be read or written.
    #[error(transparent)]
    ServedMap(#[from] ServedMapError),
}

/// A configuration that passed every check, with its tile loaded.
pub struct Prepared {
    /// The configuration.
    pub config: Config,
    /// The configuration file.
    pub path: PathBuf,
    /// The deployment's namespace.
    pub namespace: Namespace,
    /// The namespace's state folder, when sessions are journaled.
    pub state_dir: Option<PathBuf>,
    /// The sources.
    pub sources: Vec<ResolvedSource>,
    /// The lanes.
    pub lanes: Lanes,
    /// What the tile says about itself (for a grid, see [`Grid::info`]).
    pub tile: TileInfo,
    /// The newest map version this namespace's daemon has served ([`ServedMap`]): `None` when
    /// nothing is recorded, or sessions are not journaled (no state folder).
    pub served_map_version: Option<u64>,
}

impl Prepared {
    /// A warning for each source whose anchor places its odometry frame's origin more than
    /// 1 km from every lane it starts with (the tile's, or the grid's cells around the anchor;
    /// [`too_far_from_lanes`]), as `lanealign correct` warns of a run's first pose: such a
    /// source's poses most likely lie where no lane can correct them (a latitude and longitude
    /// of another city, swapped, or a tile of another region).
    pub fn anchor_warnings(&self) -> Vec<String> {
        self.sources
            .iter()
            .enumerate()
            .filter_map(|(i, source)| {
                let map = match &self.lanes {
                    Lanes::Tile(map) => map,
                    Lanes::Grid { starts, .. } => starts.get(i)?,
                };
                let origin = source
                    .anchor
                    .anchored_from_odom(&self.tile.plane)
                    .apply([0.0, 0.0]);
                too_far_from_lanes(map, origin).map(|distance| {
                    format!(
                        "source {}: its anchor places the odometry frame's origin {distance} from \
                         the nearest lane: check its anchor (lat, lon in degrees; yaw_deg from \
                         East, counter-clockwise) and that {} covers where the vehicle drives",
                        source.name,
                        self.config.tile.display()
                    )
                })
            })
            .collect()
    }
}

/// Where the daemon's lanes come from.
pub enum Lanes {
    /// One tile, loaded whole.
    Tile(Arc<LaneMap>),
    /// A grid: each session loads the cells around it.
    Grid {
        /// The grid.
        grid: Arc<Grid>,
        /// The map each source's sessions start with (the cells around its anchor), in the
        /// order of the sources.
        starts: Vec<Arc<LaneMap>>,
    },
}

/// Opens a grid, checks its manifest against the configuration at `path` (signer, lane
/// geometry) before reading any cell, and assembles, for each source, the cells around its
/// anchor (checked against the trusted keys): what its sessions start with.
fn prepare_grid(
    config: &Config,
    path: &Path,
    sources: &[ResolvedSource],
    served: Option<u64>,
) -> Result<(Lanes, TileInfo), DaemonError> {
    let bad = |message: String| DaemonError::Grid {
        path: config.tile.clone(),
        message,
    };
    let grid = Arc::new(Grid::open(&config.tile).map_err(|e| bad(error_line(&e)))?);
    let info = grid.info();
    config.check_tile(path, sources, &info)?;
    if let Some(served) = served {
        not_older(&info, served).map_err(&bad)?;
    }
    let trusted = config.trusted_keys();
    let mut starts = Vec::with_capacity(sources.len());
    for source in sources {
        let origin = source
            .anchor
            .anchored_from_odom(&grid.plane())
            .apply([0.0, 0.0]);
        let wanted = grid.wanted(&[origin], &config.grid);
        let cells = wanted
            .iter()
            .map(|&key| load_trusted(&grid, key, &trusted).map(Arc::new))
            .collect::<Result<Vec<_>, _>>()
            .map_err(&bad)?;
        if cells.is_empty() {
            return Err(bad(format!(
                "no cell holds lanes within {} m of source {}'s anchor",
                config.grid.radius_m, source.name
            )));
        }
        let map = grid::assemble(&grid, &cells).map_err(|e| bad(e.to_string()))?;
        starts.push(Arc::new(map));
    }
    Ok((Lanes::Grid { grid, starts }, info))
}

/// Reads and checks the configuration, loads and checks the tile against every source: all the
/// rules the daemon applies before it starts. `lanealignd check` is exactly this.
pub fn prepare(path: &Path) -> Result<Prepared, DaemonError> {
    let config = Config::load(path)?;
    let resolved = config.resolve(path)?;
    if let Some(dir) = &resolved.state_dir {
        check_state_dir(dir)?;
    }
    if config.cpu_dma_latency_us.is_some() {
        cpu_latency::check(Path::new(cpu_latency::DEVICE))?;
    }
    let (namespace, sources) = (resolved.namespace, resolved.sources);
    // Read, never written here: `check` changes nothing.
    let served_before = |info: &TileInfo| match &resolved.state_dir {
        Some(dir) => ServedMap::in_dir(dir).check(info.map_version),
        None => Ok(None),
    };
    if grid::is_grid(&config.tile) {
        let (lanes, info) = prepare_grid(&config, path, &sources, None)?;
        let served_map_version = served_before(&info)?;
        return Ok(Prepared {
            path: path.to_path_buf(),
            namespace,
            state_dir: resolved.state_dir,
            sources,
            lanes,
            tile: info,
            served_map_version,
            config,
        });
    }
    let (map, info) = tile::load(&config.tile).map_err(|source| {
        let hint = match &source {
            tile::TileError::Input(InputError::Io { source: io, .. })
                if io.kind() == std::io::ErrorKind::NotFound =>
            {
                format!(
                    "\nmake the tile with `lanealign-map compile INPUT.osm --origin LAT,LON [--projection kitti] -o {}` (README, \"The daemon\")",
                    config.tile.display()
                )
            }
            _ => String::new(),
        };
        DaemonError::Tile { source, hint }
    })?;
    config.check_tile(path, &sources, &info)?;
    let served_map_version = served_before(&info)?;
    Ok(Prepared {
        path: path.to_path_buf(),
        namespace,
        state_dir: resolved.state_dir,
        sources,
        lanes: Lanes::Tile(Arc::new(map)),
        tile: info,
        served_map_version,
        config,
    })
}

/// Checks, changing nothing, that the daemon can make `dir` and write in it: its nearest folder
/// that exists must be one this process may write in (not a file, not on a read-only file
/// system).
fn check_state_dir(dir: &Path) -> Result<(), DaemonError> {
    // A relative path's last ancestor is "", the working folder, which `exists` calls absent.
    let existing = dir
        .ancestors()
        .map(|p| match p.as_os_str().is_empty() {
            true => Path::new("."),
            false => p,
        })
        .find(|p| p.exists())
        .unwrap_or(dir);
    let error = |source: std::io::Error| DaemonError::State {
        path: existing.to_path_buf(),
        source,
    };
    if !existing.is_dir() {
        return Err(error(std::io::ErrorKind::NotADirectory.into()));
    }
    rustix::fs::access(
        existing,
        rustix::fs::Access::WRITE_OK | rustix::fs::Access::EXEC_OK,
    )
    .map_err(|e| error(e.into()))
}

/// Removes the resources of nodes in `namespace` whose process died; returns how many, or why
/// the nodes could not be listed (too few file descriptors, for one).
pub fn remove_dead_nodes(namespace: &Namespace) -> Result<usize, NodeListFailure> {
    let mut removed = 0;
    let listed = Node::<Ipc>::list(&namespace.config(), |state| {
        if let NodeState::Dead(view) = state {
            let id = *view.id();
            match view.try_remove_stale_resources() {
                Ok(()) => {
                    removed += 1;
                    tracing::info!(node = ?id, "removed the resources of a dead node");
                }
                Err(e) => {
                    tracing::warn!(node = ?id, error = %error_line(&e), "could not remove a dead node's resources")
                }
            }
        }
        CallbackProgression::Continue
    });
    listed.map(|_| removed)
}

/// Says that log records were dropped (their reader did not keep up), with the total, at most
/// once per metrics interval: while the log is blocked the saying waits or is dropped too, and
/// the next one after it flows again tells how many were lost.
struct LogDrops {
    /// Dropped records said so far.
    said: u64,
    /// When it was last said.
    last: Option<Instant>,
    /// The least time between two sayings.
    every: Duration,
}

impl LogDrops {
    fn new(every: Duration) -> Self {
        LogDrops {
            said: 0,
            last: None,
            every,
        }
    }

    /// `dropped`: records dropped since the start; returns whether it said so now.
    fn record(&mut self, dropped: u64, now: Instant) -> bool {
        let due = self
            .last
            .is_none_or(|t| now.duration_since(t) >= self.every);
        if dropped <= self.said || !due {
            return false;
        }
        tracing::warn!(
            dropped_log_lines = dropped,
            "log records were dropped: the log's reader did not keep up (the daemon never waits for it)"
        );
        self.said = dropped;
        self.last = Some(now);
        true
    }
}

/// Says when listing the namespace's nodes starts failing and when it works again, not at
/// every supervision period in between.
#[derive(Default)]
struct ListingHealth {
    /// Listings failed in a row.
    failures: u64,
}

impl ListingHealth {
    fn record(&mut self, listed: Result<usize, NodeListFailure>) {
        match listed {
            Ok(_) if self.failures > 0 => {
                tracing::info!(failures = self.failures, "listing nodes works again");
                self.failures = 0;
            }
            Ok(_) => {}
            Err(e) => {
                if self.failures == 0 {
                    tracing::warn!(error = %error_line(&e), "listing nodes failed: dead clients' resources stay until it works again (said when it does)");
                }
                self.failures += 1;
            }
        }
    }
}

/// Sources of `namespace` that have a pose service but no configured worker.
fn unknown_sources(namespace: &Namespace, known: &[SourceName]) -> BTreeSet<String> {
    let mut unknown = BTreeSet::new();
    let _ = Ipc::list(&namespace.config(), |details| {
        let name = details.static_details.name().to_string();
        if let Some(source) = SourceName::of_odom_service(&name) {
            if !known.contains(&source) {
                unknown.insert(source.to_string());
            }
        }
        CallbackProgression::Continue
    });
    unknown
}

/// The namespace's instance lock: held for the daemon's life (released by the kernel, even on
/// kill -9).
fn lock(namespace: &Namespace, state_dir: Option<&Path>) -> Result<Option<File>, DaemonError> {
    let others = namespace.daemons()?;
    if let Some(other) = others.first() {
        let version = if other.speaks_this_wire() {
            String::new()
        } else {
            format!(
                ", {}; this build wire {WIRE_VERSION}",
                wire_name(other.wire)
            )
        };
        return Err(DaemonError::AlreadyRunning {
            namespace: namespace.to_string(),
            detail: format!(" (pid {}{version})", other.pid),
        });
    }
    let Some(dir) = state_dir else {
        return Ok(None);
    };
    let state = |path: &Path| {
        let path = path.to_path_buf();
        move |source| DaemonError::State { path, source }
    };
    std::fs::create_dir_all(dir).map_err(state(dir))?;
    let path = dir.join("lanealignd.lock");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(state(&path))?;
    match rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => Ok(Some(file)),
        Err(e) if e == rustix::io::Errno::WOULDBLOCK => Err(DaemonError::AlreadyRunning {
            namespace: namespace.to_string(),
            detail: format!(" (it holds {})", path.display()),
        }),
        Err(e) => Err(state(&path)(e.into())),
    }
}

/// Refuses, on SIGHUP, a map older than the one served (`served`, its map version): an older
/// map put in the configured place, signed or not, is a rollback, not a reload.
fn not_older(info: &TileInfo, served: u64) -> Result<(), String> {
    if info.map_version < served {
        return Err(format!(
            "map version {} is older than the served map's {served}: SIGHUP never goes back to an \
             older map (build the one wanted with a larger --map-version; to go back \
             deliberately, remove the record of the newest map served, if sessions are journaled, \
             and restart: docs/operations.md)",
            info.map_version
        ));
    }
    Ok(())
}

/// Records that the map `info` describes is served ([`ServedMap::record`]), before it is: a map
/// older than the record is refused. A record that cannot be written (a full disk) is logged as
/// an error and the map served anyway, as a journal that cannot be written ends the journal,
/// not the daemon: the map passed every check, and only a later restart's floor is lower.
fn record_served(record: Option<&ServedMap>, info: &TileInfo) -> Result<(), ServedMapError> {
    let Some(record) = record else {
        return Ok(());
    };
    match record.record(info.map_version) {
        Err(ServedMapError::Write(e)) => {
            tracing::error!(record = %record.path().display(), map_version = info.map_version, error = %error_line(&e), "the map version served could not be recorded: the map is served, but a restart could go back to an older one");
            Ok(())
        }
        recorded => recorded,
    }
}

/// The tile's (or a grid's manifest's) signer for the log: its public key, or `unsigned`.
fn signer_of(info: &TileInfo) -> String {
    info.signer
        .map_or_else(|| "unsigned".into(), |key| tile::key_hex(&key))
}

/// What a source's journals are written under: its configuration and the tile.
fn source_fingerprint(source: &ResolvedSource, tile: &TileInfo) -> u64 {
    let corrector = toml::to_string(&source.corrector).unwrap_or_default();
    fingerprint(&[
        source.name.as_str(),
        &corrector,
        source.convention.name(),
        &format!("{:?}", source.anchor),
        &format!("{:016x}", tile.checksum),
    ])
}

/// Tells systemd (when it started the daemon with `Type=notify`) how things stand.
fn notify(states: &[sd_notify::NotifyState<'_>]) {
    if let Err(e) = sd_notify::notify(states) {
        tracing::debug!(error = %error_line(&e), "sd_notify failed");
    }
}

/// Loads the configured tile again, checks it against every source and against the map
/// version served (`served`, updated), records that version (`record`, when sessions are
/// journaled; [`record_served`]), and hands it to the workers for their new sessions. True
/// when it did.
fn reload(
    config: &Config,
    path: &Path,
    sources: &[ResolvedSource],
    workers: &[Worker],
    loader_threads: &mut Vec<std::thread::JoinHandle<()>>,
    served: &mut u64,
    record: Option<&ServedMap>,
) -> bool {
    tell_config_changes(config, path);
    if grid::is_grid(&config.tile) {
        return match reload_grid(config, path, sources, workers, *served, record) {
            Ok((handle, map_version)) => {
                loader_threads.push(handle);
                *served = map_version;
                true
            }
            Err(e) => {
                tracing::error!(error = %e, "SIGHUP: the grid was not reloaded; every session keeps the one it has");
                false
            }
        };
    }
    let loaded = tile::load(&config.tile).map_err(|e| error_line(&e));
    let checked = loaded.and_then(|(map, info)| {
        config
            .check_tile(path, sources, &info)
            .map_err(|e| error_line(&e))?;
        not_older(&info, *served)?;
        record_served(record, &info).map_err(|e| error_line(&e))?;
        Ok((Arc::new(map), info))
    });
    match checked {
        Ok((map, info)) => {
            for ((_, _, tx), source) in workers.iter().zip(sources) {
                let _ = tx.send(Reload {
                    map: map.clone(),
                    grid: None,
                    fingerprint: source_fingerprint(source, &info),
                });
            }
            tracing::info!(tile = %config.tile.display(), lanes = info.lanes, checksum = format_args!("{:016x}", info.checksum), signer = %signer_of(&info), map_version = info.map_version, "tile reloaded on SIGHUP: new sessions use it");
            *served = info.map_version;
            true
        }
        Err(e) => {
            tracing::error!(error = %e, "SIGHUP: the tile was not reloaded; every session keeps the one it has");
            false
        }
    }
}

/// Says, on SIGHUP, what of the configuration file at `path` the daemon running `running` does
/// not apply: a file changed since the start (SIGHUP loads only the tile again), or one that no
/// longer passes the checks, so that a restart would fail.
fn tell_config_changes(running: &Config, path: &Path) {
    match Config::load(path).and_then(|now| now.resolve(path).map(|_| now)) {
        Ok(now) => {
            let changes = running.changes_to(&now);
            if !changes.is_empty() {
                tracing::warn!(config = %path.display(), changed = %changes.join(", "), tile = %running.tile.display(), "SIGHUP: the configuration file changed since the daemon started; SIGHUP loads only the tile again (the one named at the start), the changes take a restart (systemctl restart lanealignd)");
            }
        }
        Err(e) => {
            tracing::warn!(config = %path.display(), error = %error_line(&e), "SIGHUP: the configuration file no longer passes the checks: the daemon runs on as it started, and a restart would fail (lanealignd check --config FILE)");
        }
    }
}

/// A running worker: its source's name, its thread and where its reloads go.
type Worker = (
    String,
    std::thread::JoinHandle<WorkerSummary>,
    mpsc::Sender<Reload>,
);

/// Opens the configured grid again (its manifest and the cells around each source's anchor,
/// checked as at start), starts a loader for it and hands both to the workers for their new
/// sessions; running sessions keep the grid and loader they have. A grid older than the map
/// version served (`served`) is refused before any cell is read, and its version is recorded
/// (`record`, [`record_served`]) before it is served. The new loader's thread and the new
/// grid's map version.
fn reload_grid(
    config: &Config,
    path: &Path,
    sources: &[ResolvedSource],
    workers: &[Worker],
    served: u64,
    record: Option<&ServedMap>,
) -> Result<(std::thread::JoinHandle<()>, u64), String> {
    let (lanes, info) =
        prepare_grid(config, path, sources, Some(served)).map_err(|e| error_line(&e))?;
    let Lanes::Grid { grid, starts } = lanes else {
        return Err("not a grid".into());
    };
    let interval = Duration::from_secs_f64(config.metrics_interval_s);
    let (loader, handle) = GridLoader::spawn(grid, config.grid, config.trusted_keys(), interval)
        .map_err(|e| error_line(&e))?;
    // Recorded once nothing but the hand-over is left: a loader that cannot start leaves the
    // record naming the grid still served. On a refusal the loader's only handle is dropped, and
    // its thread ends.
    record_served(record, &info).map_err(|e| error_line(&e))?;
    for (((_, _, tx), source), map) in workers.iter().zip(sources).zip(starts) {
        let _ = tx.send(Reload {
            map,
            grid: Some(loader.clone()),
            fingerprint: source_fingerprint(source, &info),
        });
    }
    tracing::info!(grid = %config.tile.display(), lanes = info.lanes, checksum = format_args!("{:016x}", info.checksum), signer = %signer_of(&info), map_version = info.map_version, "grid reloaded on SIGHUP: new sessions use it");
    Ok((handle, info.map_version))
}

/// Runs until SIGINT or SIGTERM: returns each source's summary. Fails, stopping every worker,
/// if another daemon serves the namespace or any source's worker cannot start.
/// `dropped_log_lines` counts the log records dropped so far (a log nobody reads); the daemon
/// says when it grows.
pub fn run(
    prepared: Prepared,
    dropped_log_lines: impl Fn() -> u64,
) -> Result<Vec<(String, WorkerSummary)>, DaemonError> {
    let Prepared {
        config,
        path,
        namespace,
        state_dir,
        sources,
        lanes,
        tile: info,
        served_map_version: _,
    } = prepared;
    // Signals first: from the `tile loaded` record on, a request to stop is a flag the daemon
    // acts on (before it, the default action ends the process, which has started nothing).
    let hangup = Arc::new(AtomicBool::new(false));
    if let Err(e) = signal_hook::flag::register(signal_hook::consts::SIGHUP, hangup.clone()) {
        tracing::warn!(error = %error_line(&e), "SIGHUP cannot reload the tile");
    }
    // A flag of its own per request, not a "last signal" that the next one (systemd sends
    // SIGCONT right after SIGTERM) overwrites.
    let stop = Arc::new(AtomicBool::new(false));
    for request in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        if let Err(e) = signal_hook::flag::register(request, stop.clone()) {
            tracing::warn!(error = %error_line(&e), signal = request, "the signal stops the daemon without a clean shutdown");
        }
    }
    let _lock = lock(&namespace, state_dir.as_deref())?;
    // Under the lock, before any source serves: the record never falls behind the map served.
    let served_record = state_dir.as_deref().map(ServedMap::in_dir);
    record_served(served_record.as_ref(), &info)?;
    // Held for the daemon's life: dropping it (or the process ending) ends the request.
    let _cpu_latency = match config.cpu_dma_latency_us {
        Some(us) => {
            let request = CpuLatencyRequest::hold(us)?;
            tracing::info!(
                cpu_dma_latency_us = us,
                "every CPU kept able to run within the latency while the daemon runs"
            );
            Some(request)
        }
        None => None,
    };
    tracing::info!(
        tile = %config.tile.display(),
        lanes = info.lanes,
        points = info.points,
        checksum = format_args!("{:016x}", info.checksum),
        signer = %signer_of(&info),
        map_version = info.map_version,
        namespace = %namespace,
        state_dir = %state_dir.as_ref().map_or("(no journal)".into(), |d| d.display().to_string()),
        "tile loaded"
    );
    let watched = watched_file(&config.tile);
    let mut tile_watch = TileWatch::new(&watched);
    let interval = Duration::from_secs_f64(config.metrics_interval_s);
    let mut loader_threads = Vec::new();
    let loader = match &lanes {
        Lanes::Tile(_) => None,
        Lanes::Grid { grid, .. } => {
            let (loader, handle) =
                GridLoader::spawn(grid.clone(), config.grid, config.trusted_keys(), interval)
                    .map_err(DaemonError::GridLoader)?;
            loader_threads.push(handle);
            Some(loader)
        }
    };
    let mut listing = ListingHealth::default();
    let mut log_drops = LogDrops::new(interval);
    match remove_dead_nodes(&namespace) {
        Ok(cleaned) if cleaned > 0 => {
            tracing::info!(cleaned, "removed stale resources left by earlier processes")
        }
        listed => listing.record(listed),
    }
    let node = namespace.daemon_node::<Ipc>()?;
    let (persistence, persistence_thread) = if state_dir.is_some() {
        let (tx, handle) = crate::persistence::spawn().map_err(DaemonError::Persistence)?;
        (Some(tx), Some(handle))
    } else {
        (None, None)
    };
    let epoch = crate::new_nonce();
    let shutdown = Arc::new(AtomicBool::new(false));
    let known: Vec<SourceName> = sources.iter().map(|s| s.name.clone()).collect();
    let (ready_tx, ready_rx) = mpsc::channel();
    let mut workers = Vec::new();
    let mut heartbeats = Vec::new();
    let mut failure = None;
    for (i, source) in sources.iter().enumerate() {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let name = source.name.to_string();
        let map = match &lanes {
            Lanes::Tile(map) => map.clone(),
            Lanes::Grid { starts, .. } => starts[i].clone(),
        };
        let heartbeat = Arc::new(AtomicU64::new(monotonic_ns()));
        let (reload_tx, reloads) = mpsc::channel();
        let setup = WorkerSetup {
            sessions: SessionSetup {
                map,
                grid: loader.clone(),
                params: source.params,
                mode: source.corrector.match_mode,
                placement: Placement {
                    convention: source.convention,
                    anchored_from_odom: source.anchor.anchored_from_odom(&info.plane),
                    smoothing: source.corrector.smoothing(),
                },
                journal_dir: state_dir.as_ref().map(|d| d.join(source.name.as_str())),
                fingerprint: source_fingerprint(source, &info),
                persistence: persistence.clone(),
                daemon_epoch: epoch,
            },
            source: source.clone(),
            namespace: namespace.clone(),
            metrics_interval: interval,
            session_timeout: Duration::from_secs_f64(config.session_timeout_s),
            max_sessions: config.max_sessions,
            shutdown: shutdown.clone(),
            heartbeat: heartbeat.clone(),
            reloads,
        };
        let ready = ready_tx.clone();
        match std::thread::Builder::new()
            .name(format!("worker-{name}"))
            .spawn(move || worker::run(setup, ready))
        {
            Ok(handle) => {
                workers.push((name, handle, reload_tx));
                heartbeats.push(heartbeat);
            }
            Err(error) => {
                failure = Some(DaemonError::Spawn { name, error });
                break;
            }
        }
    }
    drop((ready_tx, persistence));
    // A request to stop is heard while the workers start too (256 sources take seconds): the
    // daemon then stops without ever saying it is ready.
    let mut started = 0;
    while failure.is_none() && started < workers.len() {
        match ready_rx.recv_timeout(STARTUP_POLL) {
            Ok(Ok(())) => started += 1,
            Ok(Err(e)) => failure = Some(e.into()),
            Err(RecvTimeoutError::Timeout) if stop.load(Ordering::Relaxed) => break,
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    if let Some(e) = failure {
        shutdown.store(true, Ordering::Relaxed);
        for (_, handle, _) in workers {
            let _ = handle.join();
        }
        return Err(e);
    }
    if started < sources.len() {
        if stop.load(Ordering::Relaxed) {
            tracing::info!(
                started,
                sources = sources.len(),
                "asked to stop while the sources' workers started"
            );
        } else {
            tracing::error!(
                started,
                sources = sources.len(),
                "workers ended before they were ready"
            );
        }
    } else {
        tracing::info!(
            sources = workers.len(),
            epoch = format_args!("{epoch:016x}"),
            "ready"
        );
        notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(&format!("serving {} sources", workers.len())),
        ]);
        let mut refused = BTreeSet::new();
        let mut served = info.map_version;
        loop {
            // A signal handled by this thread ends the sleep early (SIGINT or SIGTERM: a request
            // to stop; SIGHUP: to reload); one handled by another thread is seen when it ends. An
            // interrupted sleep is no request by itself: a process stopped and continued (SIGSTOP,
            // SIGCONT) has its sleep interrupted too.
            let _ = node.wait(SUPERVISION_PERIOD);
            if stop.load(Ordering::Relaxed) {
                break;
            }
            if hangup.swap(false, Ordering::Relaxed)
                && reload(
                    &config,
                    &path,
                    &sources,
                    &workers,
                    &mut loader_threads,
                    &mut served,
                    served_record.as_ref(),
                )
            {
                tile_watch = TileWatch::new(&watched);
            }
            if let Some(change) = tile_watch.check() {
                tracing::warn!(tile = %watched.display(), change, "the tile file changed on disk; every source keeps serving the validated copy loaded at start (SIGHUP loads the file for new sessions; a grid's cells changed since are refused)");
            }
            listing.record(remove_dead_nodes(&namespace));
            log_drops.record(dropped_log_lines(), Instant::now());
            for source in unknown_sources(&namespace, &known) {
                if refused.insert(source.clone()) {
                    tracing::warn!(
                        source,
                        refused_sources = refused.len(),
                        "poses sent to a source that is not configured are refused"
                    );
                }
            }
            // The watchdog is fed only while every worker goes round its loop.
            let now = monotonic_ns();
            let stalled = heartbeats
                .iter()
                .any(|h| now.saturating_sub(h.load(Ordering::Relaxed)) > 2_000_000_000);
            if !stalled {
                notify(&[sd_notify::NotifyState::Watchdog]);
            }
            if workers.iter().all(|(_, h, _)| h.is_finished()) {
                tracing::error!("every worker has stopped");
                break;
            }
        }
    }
    tracing::info!("shutting down");
    notify(&[sd_notify::NotifyState::Stopping]);
    shutdown.store(true, Ordering::Relaxed);
    let mut summaries = Vec::new();
    for (name, handle, _) in workers {
        match handle.join() {
            Ok(summary) => summaries.push((name, summary)),
            Err(_) => tracing::error!(source = %name, "worker panicked"),
        }
    }
    if let Some(handle) = persistence_thread {
        let _ = handle.join();
    }
    drop(loader);
    for handle in loader_threads {
        let _ = handle.join();
    }
    Ok(summaries)
}

/// The file whose changes the daemon reports: the tile, or a grid's manifest.
fn watched_file(tile: &Path) -> PathBuf {
    if grid::is_grid(tile) {
        tile.join(grid::MANIFEST)
    } else {
        tile.to_path_buf()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dropped_log_records_are_said_with_their_total_at_most_once_per_interval() {
        let mut drops = LogDrops::new(Duration::from_secs(5));
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        assert!(!drops.record(0, at(0)), "nothing dropped, nothing said");
        assert!(drops.record(3, at(0)));
        assert!(!drops.record(7, at(1)), "within the interval");
        assert!(drops.record(7, at(5)));
        assert_eq!(drops.said, 7);
        assert!(!drops.record(7, at(20)), "no more dropped since");
    }
}
