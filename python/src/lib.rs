//! The `lanealign._lanealign` extension: `correct` and `eval` on numpy arrays, the same code and
//! defaults as `lanealign correct` and `lanealign eval`, so that results are equal bit for bit.

use std::ffi::CString;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use lanealign_cli::maps::MapSource;
use lanealign_cli::synthetic;
use lanealign_cli::{evaluation, status_file};
use lanealign_client::connection::new_session_id;
use lanealign_client::{Closed, Connection};
use lanealign_core::corrector::Status;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::input::write_atomic;
use lanealign_core::lane_geometry::{RoadClasses, Traffic};
use lanealign_core::metrics::{ape_2d, calibration};
use lanealign_core::params::{CorrectorConfig, Method, Overrides, Preset, UNMARKED_OFFSET_SCALE};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::report::error_line;
use lanealign_core::source_corrector::Placement;
use lanealign_core::tile;
use lanealign_core::trajectory::{self, Trajectory};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::grid_compile::{compile_grid, GridOptions};
use lanealign_map::keys::{self, read_secret_key};
use lanealign_map::osm_lanes::LaneOptions;
use lanealign_wire::clock::{deadline_after, time_left};
use lanealign_wire::payload::{
    from_upper_triangle, CorrectedPose, ReasonCode, StatusCode, Warning,
};
use lanealign_wire::service::{Namespace, SourceName, WIRE_VERSION};
use lanealign_wire::wait::WaitStrategy;
use numpy::ndarray::{Array1, Array3, ArrayD, ArrayViewD, Axis, IxDyn};
use numpy::{
    AllowTypeChange, IntoPyArray, PyArray1, PyArray3, PyArrayDyn, PyArrayLikeDyn, PyReadonlyArray1,
    PyReadonlyArrayDyn,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyString};

/// An error as Python sees it: the message and its causes, as the command line prints them.
fn error(e: impl Into<anyhow::Error>) -> PyErr {
    PyValueError::new_err(message(e))
}

/// An error's message and its causes on one line, each cause once, as the command line shows
/// them.
fn message(e: impl Into<anyhow::Error>) -> String {
    error_line(e.into().as_ref())
}

/// The status names, indexed by the codes `correct` returns.
const STATUS_NAMES: [&str; 7] = Status::NAMES;

/// The 12 row-major numbers of each pose (a KITTI row each) of an (N, 3, 4), (N, 4, 4) or
/// (N, 12) array; `None` for any other shape.
fn kitti_rows(array: &ArrayViewD<'_, f64>) -> Option<Vec<[f64; 12]>> {
    let element: &dyn Fn(usize, usize) -> f64 = match array.shape() {
        [_, 3 | 4, 4] => &|i, k| array[IxDyn(&[i, k / 4, k % 4])],
        [_, 12] => &|i, k| array[IxDyn(&[i, k])],
        _ => return None,
    };
    Some(
        (0..array.shape()[0])
            .map(|i| std::array::from_fn(|k| element(i, k)))
            .collect(),
    )
}

/// The poses of an (N, 3, 4), (N, 4, 4) or (N, 12) array; `None` for any other shape.
fn kitti_poses(array: &ArrayViewD<'_, f64>) -> Option<Vec<Pose3>> {
    kitti_rows(array).map(|rows| rows.iter().map(Pose3::from_row_major).collect())
}

/// Poses of shape (N, 3, 4), (N, 4, 4), (N, 12) (a KITTI file's rows, as `np.loadtxt` reads
/// it) or planar (N, 3) `[x, y, yaw]`.
fn poses_from(array: &ArrayViewD<'_, f64>) -> PyResult<Vec<Pose3>> {
    if let Some(poses) = kitti_poses(array) {
        return Ok(poses);
    }
    match array.shape() {
        [n, 3] => Ok((0..*n)
            .map(|i| {
                let p = |c: usize| array[IxDyn(&[i, c])];
                Pose3::planar(p(0), p(1), p(2), 0.0)
            })
            .collect()),
        shape => Err(PyValueError::new_err(format!(
            "poses must have shape (N, 3, 4), (N, 4, 4), (N, 12) or (N, 3), not {shape:?}"
        ))),
    }
}

/// `poses` in the shape of `like`.
fn poses_into(poses: &[Pose3], like: &[usize]) -> ArrayD<f64> {
    let mut out = ArrayD::zeros(IxDyn(like));
    for (i, p) in poses.iter().enumerate() {
        match like {
            [_, 3] => {
                let [x, y] = p.planar_position();
                out[IxDyn(&[i, 0])] = x;
                out[IxDyn(&[i, 1])] = y;
                out[IxDyn(&[i, 2])] = p.planar_heading();
            }
            [_, 12] => {
                for (k, value) in p.to_row_major().into_iter().enumerate() {
                    out[IxDyn(&[i, k])] = value;
                }
            }
            _ => {
                for (k, value) in p.to_row_major().into_iter().enumerate() {
                    out[IxDyn(&[i, k / 4, k % 4])] = value;
                }
                if like[1] == 4 {
                    out[IxDyn(&[i, 3, 3])] = 1.0;
                }
            }
        }
    }
    out
}

