//! The daemon's configuration (TOML), typed: unknown keys and bad values are refused naming the
//! key. [`Config::resolve`] is the one validation; `lanealignd check` and the daemon both call
//! it, and [`Config::check_tile`] the one tile check. `configs/lanealignd.toml` documents every
//! field.

use std::path::{Path, PathBuf};

use lanealign_core::geo::Anchor;
use lanealign_core::grid::{self, LoadPolicy};
use lanealign_core::input::{read_regular_file, InputError};
use lanealign_core::params::{CorrectorConfig, Params};
use lanealign_core::pose::AxisConvention;
use lanealign_core::tile::{key_hex, parse_key_hex, TileInfo};
use lanealign_wire::service::{Namespace, SourceName};
use lanealign_wire::wait::WaitStrategy;
use serde::{Deserialize, Serialize};

/// The whole configuration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The lane tile, or a grid's folder (relative paths are relative to the config file).
    pub tile: PathBuf,
    /// For a grid: which cells each session keeps loaded (default 250 m around its window,
    /// 300 m ahead).
    #[serde(default, skip_serializing_if = "is_default_policy")]
    pub grid: LoadPolicy,
    /// The deployment's namespace: daemons and clients of different namespaces never see each
    /// other. Default `default`.
    #[serde(default = "default_namespace")]
    pub namespace: String,
    /// Seconds between two metrics reports per source (0.1 to 3600).
    #[serde(default = "default_metrics_interval")]
    pub metrics_interval_s: f64,
    /// Where sessions are journaled, the instance lock is held and the newest map version
    /// served is recorded (a folder per namespace below it); relative to the config file.
    /// Default: see [`default_state_dir`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state_dir: Option<PathBuf>,
    /// Journal every session, so that a restarted daemon continues each exactly where it was.
    /// Default true.
    #[serde(default = "default_true")]
    pub journal: bool,
    /// A session with no pose for this many seconds ends and its journal is removed (1 to
    /// 604800). Default 600.
    #[serde(default = "default_session_timeout")]
    pub session_timeout_s: f64,
    /// Sessions per source at most (1 to 64); a new one beyond takes the place of one whose
    /// client is gone, or of the least recently active once that one is quiet, or waits.
    /// Default 16.
    #[serde(default = "default_max_sessions")]
    pub max_sessions: usize,
    /// `text` or `json` log lines.
    #[serde(default)]
    pub log_format: LogFormat,
    /// Public keys (64 hex digits each, from `lanealign-map keygen`) of the builders whose
    /// signed tiles this daemon accepts. Empty (the default): any valid tile, signed or not.
    /// Not empty: the tile must carry a valid signature by one of them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trusted_tile_keys: Vec<String>,
    /// The oldest map this daemon serves: a tile, or a grid's manifest, whose map version
    /// (`lanealign-map compile --map-version N`) is below it is refused at the start, by
    /// `check` and on SIGHUP. Default 0: any. (Neither SIGHUP nor a restart goes back to a map
    /// older than the newest served: [`crate::served_map`].)
    #[serde(default)]
    pub min_map_version: u64,
    /// Keep every CPU able to run within this many microseconds while the daemon runs (0 to
    /// 1000000; 0: idle CPUs poll instead of halting), through the kernel's
    /// `/dev/cpu_dma_latency` ([`crate::cpu_latency`]). Absent (the default): no request.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_dma_latency_us: Option<u32>,
    /// The odometry sources.
    #[serde(rename = "source")]
    pub sources: Vec<SourceConfig>,
}

fn default_namespace() -> String {
    Namespace::default().to_string()
}

fn default_metrics_interval() -> f64 {
    5.0
}

fn default_true() -> bool {
    true
}

fn default_session_timeout() -> f64 {
    600.0
}

/// Sources a daemon serves at most: each is a worker thread with its own shared-memory services.
/// 300 started in 2.3 s here and held 750 MB; 3000 had 464 workers started after 90 s, the
/// daemon not ready (both measured before [`Namespace::daemon_node`], with which 256 start in
/// 0.6 s instead of 1.8-2.0 s).
pub const MAX_SOURCES: usize = 256;

