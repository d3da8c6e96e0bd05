from typing import Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

STATUS_NAMES: List[str]
WIRE_VERSION: int

def correct(
    poses: np.ndarray,
    *,
    preset: str,
    osm: Optional[str] = ...,
    tile: Optional[str] = ...,
    lanes: Optional[str] = ...,
    anchor: Optional[Sequence[float]] = ...,
    projection: Optional[str] = ...,
    method: str = ...,
    frame: str = ...,
    odometry_rate_hz: Optional[float] = ...,
    smooth: bool = ...,
    overrides: Optional[Mapping[str, Union[int, float, bool]]] = ...,
    stamps: Optional[np.ndarray] = ...,
    status: Optional[str] = ...,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]: ...
def eval(
    gt: np.ndarray,
    est: np.ndarray,
    *,
    frame: str = ...,
    covariance: Optional[np.ndarray] = ...,
    anchor_yaw: Optional[float] = ...,
    gt_stamps: Optional[np.ndarray] = ...,
    est_stamps: Optional[np.ndarray] = ...,
) -> Dict[str, Union[float, int]]: ...
def compile_map(
    inputs: List[str],
    output: str,
    *,
    origin: Optional[Tuple[float, float]] = ...,
    projection: str = ...,
    spacing: float = ...,
    traffic: str = ...,
    unmarked_offset_scale: float = ...,
    grid: Optional[float] = ...,
    margin: float = ...,
    classes: Optional[str] = ...,
    sign: Optional[str] = ...,
    map_version: int = ...,
) -> Dict[str, Union[float, int, str]]: ...
def synthetic_town(tile: str, *, laps: int = ..., seed: int = ...) -> Tuple[np.ndarray, np.ndarray]: ...
def read_trajectory(path: str, *, format: str = ...) -> Tuple[np.ndarray, Optional[np.ndarray]]: ...
def format_trajectory(poses: npt.ArrayLike, *, format: str = ...,
                      stamps: Optional[np.ndarray] = ...) -> str: ...

class CloseError(ValueError):
    """Closing a client failed: what it had, as ``Client.close`` returns it."""

    answers: List[Dict[str, object]]
    unanswered: List[int]
    daemon_told: bool

class Client:
    """A connection to one source of a running lanealignd: one session. Any thread may use it,
    and one may wait in ``recv`` while others ``publish``; ``recv`` and ``close`` wait without
    the GIL."""

    def __init__(self, source: str, *, namespace: str = ..., wait: str = ...,
                 session: Optional[int] = ..., next_seq: int = ...) -> None:
        """A new session, or with ``session`` and ``next_seq`` (an earlier client's) that session
        continued while the daemon still has it."""
    @property
    def session(self) -> int: ...
    @property
    def next_seq(self) -> int: ...
    def daemon_connected(self) -> bool: ...
    def why_unserved(self) -> str:
        """Why no daemon serves the source: no daemon runs in the namespace, or the one that runs
        serves other sources (named), or it has the source and has not taken its poses yet, or its
        sources cannot be listed."""
    def session_opened(self) -> bool: ...
    def publish(self, stamp_ns: int, pose: npt.ArrayLike) -> int:
        """Publishes a pose ((3, 4), (4, 4) or a KITTI row of 12 numbers; any array-like of
        numbers) stamped ``stamp_ns``; returns its sequence number."""
        ...
    def recv(self, timeout_s: float) -> Optional[Dict[str, object]]:
        """The next answer, or None after ``timeout_s``: ``seq``, ``stamp_ns``, ``pose`` (3x4),
        ``status`` and ``reason`` (the names of the status CSV; ``reason`` is empty but for a
        rejected or reset step, or ``sessions_full`` on a ``pass_through`` answer while the
        session waits for a place among the source's ``max_sessions``), ``map_from_odom``,
        ``covariance`` (3x3), ``anchor_yaw``, ``odometry_scale``, ``odometry_scale_sd``; the
        step's ``residual_m``, ``match_ratio``, ``window_len`` and ``applied_directions`` (the
        status CSV's columns), ``expected_seq``, ``daemon_epoch``, and the pose's
        ``sent_mono_ns``, ``received_mono_ns`` and ``published_mono_ns`` (CLOCK_MONOTONIC, which
        ``time.monotonic_ns()`` reads on Linux: the round trip is it minus ``sent_mono_ns``);
        ``warnings``: the names of what the session's poses raised before this one (``axes``,
        ``rate``, ``pace``, ``refusals``, ``lost_track``, ``jumped``, ``poses_missing``;
        docs/wire.md)."""
        ...
    def close(self, timeout_s: float = ...) -> Dict[str, object]: ...
    def __enter__(self) -> "Client": ...
    def __exit__(self, exc_type: object, exc_value: object, traceback: object) -> bool:
        """Ends the session as ``close()`` does, unless closed in the block (which keeps the
        answers in flight; leaving drops them). The block's exception is never swallowed."""
        ...
