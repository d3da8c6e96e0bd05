"""lanealign for Python: correct and evaluate trajectories, numpy arrays in and out.

``correct`` runs exactly what ``lanealign correct`` runs (same defaults, bit-identical
results); ``eval`` reports what ``lanealign eval --json`` reports (given the covariances, what
it reports with ``--status``); ``compile_map`` writes the tile ``lanealign-map compile`` writes;
``Client`` publishes poses to a running ``lanealignd`` and receives the corrected ones over
shared memory. Errors are ``ValueError`` with the command line's messages; a ``Client.close``
that fails raises ``CloseError`` (a ``ValueError``) holding the answers that arrived and the
poses that got none.
"""

import os
from typing import Mapping, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from . import _lanealign
from ._lanealign import Client, CloseError

#: The status names; ``Corrected.status`` holds indices into this tuple.
STATUS_NAMES: Tuple[str, ...] = tuple(_lanealign.STATUS_NAMES)

#: The version of the wire this package's ``Client`` speaks; a ``Client`` does not connect to a
#: daemon of another (``lanealignd --version`` prints the daemon's).
WIRE_VERSION: int = _lanealign.WIRE_VERSION


def _floats(a):
    """``a`` as a contiguous float64 array, as the extension takes arrays; ``None`` stays."""
    return None if a is None else np.ascontiguousarray(a, dtype=np.float64)


class Corrected(NamedTuple):
    """The result of :func:`correct`."""

    #: Corrected poses: the input's shape, axis convention and frame.
    poses: np.ndarray
    #: One status code per pose (uint8), an index into :data:`STATUS_NAMES`.
    status: np.ndarray
    #: (N, 3, 3) covariance of each corrected pose (map plane; x, y in metres, yaw in radians);
    #: NaN for a pose that is no pose (status ``invalid_input``), as are its scale entries.
    covariance: np.ndarray
    #: (N) what the odometry's steps are multiplied by after each pose: the estimate of its scale
    #: (1 where it is not estimated; the orb-slam3 preset and ``scale_sigma`` estimate it).
    odometry_scale: np.ndarray
    #: (N) the standard deviation of ``odometry_scale`` (0 where it is not estimated).
    odometry_scale_sd: np.ndarray
    #: The map plane's rotation from the odometry frame (radians): ``covariance`` turned by
    #: ``-anchor_yaw`` is in the odometry frame. The anchor's yaw, plus the meridian convergence
    #: for a tile whose origin is not the anchor's; 0 for ``lanes``. ``eval`` takes it beside
    #: ``covariance``.
    anchor_yaw: float


