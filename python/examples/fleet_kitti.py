"""Corrects and evaluates every KITTI drive of ../shared/data and compiles every sequence's map,
as Dask tasks.

    python3 python/examples/fleet_kitti.py [SCHEDULER_ADDRESS] [--out DIR]

Without an address it starts a local cluster of two worker processes; with one (for example
``tcp://scheduler:8786``, from ``dask scheduler`` and ``dask worker`` on other nodes) the same code
runs there. The data and ``--out`` must be paths every worker can reach. See docs/fleet.md.
"""

import argparse
from pathlib import Path

import distributed

from lanealign import fleet

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SEQUENCES = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"]
PRESETS = {"lidar": "kiss-icp", "stereo_vo": "orb-slam3"}


def anchor_of(seq):
    row = next(l for l in (DATA / "kitti" / "georef.csv").read_text().splitlines()
               if l.startswith(f"{seq},"))
    f = row.split(",")
    return (float(f[1]), float(f[2]), float(f[4]), float(f[5]), float(f[6]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scheduler", nargs="?", help="a Dask scheduler's address")
    parser.add_argument("--out", default="results/fleet", help="where outputs go")
    args = parser.parse_args()
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    drives = [
        fleet.Drive(poses=str(DATA / "odometry" / odometry / f"{seq}.txt"),
                    output=str(out / f"{odometry}_{seq}.txt"), preset=preset,
                    osm=str(DATA / "osm" / f"kitti_{seq}.osm"), anchor=anchor_of(seq),
                    projection="kitti", frame="kitti-camera",
                    gt=str(DATA / "kitti" / "poses" / f"{seq}.txt"))
        for odometry, preset in PRESETS.items() for seq in SEQUENCES
    ]
    regions = [fleet.Region(inputs=[str(DATA / "osm" / f"kitti_{seq}.osm")],
                            output=str(out / f"kitti_{seq}.tile"), origin=anchor_of(seq)[:2],
                            projection="kitti")
               for seq in SEQUENCES]
    cluster = None if args.scheduler else distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, dashboard_address=None)
    failed = 0
    with distributed.Client(args.scheduler or cluster) as client:
        for summary in fleet.correct_drives(client, drives):
            if "error" in summary:
                failed += 1
                print(f"{summary['output']}: failed: {summary['error']}")
                continue
            raw, corrected = summary["raw"], summary["corrected"]
            print(f"{summary['output']}: {summary['poses']} poses, {summary['accepted']} accepted, "
                  f"APE-2D {raw['ape2d_mean_m']:.3f} -> {corrected['ape2d_mean_m']:.3f} m, "
                  f"cov95 coverage {corrected['cov95_coverage']:.3f} "
                  f"({corrected['calibration_verdict']})")
        for summary in fleet.compile_regions(client, regions):
            if "error" in summary:
                failed += 1
                print(f"{summary['output']}: failed: {summary['error']}")
                continue
            print(f"{summary['output']}: {summary['lanes']} lanes, {summary['lane_km']:.1f} lane-km")
    if cluster is not None:
        cluster.close()
    if failed:
        raise SystemExit(f"{failed} of {len(drives) + len(regions)} tasks failed")


if __name__ == "__main__":
    main()
