"""The Python call against the command line, side by side: KITTI 00 LiDAR, kiss-icp, OSM lanes.

    python3 python/benches/overhead.py [--runs 7]

Prints the median wall time of `lanealign correct` as a whole process (start, read, correct,
write) and of `lanealign.correct` as a call (the poses already in a numpy array), and their ratio.
"""

import argparse
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import lanealign

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("LANEALIGN_BIN", ROOT / "target" / "release" / "lanealign"))
DATA = ROOT.parent / "shared" / "data"
ANCHOR = (48.9825452359, 8.3903661, 59.5584, 0.806, 0.365)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=7)
    runs = parser.parse_args().runs
    odometry = DATA / "odometry" / "lidar" / "00.txt"
    osm = DATA / "osm" / "kitti_00.osm"
    poses = np.loadtxt(odometry).reshape(-1, 3, 4)
    cli, call = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(runs):
            start = time.perf_counter()
            subprocess.run([str(BIN), "correct", "--osm", str(osm), "--anchor",
                            ",".join(map(repr, ANCHOR)), "--projection", "kitti", "--preset",
                            "kiss-icp", "--frame", "kitti-camera", str(odometry), "-o",
                            f"{tmp}/out.txt"], check=True, capture_output=True)
            cli.append(time.perf_counter() - start)
            start = time.perf_counter()
            lanealign.correct(poses, osm=str(osm), anchor=ANCHOR, projection="kitti",
                              preset="kiss-icp", frame="kitti-camera")
            call.append(time.perf_counter() - start)
    c, p = statistics.median(cli), statistics.median(call)
    print(f"KITTI 00 lidar, {len(poses)} poses, {runs} runs each, medians")
    print("| run | ms |\n|---|---|")
    print(f"| lanealign correct (whole process) | {c * 1e3:.1f} |")
    print(f"| lanealign.correct (call) | {p * 1e3:.1f} |")
    print(f"call / whole process: {p / c:.2f}")


if __name__ == "__main__":
    main()