def correct(
    poses: np.ndarray,
    *,
    preset: str,
    osm: Optional[str] = None,
    tile: Optional[str] = None,
    lanes: Optional[str] = None,
    anchor: Optional[Sequence[float]] = None,
    projection: Optional[str] = None,
    method: str = "robust",
    frame: str = "flu",
    odometry_rate_hz: Optional[float] = None,
    smooth: bool = False,
    overrides: Optional[Mapping[str, Union[int, float, bool]]] = None,
    stamps: Optional[np.ndarray] = None,
    status: Optional[str] = None,
) -> Corrected:
    """Correct a trajectory against lane centrelines, as ``lanealign correct`` does.

    ``poses``: (N, 3, 4) or (N, 4, 4) poses, (N, 12) rows of a KITTI file (as ``np.loadtxt``
    reads one), or planar (N, 3) ``[x, y, yaw]`` (metres, radians; ``frame="flu"`` only); the
    corrected poses come back in the same shape. Exactly one map: ``osm`` (raw OSM or Lanelet2,
    ``.osm``/``.osm.pbf``), ``tile`` (from ``lanealign-map compile``) or ``lanes`` (a
    ``lane_id,x,y`` CSV in the odometry frame). ``anchor`` = (lat, lon, yaw_deg) or (lat, lon,
    yaw_deg, east_m, north_m) places the odometry frame on Earth (needed with ``osm`` and
    ``tile``); ``projection``: ``"tangent"`` (default for osm) or
    ``"kitti"``. ``preset``: liodom, basalt, kiss-icp or orb-slam3; ``method``: robust or paper;
    ``frame``: ``"flu"`` or ``"kitti-camera"``. ``odometry_rate_hz``: the poses' rate when it is
    not the presets' 10 Hz (above, only every ``round(rate / 10)``-th pose then enters the window,
    the others get the correction in force, status ``"carried"``; below, the window's pose counts
    shrink by ``rate / 10``). ``smooth``: publish smoothed
    poses, as ``--smooth``. ``overrides``: parameters by name, as ``--set KEY=VALUE`` takes them
    (``lanealign params`` lists them), e.g. ``{"max_window": 800, "lane_tolerance_m": 0.5}``;
    an unknown name or a value of the wrong type is a ``ValueError``. ``stamps``: each pose's
    time in seconds (N), as a TUM file gives them: finite and increasing, as ``lanealign
    correct`` checks a TUM file's (else a ``ValueError`` names the first that is not). The
    odometry's speed, which tells its jumps (status ``"odometry_jump"``) from its motion, is
    then judged by them, so that a pause in the poses is not taken for a jump even over a bend,
    and a pose that glitched straight ahead is one; without them the poses come at
    ``odometry_rate_hz``, and a step too long for one period is motion only where it drives on
    as the step before did (poses missing; such a pose's covariance also covers a glitch straight
    ahead, and a warning names it). An odometry whose scale may be off by more than
    about 1 % (wheel odometry) has it estimated with ``overrides={"scale_sigma": 0.05}``; the
    orb-slam3 preset does so by default; ``odometry_scale`` says what came of it. ``status``: a
    path to write the status CSV ``--status`` writes (what happened at each pose, the covariance,
    ``map_from_odom``), whole or not at all.

    What ``lanealign correct`` prints as ``WARN`` lines (a run set up wrongly, an odometry that
    jumped, lost track or had poses missing) comes as a ``UserWarning`` each, with the same text.
    """
    return Corrected(*_lanealign.correct(
        _floats(poses),
        preset=preset,
        osm=osm,
        tile=tile,
        lanes=lanes,
        anchor=anchor,
        projection=projection,
        method=method,
        frame=frame,
        odometry_rate_hz=odometry_rate_hz,
        smooth=smooth,
        overrides=overrides,
        stamps=_floats(stamps),
        status=None if status is None else str(status),
    ))


def eval(  # noqa: A001
    gt: np.ndarray,
    est: np.ndarray,
    *,
    frame: str = "flu",
    covariance: Optional[np.ndarray] = None,
    anchor_yaw: Optional[float] = None,
    gt_stamps: Optional[np.ndarray] = None,
    est_stamps: Optional[np.ndarray] = None,
    max_dt: float = 0.01,
) -> dict:
    """APE-2D of ``est`` against ``gt`` (no alignment), as ``lanealign eval``. Each is
    (N, 3, 4), (N, 4, 4), (N, 12) or planar (N, 3), as ``correct`` takes them. They are paired by
    index (then as long as each other), or, given ``gt_stamps`` and ``est_stamps`` (seconds, one
    per pose, finite and increasing), by time as ``lanealign eval`` pairs two TUM files: each
    estimated pose with the ground truth within ``max_dt`` seconds of it (``--max-dt``, 10 ms
    unless told), each pose in one pair at most; ``poses`` says how many paired, and stamps of
    which none pair are a ``ValueError`` saying where each lies.

    Returns ``ape2d_mean_m``, ``rmse_m``, ``lateral_rmse_m``, ``heading_mean_deg``, ``max_m``
    and ``poses``. With ``covariance`` (N, 3, 3) and ``anchor_yaw`` (``Corrected.covariance``
    and ``Corrected.anchor_yaw``, one per estimated pose; a ``Client``'s answers carry both)
    also how well the
    covariances describe the errors, as ``lanealign eval --status``: ``cov95_coverage`` (the
    fraction of poses whose error lies inside the 95 % ellipse), ``nees_mean``,
    ``independent_samples``, what a covariance describing the errors exactly would show over as
    many independent errors (``cov95_coverage_if_exact`` and ``nees_mean_if_exact``: 2.5th and
    97.5th percentiles) and ``calibration_verdict`` ("consistent", "too confident" or "too
    cautious"). A covariance that is not symmetric, or not positive definite (a pose with status
    ``invalid_input``), is a ``ValueError``.
    """
    return _lanealign.eval(
        _floats(gt),
        _floats(est),
        frame=frame,
        covariance=_floats(covariance),
        anchor_yaw=anchor_yaw,
        gt_stamps=_floats(gt_stamps),
        est_stamps=_floats(est_stamps),
        max_dt=max_dt,
    )