fn parsed<T: std::str::FromStr>(what: &str, text: &str) -> PyResult<T>
where
    T::Err: std::fmt::Display,
{
    text.parse().map_err(|e| {
        PyValueError::new_err(format!(
            "{what} \"{}\": {e}",
            lanealign_core::input::quote(text)
        ))
    })
}

/// An anchor from (lat, lon, yaw_deg) or (lat, lon, yaw_deg, east_m, north_m), as the command
/// line's `--anchor` takes it.
fn anchor_from(values: &[f64]) -> PyResult<Anchor> {
    let (lat, lon, yaw_deg, east_m, north_m) = match *values {
        [lat, lon, yaw_deg] => (lat, lon, yaw_deg, 0.0, 0.0),
        [lat, lon, yaw_deg, east_m, north_m] => (lat, lon, yaw_deg, east_m, north_m),
        _ => {
            return Err(PyValueError::new_err(format!(
            "anchor is (lat, lon, yaw_deg) or (lat, lon, yaw_deg, east_m, north_m), not {} values",
            values.len()
        )))
        }
    };
    Anchor::new(lat, lon, yaw_deg, east_m, north_m).map_err(error)
}

/// The corrected poses (the input's shape and frame), a status code per pose (an index into
/// `STATUS_NAMES`), the covariance of each corrected pose (N, 3, 3; map plane, x, y in metres
/// and yaw in radians), and the odometry's scale estimate after each pose with its standard
/// deviation (N each; ratios).
type Corrected<'py> = (
    Bound<'py, PyArrayDyn<f64>>,
    Bound<'py, PyArray1<u8>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    f64,
);

/// The stamps (seconds) of `poses` poses given as argument `name`, checked as a TUM file's are
/// (`trajectory::stamps_problem`): one per pose, finite and increasing.
fn checked_stamps(
    name: &str,
    stamps: Option<&PyReadonlyArray1<'_, f64>>,
    poses: usize,
) -> PyResult<Option<Vec<f64>>> {
    let Some(stamps) = stamps.map(|s| s.as_array().to_vec()) else {
        return Ok(None);
    };
    if stamps.len() != poses {
        return Err(PyValueError::new_err(format!(
            "{name}: {} stamps for {poses} poses",
            stamps.len()
        )));
    }
    if let Some((i, problem)) = trajectory::stamps_problem(&stamps) {
        return Err(PyValueError::new_err(format!("{name}[{i}]: {problem}")));
    }
    Ok(Some(stamps))
}

/// Parameter overrides from a dict of names to numbers and bools, read as the command line's
/// `--set KEY=VALUE` reads them (a float stays a float: `800.0` is no pose count).
fn overrides_from(dict: &Bound<'_, PyDict>) -> PyResult<Overrides> {
    let mut pairs = Vec::with_capacity(dict.len());
    for (key, value) in dict.iter() {
        let key: String = key.extract().map_err(|_| {
            PyValueError::new_err(format!("overrides: {key}: not a parameter name"))
        })?;
        let text = if value.is_instance_of::<PyBool>() {
            value.extract::<bool>()?.to_string()
        } else if let Ok(i) = value.extract::<i64>() {
            i.to_string()
        } else if let Ok(f) = value.extract::<f64>() {
            match f {
                f if f.is_nan() => "nan".to_string(),
                f if f.is_infinite() => (if f > 0.0 { "inf" } else { "-inf" }).to_string(),
                f => format!("{f:?}"),
            }
        } else {
            return Err(PyValueError::new_err(format!(
                "overrides: {key} = {}: not a number or a bool",
                value.repr()?
            )));
        };
        pairs.push((key, text));
    }
    Overrides::from_assignments(pairs.iter().map(|(k, v)| (k.as_str(), v.as_str())))
        .map_err(|e| PyValueError::new_err(format!("overrides: {e}")))
}

