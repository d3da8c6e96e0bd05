"""Fleet batches on a local Dask cluster of two worker processes equal a serial run."""

import re

import numpy as np
import pytest

import lanealign
from lanealign import fleet
from test_lanealign import DATA, needs_data


def anchor_of(seq):
    row = next(l for l in (DATA / "kitti" / "georef.csv").read_text().splitlines()
               if l.startswith(f"{seq},"))
    f = row.split(",")
    return (float(f[1]), float(f[2]), float(f[4]), float(f[5]), float(f[6]))


def test_two_workers_equal_a_serial_run(tmp_path):
    needs_data()
    distributed = pytest.importorskip("distributed")
    drives = []
    for seq, odometry, preset in [("04", "lidar", "kiss-icp"), ("07", "lidar", "kiss-icp"),
                                  ("07", "stereo_vo", "orb-slam3"), ("10", "lidar", "liodom")]:
        for where in ("serial", "cluster"):
            (tmp_path / where).mkdir(exist_ok=True)
            drives.append(fleet.Drive(
                poses=str(DATA / "odometry" / odometry / f"{seq}.txt"),
                output=str(tmp_path / where / f"{odometry}_{seq}.txt"),
                preset=preset, osm=str(DATA / "osm" / f"kitti_{seq}.osm"),
                anchor=anchor_of(seq), projection="kitti", frame="kitti-camera",
                gt=str(DATA / "kitti" / "poses" / f"{seq}.txt")))
    serial = [d for d in drives if "/serial/" in d.output]
    on_cluster = [d for d in drives if "/cluster/" in d.output]
    regions = [fleet.Region(inputs=[str(DATA / "osm" / f"kitti_{seq}.osm")],
                            output=str(tmp_path / where / f"{seq}.tile"),
                            origin=anchor_of(seq)[:2], projection="kitti")
               for seq in ("00", "05") for where in ("serial", "cluster")]
    expected = [fleet.correct_drive(d) for d in serial]
    expected_tiles = [fleet.compile_region(r) for r in regions if "/serial/" in r.output]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        got = fleet.correct_drives(client, on_cluster)
        got_tiles = fleet.compile_regions(client, [r for r in regions if "/cluster/" in r.output])
    for s, c, d_s, d_c in zip(expected, got, serial, on_cluster):
        assert {k: v for k, v in s.items() if k != "output"} == \
            {k: v for k, v in c.items() if k != "output"}
        assert np.array_equal(np.loadtxt(d_s.output), np.loadtxt(d_c.output))
    # With ground truth, the summary holds what lanealign.eval reports for the drive.
    lidar_10 = next(i for i, d in enumerate(serial) if d.preset == "liodom")
    gt = np.loadtxt(serial[lidar_10].gt).reshape(-1, 3, 4)
    poses = np.loadtxt(serial[lidar_10].poses).reshape(-1, 3, 4)
    assert got[lidar_10]["raw"] == lanealign.eval(gt, poses, frame="kitti-camera")
    result = lanealign.correct(poses, preset="liodom", osm=serial[lidar_10].osm,
                               anchor=serial[lidar_10].anchor, projection="kitti",
                               frame="kitti-camera")
    assert got[lidar_10]["corrected"] == lanealign.eval(
        gt, result.poses, frame="kitti-camera", covariance=result.covariance,
        anchor_yaw=result.anchor_yaw)
    # 10's LiDAR odometry (1.88 m) is corrected to 0.80 m.
    assert got[lidar_10]["corrected"]["ape2d_mean_m"] < 0.5 * got[lidar_10]["raw"]["ape2d_mean_m"]
    assert 0 < got[lidar_10]["corrected"]["cov95_coverage"] <= 1
    for s, c in zip(expected_tiles, got_tiles):
        assert open(s["output"], "rb").read() == open(c["output"], "rb").read()
        assert s["lanes"] == c["lanes"] > 0


def test_the_fleet_example_runs(tmp_path):
    needs_data()
    pytest.importorskip("distributed")
    import subprocess
    import sys
    from test_lanealign import ROOT

    out = subprocess.run([sys.executable, str(ROOT / "python" / "examples" / "fleet_kitti.py"),
                          "--out", str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert len(list(tmp_path.glob("*.txt"))) == 20 and len(list(tmp_path.glob("*.tile"))) == 10
    # Every drive is evaluated against its ground truth: 00's LiDAR run 4.009 -> 1.026 m.
    assert len(re.findall(r"APE-2D [\d.]+ -> [\d.]+ m, cov95 coverage [\d.]+ \((consistent|too "
                          r"cautious|too confident)\)", out.stdout)) == 20, out.stdout
    # With a verdict against an exact covariance: stereo_vo 01's is too confident (its visual
    # odometry loses track on the highway, docs/method.md, "The verdict").
    assert re.search(r"stereo_vo_01\.txt: .*\(too confident\)", out.stdout), out.stdout
    assert re.search(r"lidar_00\.txt: 4541 poses, \d+ accepted, APE-2D 4\.009 -> 1\.026 m",
                     out.stdout), out.stdout


def test_a_drive_whose_figures_cannot_be_computed_is_still_corrected(tmp_path):
    needs_data()
    drive = fleet.Drive(poses=str(DATA / "odometry" / "lidar" / "04.txt"),
                        output=str(tmp_path / "04.txt"), preset="kiss-icp",
                        osm=str(DATA / "osm" / "kitti_04.osm"), anchor=anchor_of("04"),
                        projection="kitti", frame="kitti-camera",
                        gt=str(DATA / "kitti" / "poses" / "07.txt"))
    summary = fleet.correct_drive(drive)
    assert summary["poses"] == len(np.loadtxt(tmp_path / "04.txt")) == 271
    for key in ("raw", "corrected"):
        assert set(summary[key]) == {"error"} and "1101" in summary[key]["error"], summary[key]
