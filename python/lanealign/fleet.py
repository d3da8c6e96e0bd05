"""Fleet-scale batches on Dask: correct many drives and compile maps region by region as tasks.

Dask (``dask.distributed``) was chosen over Ray: it is pure Python and installs with pip anywhere
the package does, its scheduler and workers run the same code on a laptop (``LocalCluster``) and
on many nodes (``dask scheduler`` / ``dask worker``, dask-jobqueue on HPC schedulers,
dask-kubernetes), and each task here is a plain function call on files, which is what Dask's task
model is made for; Ray's actors and object store buy nothing for it. See docs/fleet.md.

Each task reads its inputs from and writes its outputs to paths every worker can reach (a shared
or network file system, or object storage mounted on the workers) and returns a small summary,
so no trajectory or map travels through the scheduler.
"""

import math
import os
from dataclasses import dataclass, field
from typing import Callable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import STATUS_NAMES, compile_map, correct, format_trajectory, read_trajectory
from . import eval as evaluate


@dataclass(frozen=True)
class Drive:
    """One drive to correct: a pose file and where it lies on which map."""

    #: The odometry's poses, in ``format``.
    poses: str
    #: Where the corrected poses go, in ``format`` (as ``lanealign correct`` writes them).
    output: str
    #: Parameter preset of the drive's odometry: liodom, basalt, kiss-icp or orb-slam3.
    preset: str
    #: Exactly one map: raw OSM, a tile, or a lane CSV in the odometry frame.
    osm: Optional[str] = None
    tile: Optional[str] = None
    lanes: Optional[str] = None
    #: (lat, lon, yaw_deg, east_m, north_m); needed with ``osm`` and ``tile``.
    anchor: Optional[Tuple[float, float, float, float, float]] = None
    projection: Optional[str] = None
    method: str = "robust"
    frame: str = "flu"
    #: The odometry's rate (Hz) when the log has no stamps and is not at the presets' 10 Hz
    #: (``--set odometry_rate_hz=...``); a TUM log's stamps say it.
    odometry_rate_hz: Optional[float] = None
    #: Parameter overrides, as :func:`lanealign.correct` takes them (``--set KEY=VALUE``).
    overrides: Optional[Mapping[str, Union[float, int, bool]]] = None
    #: Smooth the corrections (``--smooth``).
    smooth: bool = False
    #: Where the status CSV goes (``--status``): what happened at each pose, its covariance and
    #: ``map_from_odom``; written whole or not at all.
    status: Optional[str] = None
    #: Ground truth of the drive, in ``format`` (KITTI paired by index, TUM by time, as
    #: ``lanealign eval`` pairs them): the summary then holds ``raw`` and ``corrected``, what
    #: :func:`lanealign.eval` reports for each (for ``corrected`` with the covariances'
    #: calibration), or ``{"error": message}`` where that cannot be computed (a ground truth of
    #: another length, a pose that is no pose). A file that cannot be read fails the task, after
    #: the corrected poses are written.
    gt: Optional[str] = None
    #: With TUM files: the largest difference (seconds) of the stamps of a ground-truth and a
    #: drive's pose that pair (``--max-dt``), and seconds added to the drive's stamps before they
    #: pair (``--t-offset``, for a ground truth on another clock).
    gt_max_dt: float = 0.01
    gt_offset: float = 0.0
    #: The format of ``poses``, ``gt`` and ``output``: ``"kitti"`` (12 numbers a line) or
    #: ``"tum"`` (stamped: the corrector reads the odometry's rate from the stamps), read and
    #: written as ``lanealign correct --format`` reads and writes them.
    format: str = "kitti"


@dataclass(frozen=True)
class Region:
    """One region's map to compile into a tile."""

    #: Road data of the region (raw OSM ``.osm`` / ``.osm.pbf`` or Lanelet2).
    inputs: Sequence[str]
    #: The tile to write.
    output: str
    #: (lat, lon) of the region's map plane; the data's centre when ``None``.
    origin: Optional[Tuple[float, float]] = None
    projection: str = "tangent"
    options: dict = field(default_factory=dict)