/// Corrects a trajectory as `lanealign correct` does (see the package's docstring).
#[allow(clippy::too_many_arguments)]
#[pyfunction]
#[pyo3(signature = (poses, *, preset, osm=None, tile=None, lanes=None, anchor=None, projection=None, method="robust", frame="flu", odometry_rate_hz=None, smooth=false, overrides=None, stamps=None, status=None))]
fn correct<'py>(
    py: Python<'py>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    preset: &str,
    osm: Option<PathBuf>,
    tile: Option<PathBuf>,
    lanes: Option<PathBuf>,
    anchor: Option<Vec<f64>>,
    projection: Option<&str>,
    method: &str,
    frame: &str,
    odometry_rate_hz: Option<f64>,
    smooth: bool,
    overrides: Option<Bound<'py, PyDict>>,
    stamps: Option<PyReadonlyArray1<'py, f64>>,
    status: Option<PathBuf>,
) -> PyResult<Corrected<'py>> {
    let array = poses.as_array();
    let shape = array.shape().to_vec();
    let frame: AxisConvention = parsed("frame", frame)?;
    let input = poses_from(&array)?;
    let stamps = checked_stamps("stamps", stamps.as_ref(), input.len())?;
    if matches!(shape.as_slice(), [_, 3]) && frame != AxisConvention::Flu {
        return Err(PyValueError::new_err(
            "planar (N, 3) poses are in the flu frame",
        ));
    }
    let mut config = CorrectorConfig::new(parsed::<Preset>("preset", preset)?, {
        parsed::<Method>("method", method)?
    });
    config.smooth = smooth;
    if let Some(dict) = &overrides {
        config.overrides = overrides_from(dict)?;
    }
    if odometry_rate_hz.is_some() {
        if config.overrides.odometry_rate_hz.is_some() {
            return Err(PyValueError::new_err(
                "odometry_rate_hz is given twice: as an argument and in overrides",
            ));
        }
        config.overrides.odometry_rate_hz = odometry_rate_hz;
    }
    let params = config.params().map_err(error)?;
    let projection = projection
        .map(|p| parsed::<Projection>("projection", p))
        .transpose()?;
    let anchor = anchor.as_deref().map(anchor_from).transpose()?;
    let need_anchor = || {
        anchor.ok_or_else(|| {
            PyValueError::new_err(
                "osm= and tile= need anchor=(lat, lon, yaw_deg[, east_m, north_m])",
            )
        })
    };
    let source = match (osm, tile, lanes) {
        (Some(path), None, None) => MapSource::Osm {
            path,
            anchor: need_anchor()?,
            projection: projection.unwrap_or_default(),
            options: LaneOptions {
                classes: RoadClasses::DEFAULT,
                traffic: Traffic::Right,
                spacing_m: 3.0,
                unmarked_offset_scale: config.unmarked_offset_scale(),
            },
        },
        (None, Some(path), None) => MapSource::Tile {
            path,
            anchor: need_anchor()?,
            projection,
        },
        (None, None, Some(path)) => MapSource::LanesCsv(path),
        _ => {
            return Err(PyValueError::new_err(
                "give exactly one of osm=, tile= and lanes=",
            ))
        }
    };
    let (run, anchor_yaw, warnings) = py
        .detach(|| -> anyhow::Result<_> {
            let loaded = source.load_for(&config)?;
            let placement = Placement {
                convention: frame,
                anchored_from_odom: loaded.anchored_from_odom,
                smoothing: config.smoothing(),
            };
            let run = loaded
                .correct(
                    params,
                    config.match_mode,
                    placement,
                    &input,
                    stamps.as_deref(),
                )?
                .0;
            let warnings = loaded.warnings(&input, stamps.as_deref(), frame, &run, &params);
            if let Some(path) = &status {
                let text = status_file::of_run(&run, &loaded.anchored_from_odom);
                write_atomic(path, text.as_bytes())?;
            }
            Ok((run, loaded.anchored_from_odom.yaw(), warnings))
        })
        .map_err(error)?;
    // What `lanealign correct` prints as WARN lines, as Python warnings, at the line that
    // called `lanealign.correct` (level 1 is the package's wrapper around this function).
    for warning in warnings {
        let message = CString::new(warning).map_err(|e| PyValueError::new_err(e.to_string()))?;
        PyErr::warn(py, &py.get_type::<PyUserWarning>(), &message, 2)?;
    }
    let corrected: Vec<Pose3> = run.iter().map(|c| c.pose).collect();
    let codes: Array1<u8> = run
        .iter()
        .map(|c| {
            STATUS_NAMES
                .iter()
                .position(|n| *n == c.status.name())
                .unwrap_or(0) as u8
        })
        .collect();
    let mut covariance = Array3::zeros((run.len(), 3, 3));
    for (i, c) in run.iter().enumerate() {
        for r in 0..3 {
            for k in 0..3 {
                covariance[[i, r, k]] = c.covariance[r][k];
            }
        }
    }
    let odometry_scale: Array1<f64> = run.iter().map(|c| c.odometry_scale).collect();
    let odometry_scale_sd: Array1<f64> = run.iter().map(|c| c.odometry_scale_sd).collect();
    Ok((
        poses_into(&corrected, &shape).into_pyarray(py),
        codes.into_pyarray(py),
        covariance.into_pyarray(py),
        odometry_scale.into_pyarray(py),
        odometry_scale_sd.into_pyarray(py),
        anchor_yaw,
    ))
}