fn default_max_sessions() -> usize {
    16
}

/// The state folder when the configuration names none: `$LANEALIGN_STATE_DIR`, else
/// `$STATE_DIRECTORY` (systemd's `StateDirectory=`, e.g. `/var/lib/lanealign`), else
/// `$XDG_STATE_HOME/lanealign`, else `$HOME/.local/state/lanealign`. All survive a reboot.
pub fn default_state_dir() -> Option<PathBuf> {
    let var = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    var("LANEALIGN_STATE_DIR")
        .or_else(|| {
            // systemd may list several folders separated by ':'; the first is ours.
            var("STATE_DIRECTORY").map(|v| {
                let text = v.to_string_lossy().into_owned();
                PathBuf::from(text.split(':').next().unwrap_or_default())
            })
        })
        .or_else(|| var("XDG_STATE_HOME").map(|d| d.join("lanealign")))
        .or_else(|| var("HOME").map(|h| h.join(".local/state/lanealign")))
}

/// Log line format.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON object per line.
    Json,
}

impl std::str::FromStr for LogFormat {
    type Err = lanealign_core::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        lanealign_core::names::parse_name(s)
    }
}

/// One odometry source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// The source name: its services are `lanealign/<name>/odom` and `.../corrected`.
    pub name: String,
    /// Axis convention of the source's poses (default `flu`).
    #[serde(default)]
    pub frame: AxisConvention,
    /// Where the source's odometry frame lies on Earth.
    pub anchor: Anchor,
    /// Echo poses back without correcting them (to measure the transport alone).
    #[serde(default)]
    pub pass_through: bool,
    /// The corrector: preset, method, matching, smoothing, overrides.
    pub corrector: CorrectorConfig,
    /// How the source's worker waits for poses (default: sleep until notified).
    #[serde(default, skip_serializing_if = "is_event")]
    pub wait: WaitStrategy,
}

fn is_default_policy(policy: &LoadPolicy) -> bool {
    *policy == LoadPolicy::default()
}

fn is_event(wait: &WaitStrategy) -> bool {
    *wait == WaitStrategy::Event
}

/// Everything the configuration resolves to.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    /// The deployment's namespace.
    pub namespace: Namespace,
    /// The namespace's state folder (journals and the instance lock), when journaling.
    pub state_dir: Option<PathBuf>,
    /// The sources.
    pub sources: Vec<ResolvedSource>,
}