def correct_drive(drive: Drive) -> dict:
    """Corrects one drive (a task): writes ``drive.output``, returns a summary. A drive whose
    pairing with its ground truth is no pairing (``gt_offset`` not finite, ``gt_max_dt`` not a
    number of seconds above 0 and at most an hour) fails before anything is written, naming it."""
    if not math.isfinite(drive.gt_offset):
        raise ValueError(f"gt_offset: {drive.gt_offset} must be a finite number of seconds")
    if not 0.0 < drive.gt_max_dt <= 3600.0:
        raise ValueError(
            f"gt_max_dt: {drive.gt_max_dt} must be a number of seconds above 0 and at most 3600")
    poses, stamps = read_trajectory(drive.poses, format=drive.format)
    result = correct(
        poses,
        preset=drive.preset,
        osm=drive.osm,
        tile=drive.tile,
        lanes=drive.lanes,
        anchor=drive.anchor,
        projection=drive.projection,
        method=drive.method,
        frame=drive.frame,
        stamps=stamps,
        odometry_rate_hz=drive.odometry_rate_hz,
        overrides=drive.overrides,
        smooth=drive.smooth,
        status=drive.status,
    )
    _write(drive.output, format_trajectory(result.poses, format=drive.format, stamps=stamps))
    counts = np.bincount(result.status, minlength=len(STATUS_NAMES))
    summary = {
        "output": drive.output,
        "poses": len(poses),
        **{name: int(n) for name, n in zip(STATUS_NAMES, counts)},
    }
    if drive.gt is not None:
        gt, gt_stamps = read_trajectory(drive.gt, format=drive.format)
        paired = {} if stamps is None else {
            "gt_stamps": gt_stamps, "est_stamps": stamps + drive.gt_offset,
            "max_dt": drive.gt_max_dt,
        }
        summary["raw"] = _evaluated(gt, poses, frame=drive.frame, **paired)
        summary["corrected"] = _evaluated(gt, result.poses, frame=drive.frame,
                                          covariance=result.covariance,
                                          anchor_yaw=result.anchor_yaw, **paired)
    return summary


def _write(path: str, text: str) -> None:
    """Writes ``text`` to ``path``, whole or not at all: into ``path.partial``, renamed into place
    once written, so that a worker killed while writing leaves no short trajectory under the
    output's name (and the task, run again, writes the same partial file over)."""
    partial = f"{path}.partial"
    try:
        with open(partial, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(partial, path)
    finally:
        if os.path.exists(partial):
            os.remove(partial)


def _evaluated(gt: np.ndarray, est: np.ndarray, **options) -> dict:
    """:func:`lanealign.eval`'s figures, or ``{"error": message}``: a drive whose figures cannot
    be computed (a pose that is no pose, a ground truth of another length) is still corrected."""
    try:
        return evaluate(gt, est, **options)
    except ValueError as e:
        return {"error": str(e)}


def compile_region(region: Region) -> dict:
    """Compiles one region's tile (a task): writes ``region.output``, returns what it holds."""
    info = compile_map(
        list(region.inputs),
        region.output,
        origin=region.origin,
        projection=region.projection,
        **region.options,
    )
    return {"output": region.output, **info}


def correct_drives(client, drives: Sequence[Drive]) -> List[dict]:
    """Corrects ``drives`` in parallel on a ``dask.distributed.Client``; summaries in order. A
    drive that fails (a file that cannot be read, a map that does not load, workers that died on
    it) gets ``{"output": ..., "error": "<exception type>: <message>"}`` in its place, and the
    other drives' summaries come back all the same."""
    return _summaries(client, correct_drive, drives)


def compile_regions(client, regions: Sequence[Region]) -> List[dict]:
    """Compiles ``regions`` in parallel on a ``dask.distributed.Client``; summaries in order. A
    region that fails gets ``{"output": ..., "error": ...}`` in its place, as in
    :func:`correct_drives`."""
    return _summaries(client, compile_region, regions)


def _summaries(client, task: Callable[..., dict],
               items: Sequence[Union[Drive, Region]]) -> List[dict]:
    """``task`` of every item on the cluster, gathered at once: a summary per item, in order, or
    what failed it. The futures are gathered by index, so that one that failed leaves no gap
    that would shift the others' summaries."""
    items = list(items)
    futures = client.map(task, items, pure=False)
    gathered = client.gather(dict(enumerate(futures)), errors="skip")
    return [gathered[i] if gathered.get(i) is not None else
            {"output": item.output, "error": _described(futures[i].exception())}
            for i, item in enumerate(items)]


def _described(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"