/// APE-2D of `est` against `gt` (paired by index, or given both stamps by time within `max_dt`
/// seconds), as `lanealign eval --json` reports it; with
/// `covariance` ((N, 3, 3), the map plane's, as `correct` returns it) and `anchor_yaw` (radians,
/// the map plane's rotation from the odometry frame) also its calibration, as `eval --status`.
#[pyfunction]
#[pyo3(signature = (gt, est, *, frame="flu", covariance=None, anchor_yaw=None, gt_stamps=None, est_stamps=None, max_dt=evaluation::DEFAULT_MAX_DT_S))]
#[allow(clippy::too_many_arguments)]
fn eval<'py>(
    py: Python<'py>,
    gt: PyReadonlyArrayDyn<'py, f64>,
    est: PyReadonlyArrayDyn<'py, f64>,
    frame: &str,
    covariance: Option<PyReadonlyArrayDyn<'py, f64>>,
    anchor_yaw: Option<f64>,
    gt_stamps: Option<PyReadonlyArray1<'py, f64>>,
    est_stamps: Option<PyReadonlyArray1<'py, f64>>,
    max_dt: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let frame: AxisConvention = parsed("frame", frame)?;
    evaluation::checked_max_dt_s(max_dt)
        .map_err(|e| PyValueError::new_err(format!("max_dt: {max_dt} {e}")))?;
    if gt_stamps.is_some() != est_stamps.is_some() {
        return Err(PyValueError::new_err(
            "gt_stamps= and est_stamps= go together (pairing by time needs both)",
        ));
    }
    let trajectory = |what: &str,
                      a: &PyReadonlyArrayDyn<'py, f64>,
                      stamps: Option<&PyReadonlyArray1<'py, f64>>|
     -> PyResult<Trajectory> {
        let poses = poses_from(&a.as_array())?;
        let stamps = checked_stamps(&format!("{what}_stamps"), stamps, poses.len())?;
        Ok(Trajectory { stamps, poses })
    };
    let est = trajectory("est", &est, est_stamps.as_ref())?;
    let paired = evaluation::pair(
        &trajectory("gt", &gt, gt_stamps.as_ref())?,
        &est,
        frame,
        evaluation::Pairing {
            max_dt_s: max_dt,
            est_offset_s: 0.0,
        },
    )
    .map_err(error)?;
    let m = ape_2d(&paired.gt, &paired.est).map_err(error)?;
    let check = match (covariance, anchor_yaw) {
        (None, None) => None,
        (Some(c), Some(yaw)) => {
            // One covariance per estimated pose, taken for the poses paired.
            let all = position_covariances(&c.as_array(), est.poses.len(), yaw)?;
            let covariance: Vec<[[f64; 2]; 2]> = paired.pairs.iter().map(|p| all[p.1]).collect();
            Some(
                calibration(&paired.gt, &paired.est, &covariance)
                    .map_err(error)?
                    .check(),
            )
        }
        _ => {
            return Err(PyValueError::new_err(
                "covariance= and anchor_yaw= go together (Corrected.covariance and \
                 Corrected.anchor_yaw)",
            ))
        }
    };
    // The command's own JSON, read by Python's parser: the same keys and, the numbers written
    // shortest round-trip, the same values bit for bit.
    let json = evaluation::figures_json(&m, check.as_ref()).map_err(error)?;
    Ok(py
        .import("json")?
        .call_method1("loads", (json.to_string(),))?
        .cast_into::<PyDict>()?)
}

/// The position covariances of an (N, 3, 3) array of map-plane covariances, turned into the
/// planar odometry frame of a source anchored with yaw `anchor_yaw` (radians), as `eval
/// --status` turns a status CSV's.
fn position_covariances(
    array: &numpy::ndarray::ArrayViewD<'_, f64>,
    poses: usize,
    anchor_yaw: f64,
) -> PyResult<Vec<[[f64; 2]; 2]>> {
    if array.shape() != [poses, 3, 3] {
        return Err(PyValueError::new_err(format!(
            "covariance: shape {:?}, expected ({poses}, 3, 3), one per pose",
            array.shape()
        )));
    }
    if !lanealign_core::geo::is_anchor_yaw_rad(anchor_yaw) {
        return Err(PyValueError::new_err(format!(
            "anchor_yaw: {anchor_yaw:?} is not an angle in [-2 pi, 2 pi] radians"
        )));
    }
    (0..poses)
        .map(|i| {
            let c = |r: usize, k: usize| array[[i, r, k]];
            let covariance = [
                [c(0, 0), c(0, 1), c(0, 2)],
                [c(1, 0), c(1, 1), c(1, 2)],
                [c(2, 0), c(2, 1), c(2, 2)],
            ];
            if let Some((r, k)) = asymmetric_entry(&covariance) {
                return Err(PyValueError::new_err(format!(
                    "the covariance of pose {i} is not symmetric: [{r}, {k}] = {:?}, [{k}, {r}] = {:?}",
                    covariance[r][k], covariance[k][r]
                )));
            }
            Ok(status_file::position_covariance_in_odom(
                anchor_yaw,
                &covariance,
            ))
        })
        .collect()
}

/// The first off-diagonal entry `(r, k)` of `covariance` that differs from its mirror by more
/// than rounding (1e-9 of `sqrt(c_rr c_kk)`, the largest a covariance of those two variances
/// can be, in its units), if any. Not finite entries are left to the positive-definiteness
/// check.
fn asymmetric_entry(covariance: &[[f64; 3]; 3]) -> Option<(usize, usize)> {
    [(0, 1), (0, 2), (1, 2)].into_iter().find(|&(r, k)| {
        let scale = (covariance[r][r] * covariance[k][k]).abs().sqrt();
        (covariance[r][k] - covariance[k][r]).abs() > 1e-9 * scale
    })
}

