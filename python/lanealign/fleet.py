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

from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import numpy as np

from . import STATUS_NAMES, compile_map, correct


@dataclass(frozen=True)
class Drive:
    """One drive to correct: a KITTI-format pose file and where it lies on which map."""

    #: KITTI-format poses (12 numbers a line).
    poses: str
    #: Where the corrected poses go (KITTI format, full precision).
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
    """Corrects one drive (a task): writes ``drive.output``, returns a summary."""
    poses = np.loadtxt(drive.poses, ndmin=2).reshape(-1, 3, 4)
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
    )
    np.savetxt(drive.output, result.poses.reshape(len(poses), 12), fmt="%.17g")
    counts = np.bincount(result.status, minlength=len(STATUS_NAMES))
    return {
        "output": drive.output,
        "poses": len(poses),
        **{name: int(n) for name, n in zip(STATUS_NAMES, counts)},
    }


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
    """Corrects ``drives`` in parallel on a ``dask.distributed.Client``; summaries in order."""
    return client.gather(client.map(correct_drive, list(drives), pure=False))


def compile_regions(client, regions: Sequence[Region]) -> List[dict]:
    """Compiles ``regions`` in parallel on a ``dask.distributed.Client``; summaries in order."""
    return client.gather(client.map(compile_region, list(regions), pure=False))