def compile_map(
    inputs,
    output: str,
    *,
    origin: Optional[Tuple[float, float]] = None,
    projection: str = "tangent",
    spacing: float = 3.0,
    traffic: str = "right",
    unmarked_offset_scale: float = 0.5,
    grid: Optional[float] = None,
    margin: float = 50.0,
    classes: Optional[str] = None,
    sign: Optional[str] = None,
    map_version: int = 0,
) -> dict:
    """Compile road data into a lane tile, as ``lanealign-map compile`` does.

    ``inputs``: raw OSM (``.osm``, ``.osm.pbf``) or Lanelet2 files; ``origin`` = (lat, lon) of the
    map plane (the data's centre when ``None``); ``projection``: ``"tangent"`` or ``"kitti"``;
    ``spacing``: minimum lane point spacing (metres); ``traffic``: ``"right"`` or ``"left"``;
    ``unmarked_offset_scale``: 0.5 for the robust method, 1 for the paper's. With ``grid`` (a
    cell size in metres) ``output`` is a folder: a grid of cells holding the lanes within
    ``margin`` metres of their squares, as ``lanealign-map compile --grid`` writes (``correct``
    takes it as ``tile``). ``classes``: comma-separated highway classes to derive lanes from
    (``None``: motorway to living_street and their links). ``sign``: a secret key file from
    ``lanealign-map keygen``; the tile (a grid's cells and manifest) is signed with it.
    ``map_version``: the build's number for this map (0 to 2**63 - 1, as ``--map-version``); a
    daemon with ``min_map_version`` refuses older maps. Returns the map's ``lanes``, ``points``,
    ``lane_km``, ``bytes`` and ``map_version`` (and ``cells`` for a grid, and ``signer``, the
    public key in hex, when signed).
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    return _lanealign.compile_map(
        [str(p) for p in inputs],
        str(output),
        origin=origin,
        projection=projection,
        spacing=spacing,
        traffic=traffic,
        unmarked_offset_scale=unmarked_offset_scale,
        grid=grid,
        margin=margin,
        classes=classes,
        sign=None if sign is None else str(sign),
        map_version=map_version,
    )


def read_trajectory(path, *, format: str = "kitti") -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Read a trajectory file as ``lanealign correct`` reads it (``format``: ``"kitti"`` or
    ``"tum"``; the same checks and messages, a leading byte-order mark allowed): ``(poses,
    stamps)``, the (N, 3, 4) poses in the file's axis convention and, for TUM, the (N,) stamps in
    seconds (``None`` for KITTI).
    """
    return _lanealign.read_trajectory(str(path), format=format)


def format_trajectory(poses, *, format: str = "kitti", stamps=None) -> str:
    """The text of a trajectory file as ``lanealign correct`` writes it: ``poses`` as
    :func:`correct` takes them, ``format`` ``"kitti"`` or ``"tum"`` (which needs ``stamps``,
    seconds, checked as a TUM file's are); every number in the shortest text that reads back
    exactly.
    """
    return _lanealign.format_trajectory(poses, format=format, stamps=_floats(stamps))


def synthetic_town(tile: str, *, laps: int = 3, seed: int = 42) -> Tuple[np.ndarray, np.ndarray]:
    """The synthetic town ``lanealign demo`` runs without data: writes its tile to ``tile`` and
    returns ``(truth, odometry)``, (N, 3, 4) poses each (``frame="flu"``, metres). The odometry
    drifts (heading bias, 1 % scale error, noise from ``seed``); its frame is the map plane, so
    ``anchor=(49.0, 8.4, 0.0, 0.0, 0.0)`` places it.
    """
    return _lanealign.synthetic_town(str(tile), laps=laps, seed=seed)


__all__ = [
    "STATUS_NAMES",
    "WIRE_VERSION",
    "Client",
    "CloseError",
    "Corrected",
    "compile_map",
    "correct",
    "eval",
    "format_trajectory",
    "read_trajectory",
    "synthetic_town",
]