/// Compiles road data into a lane tile (or with `grid` a grid folder; PBF inputs stream), as
/// `lanealign-map compile` does, signed with the key in file `sign` when given; returns what
/// it holds.
#[allow(clippy::too_many_arguments)]
#[pyfunction]
#[pyo3(signature = (inputs, output, *, origin=None, projection="tangent", spacing=3.0, traffic="right", unmarked_offset_scale=UNMARKED_OFFSET_SCALE, grid=None, margin=50.0, classes=None, sign=None, map_version=0))]
fn compile_map<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    origin: Option<(f64, f64)>,
    projection: &str,
    spacing: f64,
    traffic: &str,
    unmarked_offset_scale: f64,
    grid: Option<f64>,
    margin: f64,
    classes: Option<&str>,
    sign: Option<PathBuf>,
    map_version: i128,
) -> PyResult<Bound<'py, PyDict>> {
    if inputs.is_empty() {
        return Err(PyValueError::new_err(
            "inputs: none given (a list of .osm, .osm.pbf or Lanelet2 files)",
        ));
    }
    lanealign_core::lane_map::check_spacing(spacing)
        .map_err(|e| PyValueError::new_err(format!("spacing: {e}")))?;
    lanealign_core::lane_geometry::check_unmarked_offset_scale(unmarked_offset_scale)
        .map_err(|e| PyValueError::new_err(format!("unmarked_offset_scale: {e}")))?;
    if map_version < 0 {
        return Err(PyValueError::new_err(format!(
            "map_version: {map_version}: a map version counts builds, 0 or more"
        )));
    }
    let map_version = u64::try_from(map_version)
        .map_err(|_| tile::TileError::MapVersion {
            map_version: map_version.unsigned_abs(),
        })
        .and_then(|v| tile::check_map_version(v).map(|()| v))
        .map_err(|e| PyValueError::new_err(format!("map_version: {e}")))?;
    let classes = match classes {
        Some(list) => RoadClasses::parse_list(list)
            .map_err(|e| PyValueError::new_err(format!("classes: {e}")))?,
        None => RoadClasses::DEFAULT,
    };
    let options = CompileOptions {
        origin,
        projection: parsed("projection", projection)?,
        lanes: LaneOptions {
            classes,
            traffic: parsed("traffic", traffic)?,
            spacing_m: spacing,
            unmarked_offset_scale,
        },
    };
    let given: Vec<Option<&std::path::Path>> = inputs
        .iter()
        .map(|p| Some(p.as_path()))
        .chain([sign.as_deref()])
        .collect();
    lanealign_core::input::check_outputs_apart(&[Some(&output)], &given).map_err(error)?;
    let key = sign
        .as_deref()
        .map(read_secret_key)
        .transpose()
        .map_err(error)?;
    if let Some(warning) = sign.as_deref().and_then(keys::exposure) {
        let message = CString::new(warning).map_err(|e| PyValueError::new_err(e.to_string()))?;
        PyErr::warn(py, &py.get_type::<PyUserWarning>(), &message, 2)?;
    }
    let (lanes, points, lane_km, bytes, cells) = py
        .detach(|| -> anyhow::Result<_> {
            if let Some(cell_size_m) = grid {
                let grid = GridOptions {
                    cell_size_m,
                    margin_m: margin,
                    sign: key.as_ref(),
                    map_version,
                };
                let done = compile_grid(&inputs, &options, &output, &grid)?;
                let m = &done.manifest;
                let bytes: u64 = m.cells.iter().map(|c| c.bytes).sum();
                return Ok((
                    m.lanes as usize,
                    m.points as usize,
                    done.lane_length_m / 1000.0,
                    bytes as usize,
                    Some(m.cells.len()),
                ));
            }
            let compiled = compile(&inputs, &options)?;
            let bytes = compiled.shipped_tile_bytes(spacing, map_version, key.as_ref())?;
            tile::write_bytes(&output, &bytes)?;
            let map = &compiled.map;
            Ok((
                map.lane_count(),
                map.len(),
                map.lane_length_m() / 1000.0,
                bytes.len(),
                None,
            ))
        })
        .map_err(error)?;
    let d = PyDict::new(py);
    d.set_item("lanes", lanes)?;
    d.set_item("points", points)?;
    d.set_item("lane_km", lane_km)?;
    d.set_item("bytes", bytes)?;
    if let Some(cells) = cells {
        d.set_item("cells", cells)?;
    }
    if let Some(key) = &key {
        d.set_item("signer", tile::key_hex(&key.verifying_key().to_bytes()))?;
    }
    d.set_item("map_version", map_version)?;
    Ok(d)
}

/// True poses and an odometry run of them, (N, 3, 4) each.
type TruthAndOdometry<'py> = (Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>);

/// The synthetic town (`lanealign demo` without data): writes its tile to `tile` and returns
/// the true poses and a drifting odometry run of them, (N, 3, 4) each (flu, metres; the
/// odometry frame is the map plane, anchor (49, 8.4, 0, 0, 0)).
#[pyfunction]
#[pyo3(signature = (tile, *, laps=3, seed=42))]
fn synthetic_town<'py>(
    py: Python<'py>,
    tile: PathBuf,
    laps: usize,
    seed: u64,
) -> PyResult<TruthAndOdometry<'py>> {
    if !(1..=synthetic::MAX_LAPS).contains(&laps) {
        return Err(PyValueError::new_err(format!(
            "laps: {laps}, expected 1 to {}",
            synthetic::MAX_LAPS
        )));
    }
    synthetic::write_town_tile(&tile).map_err(error)?;
    let (truth, odometry) = synthetic::drive(laps, seed);
    let shape = |n: usize| [n, 3, 4];
    Ok((
        poses_into(&truth, &shape(truth.len())).into_pyarray(py),
        poses_into(&odometry, &shape(odometry.len())).into_pyarray(py),
    ))
}

