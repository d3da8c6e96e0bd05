//! The daemon's configuration (TOML). Unknown keys and bad values are refused at start, naming
//! the key; see `configs/lanealignd.toml` for every field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Anchor;
use lanealign_core::params::{Method, Params, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::smoothing::Smoothing;
use serde::Deserialize;

/// The whole configuration file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The lane tile (relative paths are relative to the config file).
    pub tile: PathBuf,
    /// Seconds between two metrics reports per source.
    #[serde(default = "default_metrics_interval")]
    pub metrics_interval_s: f64,
    /// `text` or `json` log lines.
    #[serde(default)]
    pub log_format: LogFormat,
    /// The odometry sources.
    #[serde(rename = "source")]
    pub sources: Vec<SourceConfig>,
}

fn default_metrics_interval() -> f64 {
    5.0
}

/// Log line format.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON object per line.
    Json,
}

/// One odometry source.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// The source name: its services are `lanealign/<name>/odom` and `.../corrected`.
    pub name: String,
    /// liodom, basalt, kiss-icp or orb-slam3.
    pub preset: String,
    /// `robust` (default, docs/method.md) or `paper` (the published algorithm).
    #[serde(default = "default_method")]
    pub method: String,
    /// Publish smoothed poses (at most 5 cm and 0.1 degree per pose beyond the odometry's own
    /// motion); `map_from_odom` stays exact.
    #[serde(default)]
    pub smooth: bool,
    /// Parameter overrides by name (see `Params::KEYS`).
    #[serde(default)]
    pub overrides: BTreeMap<String, toml::Value>,
    /// Axis convention of the source's poses: `flu` or `kitti-camera`.
    #[serde(default = "default_frame")]
    pub frame: String,
    /// Where the source's odometry frame lies on Earth.
    pub anchor: AnchorConfig,
    /// `fast` (default) or `reference` matching.
    #[serde(default = "default_match_mode")]
    pub match_mode: String,
    /// Echo poses back without correcting them (to measure the transport alone).
    #[serde(default)]
    pub pass_through: bool,
}

fn default_method() -> String {
    "robust".into()
}

fn default_frame() -> String {
    "flu".into()
}

fn default_match_mode() -> String {
    "fast".into()
}

/// A source's anchor (`kitti/georef.csv` semantics).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorConfig {
    /// Origin latitude, degrees.
    pub lat: f64,
    /// Origin longitude, degrees.
    pub lon: f64,
    /// Yaw of the odometry x axis, counter-clockwise from East, degrees.
    pub yaw_deg: f64,
    /// East offset of the odometry origin, metres.
    #[serde(default)]
    pub east_m: f64,
    /// North offset of the odometry origin, metres.
    #[serde(default)]
    pub north_m: f64,
}

/// A source ready to run.
#[derive(Debug, Clone)]
pub struct ResolvedSource {
    /// Its name.
    pub name: String,
    /// Its corrector parameters.
    pub params: Params,
    /// Smoothing of its published poses, if asked for.
    pub smoothing: Option<Smoothing>,
    /// Its axis convention.
    pub convention: AxisConvention,
    /// Its anchor.
    pub anchor: Anchor,
    /// Its match mode.
    pub match_mode: MatchMode,
    /// Echo without correcting.
    pub pass_through: bool,
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
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
        /// The key, dotted (`source.lidar.preset`).
        key: String,
        /// What is wrong.
        message: String,
    },
}

