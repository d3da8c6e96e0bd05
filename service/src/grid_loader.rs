//! Maps from a grid of tiles, loaded around each session on a thread of their own.
//!
//! Each session that corrects on a grid has a [`GridView`]. Before each pose it takes the newest
//! map the loader has assembled for it, if one arrived (an `Arc` swap between two poses); every
//! quarter cell the source drives it works out which cells its window and the road ahead need
//! ([`Grid::wanted`]) and, when its map lacks any, asks the loader. The loader thread reads the
//! missing cells (validated, checksummed against the manifest, signature checked when keys are
//! trusted), assembles the session's new map and sends it back. A session that keeps up never
//! waits for a file: until the new map arrives it corrects on the one it has, and its map counts
//! any query that reaches past its cells. A session that is behind (poses queued) waits for
//! it, briefly, rather than outrun its loader. Cells no session wants any more are dropped.

use std::collections::{BTreeSet, HashMap};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use lanealign_core::grid::{self, CellKey, CellNeeds, Grid, GridCell, LoadPolicy};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::report::error_line;

/// Longest a session that is behind waits for the map it asked for (see
/// [`GridView::arrived`]); a loader slower than this leaves it on the map it has, as before.
pub const CATCH_UP: Duration = Duration::from_millis(100);

/// A request to the loader thread.
enum Request {
    /// Assemble the map of `wanted` for session `requester`.
    Map {
        requester: u64,
        wanted: BTreeSet<CellKey>,
        reply: Sender<Arc<LaneMap>>,
    },
    /// Session `requester` ended: its cells may go.
    Forget(u64),
}

/// A handle on the loader thread, shared by every session of every source.
#[derive(Clone)]
pub struct GridLoader {
    grid: Arc<Grid>,
    policy: LoadPolicy,
    requests: Sender<Request>,
}

impl std::fmt::Debug for GridLoader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GridLoader")
            .field("grid", &self.grid)
            .field("policy", &self.policy)
            .finish()
    }
}

/// Which cell signers the daemon accepts: `None` accepts any valid cell.
pub type Trusted = Option<Vec<[u8; 32]>>;

impl GridLoader {
    /// Starts the loader thread for `grid`; it reports every `interval` and ends when every
    /// handle is dropped.
    pub fn spawn(
        grid: Arc<Grid>,
        policy: LoadPolicy,
        trusted: Trusted,
        interval: Duration,
    ) -> std::io::Result<(GridLoader, std::thread::JoinHandle<()>)> {
        let (tx, rx) = mpsc::channel();
        let thread_grid = grid.clone();
        let handle = std::thread::Builder::new()
            .name("grid-loader".into())
            .spawn(move || Loader::new(thread_grid, trusted).run(rx, interval))?;
        Ok((
            GridLoader {
                grid,
                policy,
                requests: tx,
            },
            handle,
        ))
    }

    /// The grid.
    pub fn grid(&self) -> &Arc<Grid> {
        &self.grid
    }

    /// Which cells sessions keep loaded.
    pub fn policy(&self) -> LoadPolicy {
        self.policy
    }

    /// A view for session `id`.
    pub fn view(&self, id: u64) -> GridView {
        GridView {
            loader: self.clone(),
            id,
            current: BTreeSet::new(),
            needs: CellNeeds::default(),
            pending: None,
            waits: 0,
        }
    }
}

/// One session's side of the loader.
pub struct GridView {
    loader: GridLoader,
    id: u64,
    /// The cells of the session's map (empty: the map it started with).
    current: BTreeSet<CellKey>,
    needs: CellNeeds,
    pending: Option<(BTreeSet<CellKey>, Receiver<Arc<LaneMap>>)>,
    /// How often the session, behind, waited for a pending map.
    waits: u64,
}

impl GridView {
    /// Whether a map asked for has not arrived yet (cells are being read).
    pub fn loading(&self) -> bool {
        self.pending.is_some()
    }

    /// How often [`Self::arrived`] waited for a pending map (the session was behind).
    pub fn waits(&self) -> u64 {
        self.waits
    }