/// A connection to one source of a running `lanealignd`: one session, its poses out over
/// iceoryx2 shared memory and its corrected poses back (see `lanealign_client::Connection`).
/// Any thread may use it, and one thread may wait in `recv` while others publish: a call waits
/// for another's brief work on the connection, never for its wait. Its waits release the GIL.
#[pyclass]
struct Client {
    /// `None` once closed. Locked only around work on the connection, never around a wait,
    /// and never while waiting for the GIL.
    connection: Mutex<Option<Connection>>,
}

/// An answer as a dict: `seq`, `stamp_ns`, `pose` (3, 4), `status` (a name), `map_from_odom`
/// (x, y, yaw), `covariance` (3, 3, map plane), `anchor_yaw` (radians), `odometry_scale` and
/// `odometry_scale_sd` (ratios), and what the status CSV says of the step (`residual_m`,
/// `match_ratio`, `window_len`, `applied_directions`), the session's `expected_seq`, the
/// daemon's run (`daemon_epoch`) and the pose's times (`sent_mono_ns`, `received_mono_ns`,
/// `published_mono_ns`: `CLOCK_MONOTONIC`, the same clock in every process of the machine), and
/// the `warnings` the session raised before the pose (their names: `axes`, `rate`, `pace`,
/// `refusals`, `lost_track`, `jumped`, `poses_missing`; docs/wire.md).
fn answer_dict<'py>(py: Python<'py>, answer: &CorrectedPose) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("seq", answer.seq)?;
    d.set_item("stamp_ns", answer.stamp_ns)?;
    let pose =
        numpy::ndarray::Array2::from_shape_vec((3, 4), answer.pose.to_vec()).map_err(error)?;
    d.set_item("pose", pose.into_pyarray(py))?;
    d.set_item(
        "status",
        StatusCode::from_code(answer.status).map_or("unknown", StatusCode::name),
    )?;
    d.set_item(
        "reason",
        ReasonCode::from_code(answer.reason).map_or("unknown", ReasonCode::name),
    )?;
    d.set_item("map_from_odom", answer.map_from_odom.to_vec())?;
    let warnings: Vec<&str> = answer.warnings().map(Warning::name).collect();
    d.set_item("warnings", warnings)?;
    let covariance = numpy::ndarray::arr2(&from_upper_triangle(&answer.covariance));
    d.set_item("covariance", covariance.into_pyarray(py))?;
    for (key, value) in [
        ("anchor_yaw", answer.anchor_yaw),
        ("odometry_scale", answer.odometry_scale),
        ("odometry_scale_sd", answer.odometry_scale_sd),
        ("residual_m", answer.residual_m),
        ("match_ratio", answer.match_ratio),
    ] {
        d.set_item(key, value)?;
    }
    for (key, value) in [
        ("window_len", u64::from(answer.window_len)),
        ("applied_directions", u64::from(answer.applied_directions)),
        ("expected_seq", answer.expected_seq),
        ("daemon_epoch", answer.daemon_epoch),
        ("sent_mono_ns", answer.sent_mono_ns),
        ("received_mono_ns", answer.received_mono_ns),
        ("published_mono_ns", answer.published_mono_ns),
    ] {
        d.set_item(key, value)?;
    }
    Ok(d)
}

fn seconds(what: &str, s: f64) -> PyResult<Duration> {
    Duration::try_from_secs_f64(s)
        .map_err(|_| PyValueError::new_err(format!("{what} must be a number of seconds")))
}

#[pymethods]
impl Client {
    /// Connects to `source` in the daemon's `namespace` with a new session, waiting for answers
    /// as `wait` says (`event`, `busy-spin[:CORE]`, `spin-then-block:SPIN_US`). With `session`
    /// and `next_seq` (an earlier client's `session` and `next_seq`, kept by a process that was
    /// restarted) it continues that session instead, while the daemon still has it: its
    /// corrector goes on where it was.
    #[new]
    #[pyo3(signature = (source, *, namespace="default", wait="event", session=None, next_seq=1))]
    fn new(
        source: &str,
        namespace: &str,
        wait: &str,
        session: Option<u64>,
        next_seq: u64,
    ) -> PyResult<Self> {
        let namespace: Namespace = parsed("namespace", namespace)?;
        let source: SourceName = parsed("source", source)?;
        let mut connection = match session {
            Some(0) => return Err(PyValueError::new_err("session: 0 is no session")),
            Some(session) => Connection::resume(&namespace, &source, session, next_seq),
            None if next_seq != 1 => {
                return Err(PyValueError::new_err(
                    "next_seq continues a session: give the session too",
                ))
            }
            None => Connection::connect_in(&namespace, &source, new_session_id()),
        }
        .map_err(error)?;
        connection.set_wait_strategy(parsed::<WaitStrategy>("wait", wait)?);
        Ok(Client {
            connection: Mutex::new(Some(connection)),
        })
    }

    /// This client's session id: with `next_seq`, what a restarted process gives `Client` to
    /// continue the session.
    #[getter]
    fn session(&self) -> PyResult<u64> {
        self.with_open(|c| c.session())
    }