impl Config {
    /// Reads and checks a configuration file; makes `tile` absolute.
    pub fn load(path: &Path) -> Result<(Config, Vec<ResolvedSource>), ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and checks configuration text; `path` names it and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<(Config, Vec<ResolvedSource>), ConfigError> {
        let mut config: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let value = |key: String, message: String| ConfigError::Value {
            path: path.to_path_buf(),
            key,
            message,
        };
        if config.tile.is_relative() {
            config.tile = path.parent().unwrap_or(Path::new(".")).join(&config.tile);
        }
        if !(config.metrics_interval_s.is_finite() && config.metrics_interval_s > 0.0) {
            return Err(value(
                "metrics_interval_s".into(),
                "must be a positive number of seconds".into(),
            ));
        }
        if config.sources.is_empty() {
            return Err(value(
                "source".into(),
                "at least one [[source]] is needed".into(),
            ));
        }
        let mut resolved = Vec::new();
        for s in &config.sources {
            let key = |field: &str| format!("source.{}.{field}", s.name);
            if s.name.is_empty()
                || !s
                    .name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(value(
                    "source.name".into(),
                    format!("'{}': use letters, digits, '-' and '_'", s.name),
                ));
            }
            if resolved.iter().any(|r: &ResolvedSource| r.name == s.name) {
                return Err(value(
                    "source.name".into(),
                    format!("'{}' is configured twice", s.name),
                ));
            }
            let preset: Preset =
                s.preset
                    .parse()
                    .map_err(|e: lanealign_core::params::ParamsError| {
                        value(key("preset"), e.to_string())
                    })?;
            let method: Method =
                s.method
                    .parse()
                    .map_err(|e: lanealign_core::params::ParamsError| {
                        value(key("method"), e.to_string())
                    })?;
            let mut params = method.params(preset);
            for (k, v) in &s.overrides {
                let text = match v {
                    toml::Value::String(t) => t.clone(),
                    other => other.to_string(),
                };
                params
                    .set(k, &text)
                    .map_err(|e| value(key(&format!("overrides.{k}")), e.to_string()))?;
            }
            let convention: AxisConvention = s
                .frame
                .parse()
                .map_err(|e: String| value(key("frame"), e))?;
            let match_mode: MatchMode = s
                .match_mode
                .parse()
                .map_err(|e: String| value(key("match_mode"), e))?;
            let a = s.anchor;
            let anchor_text = format!(
                "{},{},{},{},{}",
                a.lat, a.lon, a.yaw_deg, a.east_m, a.north_m
            );
            let anchor: Anchor = anchor_text
                .parse()
                .map_err(|e: String| value(key("anchor"), e))?;
            if a.lat.abs() > 90.0 || a.lon.abs() > 180.0 {
                return Err(value(
                    key("anchor"),
                    "latitude or longitude out of range".into(),
                ));
            }
            resolved.push(ResolvedSource {
                name: s.name.clone(),
                params,
                smoothing: s.smooth.then(Smoothing::default),
                convention,
                anchor,
                match_mode,
                pass_through: s.pass_through,
            });
        }
        Ok((config, resolved))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
tile = "maps/00.tile"
[[source]]
name = "lidar"
preset = "kiss-icp"
frame = "kitti-camera"
anchor = { lat = 48.98, lon = 8.39, yaw_deg = 59.5 }
overrides = { max_window = 800 }
"#;

    #[test]
    fn a_good_config_resolves() {
        let (c, s) = Config::parse(GOOD, Path::new("/etc/lanealign/d.toml")).unwrap();
        assert_eq!(c.tile, Path::new("/etc/lanealign/maps/00.tile"));
        assert_eq!(s[0].params.max_window, 800);
        assert_eq!(s[0].convention, AxisConvention::KittiCamera);
        assert_eq!(c.metrics_interval_s, 5.0);
    }

    #[test]
    fn the_shipped_config_is_valid() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/lanealignd.toml");
        let (config, sources) = Config::load(&path).unwrap();
        assert!(config.tile.ends_with("kitti_00.tile"));
        assert_eq!(sources[0].name, "lidar");
        assert_eq!(sources[0].convention, AxisConvention::KittiCamera);
    }

    #[test]
    fn bad_configs_name_the_key() {
        let p = Path::new("d.toml");
        let cases = [
            (
                GOOD.replace("preset = \"kiss-icp\"", "preset = \"kiss\""),
                "source.lidar.preset",
            ),
            (
                GOOD.replace("max_window = 800", "max_windw = 800"),
                "source.lidar.overrides.max_windw",
            ),
            (
                GOOD.replace("max_window = 800", "max_window = 3"),
                "source.lidar.overrides.max_window",
            ),
            (GOOD.replace("tile =", "tiles ="), "tiles"),
            (GOOD.replace("preset = \"kiss-icp\"\n", ""), "preset"),
            (
                GOOD.replace("frame = \"kitti-camera\"", "frame = \"kitti\""),
                "source.lidar.frame",
            ),
            (format!("{GOOD}\ncolour = 1\n"), "colour"),
        ];
        for (text, key) in cases {
            let e = Config::parse(&text, p).unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }
}