    /// The map the loader assembled since the last call, if one arrived. Waits for it (at most
    /// [`CATCH_UP`]) only when `behind()` says more poses are queued behind this one: the
    /// session is then answering faster than it is driven (a replay flooding it, or a backlog)
    /// and would outrun the cells being read, which makes its answers differ from offline
    /// correction on the whole map. A session keeping up never waits for a file.
    pub fn arrived(&mut self, behind: impl FnOnce() -> bool) -> Option<Arc<LaneMap>> {
        let (_, rx) = self.pending.as_ref()?;
        let received = match rx.try_recv() {
            Err(TryRecvError::Empty) if behind() => {
                self.waits += 1;
                rx.recv_timeout(CATCH_UP).map_err(|e| match e {
                    RecvTimeoutError::Timeout => TryRecvError::Empty,
                    RecvTimeoutError::Disconnected => TryRecvError::Disconnected,
                })
            }
            other => other,
        };
        match received {
            Ok(map) => {
                let (cells, _) = self.pending.take()?;
                self.current = cells;
                Some(map)
            }
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => {
                // The loader could not make it (logged there): ask again a quarter cell on.
                self.pending = None;
                None
            }
        }
    }

    /// Asks for a new map when the cells a window (oldest first) plus the next position
    /// (metres, map plane) need are not all in the current one. Checks once per quarter cell
    /// driven, and only with no request in flight.
    pub fn request_if_needed(&mut self, window: &[[f64; 2]], next: [f64; 2]) {
        if self.pending.is_some() {
            return;
        }
        let (grid, policy) = (&self.loader.grid, &self.loader.policy);
        let Some(wanted) = self.needs.check(grid, policy, window, next, &self.current) else {
            return;
        };
        let (reply, rx) = mpsc::channel();
        let request = Request::Map {
            requester: self.id,
            wanted: wanted.clone(),
            reply,
        };
        if self.loader.requests.send(request).is_ok() {
            self.pending = Some((wanted, rx));
        }
    }
}

impl Drop for GridView {
    fn drop(&mut self) {
        let _ = self.loader.requests.send(Request::Forget(self.id));
    }
}

/// Loads a cell and refuses one not signed by a trusted key (when keys are configured).
pub(crate) fn load_trusted(
    grid: &Grid,
    key: CellKey,
    trusted: &Trusted,
) -> Result<GridCell, String> {
    let cell = grid.load_cell(key).map_err(|e| error_line(&e))?;
    if let Some(keys) = trusted {
        if !cell.signer().is_some_and(|s| keys.contains(&s)) {
            return Err(format!(
                "{}: not signed by a key in trusted_tile_keys: compile the grid with `lanealign-map compile --grid SIZE_M --sign KEY`",
                grid.cell_path(key).display()
            ));
        }
    }
    Ok(cell)
}

/// The loader thread's state.
struct Loader {
    grid: Arc<Grid>,
    trusted: Trusted,
    cells: HashMap<CellKey, Arc<GridCell>>,
    wanted: HashMap<u64, BTreeSet<CellKey>>,
    load_ns: Histogram<u64>,
    assemble_ns: Histogram<u64>,
    maps: u64,
    failures: u64,
    /// Cells whose failure was logged (once per cell: a session near it asks again and again).
    refused: std::collections::HashSet<CellKey>,
}

impl Loader {
    fn new(grid: Arc<Grid>, trusted: Trusted) -> Loader {
        let histogram = || {
            Histogram::new_with_bounds(1, 100_000_000_000, 3)
                .expect("constant, valid histogram bounds")
        };
        Loader {
            grid,
            trusted,
            cells: HashMap::new(),
            wanted: HashMap::new(),
            load_ns: histogram(),
            assemble_ns: histogram(),
            maps: 0,
            failures: 0,
            refused: std::collections::HashSet::new(),
        }
    }