    /// The sequence number the next pose gets.
    #[getter]
    fn next_seq(&self) -> PyResult<u64> {
        self.with_open(|c| c.next_seq())
    }

    /// True when a daemon serves the source.
    fn daemon_connected(&self) -> PyResult<bool> {
        self.with_open(|c| c.daemon_connected())
    }

    /// Why no daemon serves the source, for a person: no daemon runs in the namespace, or the
    /// one that runs serves other sources (named), or it has the source and has not taken its
    /// poses yet, or its sources cannot be listed.
    fn why_unserved(&self) -> PyResult<String> {
        self.with_open(|c| c.why_unserved())
    }

    /// True when the daemon has opened this session (it does at the session's first pose). A
    /// living daemon that has not opened it after the first pose could not (its log says why,
    /// for example no room in /dev/shm).
    fn session_opened(&self) -> PyResult<bool> {
        self.with_open(|c| c.session_opened())
    }

    /// Publishes one pose stamped `stamp_ns`: a (3, 4) or (4, 4) matrix or the 12 numbers of a
    /// KITTI row (any array-like of numbers: a numpy array of any number type, a list), in the
    /// source's axis convention; returns its sequence number.
    fn publish(
        &self,
        stamp_ns: i64,
        pose: PyArrayLikeDyn<'_, f64, AllowTypeChange>,
    ) -> PyResult<u64> {
        let array = pose.as_array();
        let row = kitti_rows(&array.view().insert_axis(Axis(0)))
            .and_then(|rows| rows.first().copied())
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "a pose has shape (3, 4), (4, 4) or (12,), not {:?}",
                    array.shape()
                ))
            })?;
        self.with_open(|c| c.publish(stamp_ns, &row))?
            .map_err(error)
    }

    /// The next answer of this session, waiting up to `timeout_s` seconds: `None`, or a dict
    /// with `seq`, `stamp_ns`, `pose` (3, 4), `status` (a name), `map_from_odom` (x, y, yaw),
    /// `covariance` (3, 3, in the map plane), `anchor_yaw` (radians: the rotation of the
    /// odometry frame into the map plane, which turns the covariance into the odometry frame),
    /// `odometry_scale` and `odometry_scale_sd`, the step's `residual_m`, `match_ratio`,
    /// `window_len` and `applied_directions`, `expected_seq`, `daemon_epoch` and the pose's
    /// `sent_mono_ns`, `received_mono_ns` and `published_mono_ns` (see `answer_dict`). While it waits, other Python threads run, and a
    /// signal (Ctrl-C) is acted on within 0.1 s.
    fn recv<'py>(&self, py: Python<'py>, timeout_s: f64) -> PyResult<Option<Bound<'py, PyDict>>> {
        let deadline = deadline_after(seconds("timeout_s", timeout_s)?);
        loop {
            let (answer, waiter) = self.with_open(|c| (c.poll(), c.waiter()))?;
            let answer = answer.map_err(error)?;
            if let Some(answer) = answer {
                return Ok(Some(answer_dict(py, &answer)?));
            }
            let left = time_left(deadline);
            if left.is_zero() {
                return Ok(None);
            }
            py.detach(|| waiter.wait(left.min(SIGNAL_CHECK_PERIOD)))
                .map_err(error)?;
            py.check_signals()?;
        }
    }

    /// Ends the session: waits up to `timeout_s` seconds for the answers still in flight, then
    /// tells the daemon, which forgets the session at once. Returns a dict: `answers` (those
    /// that arrived, as `recv` gives them), `unanswered` (sequence numbers) and `daemon_told`.
    /// The client cannot be used after. When closing fails it raises `CloseError`, which
    /// holds the same three as attributes: no answer that arrived is lost.
    #[pyo3(signature = (timeout_s=1.0))]
    fn close<'py>(&self, py: Python<'py>, timeout_s: f64) -> PyResult<Bound<'py, PyDict>> {
        let timeout = seconds("timeout_s", timeout_s)?;
        let connection = self.locked()?.take().ok_or_else(closed_error)?;
        close_connection(py, connection, timeout)
    }

    /// `with Client(...) as client:` gives the client to the block.
    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// Leaving the `with` block ends the session as `close()` does (waiting up to 1 s for the
    /// answers in flight, which are then dropped: to keep them, call `close` in the block), unless
    /// it is closed already. A failed close raises `CloseError`, chained to the block's exception
    /// when there is one; the block's exception is never swallowed.
    fn __exit__<'py>(
        &self,
        py: Python<'py>,
        _exc_type: Bound<'py, PyAny>,
        _exc_value: Bound<'py, PyAny>,
        _traceback: Bound<'py, PyAny>,
    ) -> PyResult<bool> {
        let open = self.locked()?.take();
        if let Some(connection) = open {
            close_connection(py, connection, EXIT_CLOSE_TIMEOUT)?;
        }
        Ok(false)
    }
}