/// A source ready to run.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedSource {
    /// Its name.
    pub name: SourceName,
    /// Its corrector configuration.
    pub corrector: CorrectorConfig,
    /// Its effective corrector parameters.
    pub params: Params,
    /// Its axis convention.
    pub convention: AxisConvention,
    /// Its anchor.
    pub anchor: Anchor,
    /// Echo without correcting.
    pub pass_through: bool,
    /// How its worker waits for poses.
    pub wait: WaitStrategy,
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read, is not a regular file, or is longer than 1 MiB.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The file is not UTF-8 text.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// Not valid TOML, an unknown key, a missing key or a value of the wrong type.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The TOML parser's message (it names the key and the line).
        message: String,
    },
    /// A value is out of range.
    #[error("{path}: {key}: {message}")]
    Value {
        /// The file.
        path: PathBuf,
        /// The key, dotted (`source.lidar.corrector`).
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// The largest configuration file read (bytes).
const MAX_CONFIG_BYTES: u64 = 1 << 20;

impl Config {
    /// Reads a configuration file (at most 1 MiB, regular files only); makes `tile` absolute.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let bytes = read_regular_file(path, MAX_CONFIG_BYTES)?;
        let text = String::from_utf8(bytes).map_err(|e| ConfigError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
        })?;
        Self::parse(&text, path)
    }

    /// Parses configuration text; `path` names it and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        let mut config: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        if config.tile.is_relative() {
            config.tile = path.parent().unwrap_or(Path::new(".")).join(&config.tile);
        }
        Ok(config)
    }

    /// What `other` changes of this configuration: the top-level keys whose values differ, and
    /// each source by name (`source 'NAME'`, with ` (added)` or ` (removed)` where only one of
    /// the two has it). Empty when they configure the same daemon (sources in another order).
    pub fn changes_to(&self, other: &Config) -> Vec<String> {
        let keys = |config: &Config| {
            let without_sources = Config {
                sources: Vec::new(),
                ..config.clone()
            };
            match toml::Value::try_from(without_sources) {
                Ok(toml::Value::Table(table)) => table,
                _ => toml::Table::new(),
            }
        };
        let (mine, theirs) = (keys(self), keys(other));
        let mut changes: Vec<String> = mine
            .keys()
            .chain(theirs.keys().filter(|k| !mine.contains_key(*k)))
            .filter(|k| mine.get(*k) != theirs.get(*k))
            .cloned()
            .collect();
        for source in &self.sources {
            match other.sources.iter().find(|o| o.name == source.name) {
                None => changes.push(format!("source '{}' (removed)", source.name)),
                Some(o) if o != source => changes.push(format!("source '{}'", source.name)),
                Some(_) => {}
            }
        }
        for added in other
            .sources
            .iter()
            .filter(|o| !self.sources.iter().any(|s| s.name == o.name))
        {
            changes.push(format!("source '{}' (added)", added.name));
        }
        changes
    }

    /// Checks every rule the daemon applies before it starts a worker, and resolves each
    /// source's parameters. The one validation: `lanealignd check` runs exactly this (and
    /// [`Config::check_tile`]).
    pub fn resolve(&self, path: &Path) -> Result<Resolved, ConfigError> {
        let value = |key: String, message: String| ConfigError::Value {
            path: path.to_path_buf(),
            key,
            message,
        };
        let namespace: Namespace =
            self.namespace
                .parse()
                .map_err(|e: lanealign_wire::service::NameError| {
                    value("namespace".into(), e.to_string())
                })?;
        if let Some(bad) = self
            .trusted_tile_keys
            .iter()
            .find(|k| parse_key_hex(k).is_none())
        {
            return Err(value(
                "trusted_tile_keys".into(),
                format!(
                    "'{}' is not a public key (64 hex digits)",
                    lanealign_core::input::quote(bad)
                ),
            ));
        }
        if !(self.metrics_interval_s.is_finite()
            && (0.1..=3600.0).contains(&self.metrics_interval_s))
        {
            return Err(value(
                "metrics_interval_s".into(),
                format!(
                    "{:?}: must be between 0.1 and 3600 seconds",
                    self.metrics_interval_s
                ),
            ));
        }
        if !(self.session_timeout_s.is_finite()
            && (1.0..=604_800.0).contains(&self.session_timeout_s))
        {
            return Err(value(
                "session_timeout_s".into(),
                format!(
                    "{:?}: must be between 1 and 604800 seconds",
                    self.session_timeout_s
                ),
            ));
        }
        self.grid.validate().map_err(|e| value("grid".into(), e))?;
        if let Some(us) = self
            .cpu_dma_latency_us
            .filter(|&us| us > crate::cpu_latency::MAX_US)
        {
            return Err(value(
                "cpu_dma_latency_us".into(),
                format!(
                    "{us}: must be at most {} microseconds",
                    crate::cpu_latency::MAX_US
                ),
            ));
        }
        if !(1..=64).contains(&self.max_sessions) {
            return Err(value(
                "max_sessions".into(),
                format!("{}: must be between 1 and 64", self.max_sessions),
            ));
        }
        let state_dir = if self.journal {
            let dir = match &self.state_dir {
                Some(d) if d.is_relative() => path.parent().unwrap_or(Path::new(".")).join(d),
                Some(d) => d.clone(),
                None => default_state_dir().ok_or_else(|| {
                    value(
                        "state_dir".into(),
                        "no default: set state_dir, or LANEALIGN_STATE_DIR, or HOME".into(),
                    )
                })?,
            };
            Some(dir.join(namespace.as_str()))
        } else {
            None
        };
        if !(1..=MAX_SOURCES).contains(&self.sources.len()) {
            return Err(value(
                "source".into(),
                format!(
                    "{} [[source]] tables: 1 to {MAX_SOURCES} are served",
                    self.sources.len()
                ),
            ));
        }
        let mut resolved: Vec<ResolvedSource> = Vec::new();
        for s in &self.sources {
            let name: SourceName =
                s.name
                    .parse()
                    .map_err(|e: lanealign_wire::service::NameError| {
                        value("source.name".into(), e.to_string())
                    })?;
            if resolved.iter().any(|r| r.name == name) {
                return Err(value(
                    "source.name".into(),
                    format!("'{name}' is configured twice"),
                ));
            }
            let params = s
                .corrector
                .params()
                .map_err(|e| value(format!("source.{name}.corrector"), e.to_string()))?;
            s.wait
                .validate()
                .map_err(|e| value(format!("source.{name}.wait"), e.to_string()))?;
            resolved.push(ResolvedSource {
                name,
                corrector: s.corrector,
                params,
                convention: s.frame,
                anchor: s.anchor,
                pass_through: s.pass_through,
                wait: s.wait,
            });
        }
        Ok(Resolved {
            namespace,
            state_dir,
            sources: resolved,
        })
    }

    /// Refuses a tile (or a grid, by its manifest's signer) not signed by a trusted key (when
    /// keys are configured) and a tile whose lane geometry a source's method was not designed
    /// for.
    pub fn check_tile(
        &self,
        path: &Path,
        sources: &[ResolvedSource],
        tile: &TileInfo,
    ) -> Result<(), ConfigError> {
        self.check_signer(path, tile)?;
        self.check_map_version(path, tile)?;
        self.check_geometry(path, sources, tile)
    }

    /// What the map is called in the messages: a tile, or a grid's manifest.
    fn map_kind(&self) -> (&'static str, &'static str) {
        match grid::is_grid(&self.tile) {
            true => ("grid's manifest", "compile --grid SIZE_M"),
            false => ("tile", "compile"),
        }
    }

    /// Refuses a map older than [`Config::min_map_version`].
    fn check_map_version(&self, path: &Path, tile: &TileInfo) -> Result<(), ConfigError> {
        if tile.map_version < self.min_map_version {
            let (what, compile) = self.map_kind();
            return Err(ConfigError::Value {
                path: path.to_path_buf(),
                key: "min_map_version".into(),
                message: format!(
                    "{what} {} is map version {}, older than the oldest this daemon serves ({}): \
                     an older map put in its place? Build the current one with `lanealign-map \
                     {compile} --map-version N`",
                    self.tile.display(),
                    tile.map_version,
                    self.min_map_version
                ),
            });
        }
        Ok(())
    }

    /// The trusted signers' public keys, when the configuration names any (`None`: any valid
    /// tile or cell is accepted).
    pub fn trusted_keys(&self) -> Option<Vec<[u8; 32]>> {
        (!self.trusted_tile_keys.is_empty()).then(|| {
            self.trusted_tile_keys
                .iter()
                .filter_map(|k| parse_key_hex(k))
                .collect()
        })
    }

    /// Refuses a tile, or a grid's manifest, not signed by a trusted key, when keys are
    /// configured (a grid's cells are checked as they are loaded).
    fn check_signer(&self, path: &Path, tile: &TileInfo) -> Result<(), ConfigError> {
        if !self.trusted_tile_keys.is_empty() {
            let trusted = tile.signer.is_some_and(|signer| {
                self.trusted_tile_keys
                    .iter()
                    .any(|k| parse_key_hex(k) == Some(signer))
            });
            if !trusted {
                let signed = match tile.signer {
                    Some(key) => format!("signed by {}, which is not trusted", key_hex(&key)),
                    None => "not signed".to_string(),
                };
                let (what, compile) = self.map_kind();
                return Err(ConfigError::Value {
                    path: path.to_path_buf(),
                    key: "trusted_tile_keys".into(),
                    message: format!(
                        "{what} {} is {signed}: compile it with `lanealign-map {compile} --sign KEY`",
                        self.tile.display()
                    ),
                });
            }
        }
        Ok(())
    }

    /// Refuses a tile (or grid) whose lane geometry a source's method was not designed for.
    pub fn check_geometry(
        &self,
        path: &Path,
        sources: &[ResolvedSource],
        tile: &TileInfo,
    ) -> Result<(), ConfigError> {
        for s in sources.iter().filter(|s| !s.pass_through) {
            s.corrector
                .check_geometry(&tile.geometry)
                .map_err(|e| ConfigError::Value {
                    path: path.to_path_buf(),
                    key: format!("source.{}.corrector", s.name),
                    message: format!("tile {}: {e}", self.tile.display()),
                })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lanealign_core::params::{Method, Preset};

    const GOOD: &str = r#"
tile = "maps/00.tile"
[[source]]
name = "lidar"
frame = "kitti-camera"
anchor = { lat = 48.98, lon = 8.39, yaw_deg = 59.5 }
corrector = { preset = "kiss-icp", overrides = { max_window = 800 } }
"#;

    fn resolve(text: &str) -> Result<Resolved, ConfigError> {
        let p = Path::new("/etc/lanealign/d.toml");
        Config::parse(text, p)?.resolve(p)
    }

    #[test]
    fn a_good_config_resolves() {
        let p = Path::new("/etc/lanealign/d.toml");
        let c = Config::parse(GOOD, p).unwrap();
        assert_eq!(c.tile, Path::new("/etc/lanealign/maps/00.tile"));
        let r = c.resolve(&p.with_file_name("x.toml")).unwrap();
        let s = r.sources;
        assert_eq!(r.namespace, Namespace::default());
        assert_eq!(s[0].params.max_window, 800);
        assert_eq!(s[0].corrector.method, Method::Robust);
        assert_eq!(s[0].convention, AxisConvention::KittiCamera);
        assert_eq!(c.metrics_interval_s, 5.0);
    }

    #[test]
    fn changes_name_the_keys_and_sources_that_differ() {
        let p = Path::new("/etc/lanealign/d.toml");
        let parse = |text: &str| Config::parse(text, p).unwrap();
        let running = parse(GOOD);
        assert_eq!(running.changes_to(&parse(GOOD)), Vec::<String>::new());
        let camera = "\n[[source]]\nname = \"camera\"\nanchor = { lat = 48.98, lon = 8.39, yaw_deg = 0 }\ncorrector = { preset = \"orb-slam3\" }\n";
        let changed = format!(
            "max_sessions = 4\n{}{camera}",
            GOOD.replace("maps/00.tile", "maps/01.tile")
                .replace("800", "900")
        );
        assert_eq!(
            running.changes_to(&parse(&changed)),
            [
                "max_sessions",
                "tile",
                "source 'lidar'",
                "source 'camera' (added)"
            ]
        );
        let both = parse(&format!("{GOOD}{camera}"));
        let reordered = format!(
            "tile = \"maps/00.tile\"\n{camera}{}",
            GOOD.replace("tile = \"maps/00.tile\"", "")
        );
        assert_eq!(both.changes_to(&parse(&reordered)), Vec::<String>::new());
        assert_eq!(both.changes_to(&running), ["source 'camera' (removed)"]);
    }

    #[test]
    fn the_shipped_config_is_valid() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/lanealignd.toml");
        let config = Config::load(&path).unwrap();
        let sources = config.resolve(&path).unwrap().sources;
        assert!(config.tile.ends_with("kitti_00.tile"));
        assert_eq!(sources[0].name.as_str(), "lidar");
        assert_eq!(sources[0].convention, AxisConvention::KittiCamera);
        assert_eq!(sources[0].corrector.preset, Preset::KissIcp);
    }

    #[test]
    fn the_grid_policy_is_read_and_checked() {
        let p = Path::new("/x/d.toml");
        let with = |grid: &str| GOOD.replacen("[[source]]", &format!("{grid}\n[[source]]"), 1);
        let c = Config::parse(&with("[grid]\nradius_m = 400.0\nahead_m = 0.0"), p).unwrap();
        assert_eq!((c.grid.radius_m, c.grid.ahead_m), (400.0, 0.0));
        assert!(c.resolve(p).is_ok());
        let c = Config::parse(&with("[grid]\nradius_m = -1.0\nahead_m = 0.0"), p).unwrap();
        let e = c.resolve(p).unwrap_err().to_string();
        assert!(e.contains("radius_m"), "{e}");
        let c = Config::parse(&with("[grid]\nradius_m = 1e300\nahead_m = 0.0"), p).unwrap();
        let e = c.resolve(p).unwrap_err().to_string();
        assert!(e.contains("radius_m = 1e300: must be 0 to"), "{e}");
        assert!(Config::parse(&with("[grid]\nradius = 4.0"), p).is_err());
        assert_eq!(Config::parse(GOOD, p).unwrap().grid, LoadPolicy::default());
    }

    #[test]
    fn a_config_written_by_serde_reads_back() {
        let p = Path::new("/x/d.toml");
        let c = Config::parse(GOOD, p).unwrap();
        let text = toml::to_string(&c).unwrap();
        assert_eq!(Config::parse(&text, p).unwrap(), c);
    }

    #[test]
    fn bad_configs_name_the_key() {
        let cases = [
            (GOOD.replace("\"kiss-icp\"", "\"kiss\""), "kiss-icp"),
            (
                GOOD.replace("max_window = 800", "max_windw = 800"),
                "max_windw",
            ),
            (
                GOOD.replace("max_window = 800", "max_window = 3"),
                "source.lidar.corrector: max_window = 3",
            ),
            (GOOD.replace("tile =", "tiles ="), "tiles"),
            (GOOD.replace("preset = \"kiss-icp\", ", ""), "preset"),
            (
                GOOD.replace("frame = \"kitti-camera\"", "frame = \"kitti\""),
                "kitti-camera",
            ),
            (format!("{GOOD}\ncolour = 1\n"), "colour"),
            (GOOD.replace("lat = 48.98", "lat = 91.0"), "latitude 91"),
            (
                format!("metrics_interval_s = 1e300\n{GOOD}"),
                "metrics_interval_s: 1e300: must be between 0.1 and 3600 seconds",
            ),
            (
                GOOD.replace("lat = 48.98", "lat = -1e300"),
                "latitude -1e300 is outside",
            ),
            (GOOD.replace("\"lidar\"", &format!("\"{}\"", "x".repeat(300))), "longer than 64"),
            (format!("namespace = \"a b\"\n{GOOD}"), "namespace"),
            (
                format!("namespace = \"{}\"\n{GOOD}", "n".repeat(16)),
                "namespace 'nnnnnnnnnnnnnnnn': longer than 15 characters",
            ),
            (format!("max_sessions = 0\n{GOOD}"), "max_sessions"),
            (
                format!("cpu_dma_latency_us = 1000001\n{GOOD}"),
                "cpu_dma_latency_us: 1000001: must be at most 1000000",
            ),
            (format!("cpu_dma_latency_us = -1\n{GOOD}"), "cpu_dma_latency_us"),
            (format!("session_timeout_s = -1\n{GOOD}"), "session_timeout_s"),
            (
                format!("{GOOD}\n[[source]]\nname = \"lidar\"\nanchor = {{ lat = 1.0, lon = 1.0, yaw_deg = 0.0 }}\ncorrector = {{ preset = \"basalt\" }}\n"),
                "configured twice",
            ),
        ];
        for (text, key) in cases {
            let e = resolve(&text).unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }
}