    fn run(mut self, requests: Receiver<Request>, interval: Duration) {
        let mut next_report = Instant::now() + interval;
        loop {
            let wait = next_report.saturating_duration_since(Instant::now());
            match requests.recv_timeout(wait) {
                Ok(Request::Map {
                    requester,
                    wanted,
                    reply,
                }) => {
                    self.wanted.insert(requester, wanted.clone());
                    self.evict();
                    if let Some(map) = self.assemble(&wanted) {
                        let _ = reply.send(map);
                    }
                }
                Ok(Request::Forget(requester)) => {
                    self.wanted.remove(&requester);
                    self.evict();
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => return,
            }
            if Instant::now() >= next_report {
                self.report();
                next_report = Instant::now() + interval;
            }
        }
    }

    /// Drops every cell no session wants.
    fn evict(&mut self) {
        let wanted = &self.wanted;
        self.cells
            .retain(|key, _| wanted.values().any(|set| set.contains(key)));
    }

    fn assemble(&mut self, wanted: &BTreeSet<CellKey>) -> Option<Arc<LaneMap>> {
        let mut cells = Vec::with_capacity(wanted.len());
        for &key in wanted {
            let cell = match self.cells.get(&key) {
                Some(cell) => cell.clone(),
                None => {
                    let start = Instant::now();
                    match load_trusted(&self.grid, key, &self.trusted) {
                        Ok(cell) => {
                            self.load_ns
                                .saturating_record(start.elapsed().as_nanos().max(1) as u64);
                            let cell = Arc::new(cell);
                            self.cells.insert(key, cell.clone());
                            cell
                        }
                        Err(e) => {
                            self.failures += 1;
                            if self.refused.insert(key) {
                                tracing::warn!(error = %e, "grid cell not loaded (logged once per cell; failures counted in the grid report): sessions near it keep the map they have");
                            }
                            return None;
                        }
                    }
                }
            };
            cells.push(cell);
        }
        let start = Instant::now();
        match grid::assemble(&self.grid, &cells) {
            Ok(map) => {
                self.assemble_ns
                    .saturating_record(start.elapsed().as_nanos().max(1) as u64);
                self.maps += 1;
                Some(Arc::new(map))
            }
            Err(e) => {
                self.failures += 1;
                tracing::warn!(error = %error_line(&e), "grid cells not assembled: sessions near them keep the map they have");
                None
            }
        }
    }

    fn report(&mut self) {
        let us = |h: &Histogram<u64>, q: f64| h.value_at_quantile(q) as f64 / 1e3;
        let points: usize = self.cells.values().map(|c| c.points()).sum();
        tracing::info!(
            resident_cells = self.cells.len(),
            resident_points = points,
            cells_loaded = self.load_ns.len(),
            maps = self.maps,
            failures = self.failures,
            load_p50_us = us(&self.load_ns, 0.5),
            load_p99_us = us(&self.load_ns, 0.99),
            assemble_p50_us = us(&self.assemble_ns, 0.5),
            assemble_p99_us = us(&self.assemble_ns, 0.99),
            "grid"
        );
        self.load_ns.reset();
        self.assemble_ns.reset();
        self.maps = 0;
        self.failures = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lanealign_core::geo::{MapPlane, Projection};
    use lanealign_core::grid::GridSpec;
    use lanealign_core::lane_geometry::LaneGeometry;
    use lanealign_core::lane_map::Lane;

    /// A view of a one-lane grid whose request is pending, and the loader's side of it.
    fn pending_view(dir: &std::path::Path) -> (GridView, Sender<Arc<LaneMap>>, Arc<LaneMap>) {
        let lane = Lane::new(1, (0..50).map(|i| [i as f64 * 5.0, 0.0]).collect());
        let map = LaneMap::new(&[lane]).unwrap();
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let spec = GridSpec {
            plane: &plane,
            spacing_m: 3.0,
            geometry: &LaneGeometry::default(),
            cell_size_m: 100.0,
            margin_m: 50.0,
            sign: None,
            map_version: 0,
        };
        grid::write(dir, &map, &spec, 1).unwrap();
        let grid = Arc::new(Grid::open(dir).unwrap());
        let (loader, _) =
            GridLoader::spawn(grid, LoadPolicy::default(), None, Duration::from_secs(60)).unwrap();
        let mut view = loader.view(1);
        let (reply, rx) = mpsc::channel();
        view.pending = Some((BTreeSet::new(), rx));
        (view, reply, Arc::new(map))
    }

    /// A session that keeps up takes what has arrived and goes on; one that is behind waits for
    /// the map it asked for (here sent 20 ms later), so that it does not outrun its loader.
    #[test]
    fn only_a_session_that_is_behind_waits_for_its_map() {
        let dir = tempfile::tempdir().unwrap();
        let (mut view, reply, map) = pending_view(dir.path());
        let mut asked = false;
        assert!(view
            .arrived(|| {
                asked = true;
                false
            })
            .is_none());
        assert!(
            asked && view.loading(),
            "not behind: still pending, not waited for"
        );
        let sender = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            reply.send(map).unwrap();
        });
        assert_eq!(view.waits(), 0);
        assert!(view.arrived(|| true).is_some(), "behind: waited for it");
        assert!(!view.loading() && view.waits() == 1);
        sender.join().unwrap();
        assert!(view
            .arrived(|| panic!("nothing pending: not asked"))
            .is_none());
    }
}