/// Closes `connection` (see `Client.close`), waiting up to `timeout` without the GIL.
fn close_connection<'py>(
    py: Python<'py>,
    connection: Connection,
    timeout: Duration,
) -> PyResult<Bound<'py, PyDict>> {
    match py.detach(move || connection.close(timeout)) {
        Ok(closed) => closed_dict(py, &closed),
        Err(e) => {
            let items = closed_dict(py, e.closed())?;
            let raised = CloseError::new_err(message(e));
            for (name, value) in items.iter() {
                raised.value(py).setattr(name.cast::<PyString>()?, value)?;
            }
            Err(raised)
        }
    }
}

/// How long leaving a client's `with` block waits for the answers in flight: as long as
/// `Client.close` does by default.
const EXIT_CLOSE_TIMEOUT: Duration = Duration::from_secs(1);

create_exception!(
    lanealign,
    CloseError,
    PyValueError,
    "Closing a client failed: `answers`, `unanswered` and `daemon_told` hold what it had, as \
     `Client.close` returns them."
);

/// What a connection had when it closed, as `Client.close` returns it.
fn closed_dict<'py>(py: Python<'py>, closed: &Closed) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let answers = closed
        .answers
        .iter()
        .map(|a| answer_dict(py, a))
        .collect::<PyResult<Vec<_>>>()?;
    d.set_item("answers", answers)?;
    d.set_item("unanswered", closed.unanswered.clone())?;
    d.set_item("daemon_told", closed.daemon_told)?;
    Ok(d)
}

/// How long a wait of `Client.recv` runs without the GIL before it looks for signals.
const SIGNAL_CHECK_PERIOD: Duration = Duration::from_millis(100);

fn closed_error() -> PyErr {
    PyValueError::new_err("the client is closed")
}

impl Client {
    /// The connection slot, locked. Taken while holding the GIL: no one holding the lock waits
    /// for the GIL, so this wait is short.
    fn locked(&self) -> PyResult<MutexGuard<'_, Option<Connection>>> {
        self.connection.lock().map_err(|_| {
            PyRuntimeError::new_err("the client is unusable: an earlier call on it panicked")
        })
    }

    /// `f` on the open connection, locked for its duration.
    fn with_open<T>(&self, f: impl FnOnce(&mut Connection) -> T) -> PyResult<T> {
        let mut slot = self.locked()?;
        Ok(f(slot.as_mut().ok_or_else(closed_error)?))
    }
}

/// A trajectory read from a file.
type ReadTrajectory<'py> = (Bound<'py, PyArray3<f64>>, Option<Bound<'py, PyArray1<f64>>>);

/// Reads a trajectory file as `lanealign correct` reads it (`format`: kitti or tum; the same
/// checks and messages): `(poses, stamps)`, the poses (N, 3, 4) in the file's axis convention
/// and for TUM the stamps (N,) in seconds (`None` for KITTI).
#[pyfunction]
#[pyo3(signature = (path, *, format="kitti"))]
fn read_trajectory<'py>(
    py: Python<'py>,
    path: PathBuf,
    format: &str,
) -> PyResult<ReadTrajectory<'py>> {
    let format: trajectory::Format = parsed("format", format)?;
    let read = py
        .detach(|| trajectory::read(&path, format))
        .map_err(error)?;
    let like = [read.poses.len(), 3, 4];
    let poses = poses_into(&read.poses, &like)
        .into_dimensionality()
        .map_err(error)?
        .into_pyarray(py);
    let stamps = read.stamps.map(|s| Array1::from(s).into_pyarray(py));
    Ok((poses, stamps))
}

/// The text of a trajectory file as `lanealign correct` writes it (`format`: kitti or tum, which
/// needs `stamps`, checked as a TUM file's are): every number with the shortest text that reads
/// back exactly. `poses` as `correct` takes them ((N, 3, 4), (N, 4, 4) or (N, 12)).
#[pyfunction]
#[pyo3(signature = (poses, *, format="kitti", stamps=None))]
fn format_trajectory(
    poses: PyArrayLikeDyn<'_, f64, AllowTypeChange>,
    format: &str,
    stamps: Option<PyReadonlyArray1<'_, f64>>,
) -> PyResult<String> {
    let format: trajectory::Format = parsed("format", format)?;
    let array = poses.as_array();
    let poses = kitti_poses(&array).ok_or_else(|| {
        PyValueError::new_err(format!(
            "poses must have shape (N, 3, 4), (N, 4, 4) or (N, 12), not {:?}",
            array.shape()
        ))
    })?;
    let stamps = checked_stamps("stamps", stamps.as_ref(), poses.len())?;
    let trajectory = Trajectory { stamps, poses };
    trajectory::format_text(&trajectory, format, std::path::Path::new("the trajectory"))
        .map_err(error)
}

#[pymodule]
fn _lanealign(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(correct, m)?)?;
    m.add_function(wrap_pyfunction!(read_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(format_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(eval, m)?)?;
    m.add_function(wrap_pyfunction!(compile_map, m)?)?;
    m.add_function(wrap_pyfunction!(synthetic_town, m)?)?;
    m.add_class::<Client>()?;
    m.add("CloseError", m.py().get_type::<CloseError>())?;
    m.add("STATUS_NAMES", STATUS_NAMES.to_vec())?;
    m.add("WIRE_VERSION", WIRE_VERSION)?;
    Ok(())
}
