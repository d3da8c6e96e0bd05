"""Fleet batches on a local Dask cluster of two worker processes equal a serial run."""

import json
import math
import os
import re
import signal
import subprocess
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

import lanealign
from lanealign import fleet
from test_lanealign import BIN, DATA, needs_data


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
        # A drive or a region that fails takes its own place in the summaries and no one else's
        # (one failure raised from the whole batch, and the others' summaries were lost).
        broken = [replace(on_cluster[0], poses=str(tmp_path / "missing.txt"),
                          output=str(tmp_path / "missing_out.txt")),
                  replace(on_cluster[1], osm=on_cluster[1].poses,
                          output=str(tmp_path / "no_map_out.txt"))]
        got = fleet.correct_drives(client, broken[:1] + on_cluster + broken[1:])
        assert got[0] == {"output": broken[0].output,
                          "error": f"ValueError: {broken[0].poses}: No such file or directory "
                                   "(os error 2)"}, got[0]
        assert got[-1]["output"] == broken[1].output and \
            got[-1]["error"].startswith("ValueError: ") and "unknown input type" in got[-1]["error"]
        assert not (tmp_path / "missing_out.txt").exists()
        assert not (tmp_path / "no_map_out.txt").exists()
        got = got[1:-1]
        missing_region = fleet.Region(inputs=[str(tmp_path / "missing.osm")],
                                      output=str(tmp_path / "missing.tile"))
        got_tiles = fleet.compile_regions(
            client, [r for r in regions if "/cluster/" in r.output] + [missing_region])
        assert got_tiles[-1]["output"] == missing_region.output and \
            "No such file" in got_tiles[-1]["error"], got_tiles[-1]
        got_tiles = got_tiles[:-1]
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


def test_a_worker_killed_mid_batch_loses_no_drive(tmp_path):
    """kill -9 of a worker while the batch runs: its tasks, and the summaries it held, are
    computed again elsewhere (Dask's nanny restarts it), and every drive comes back as a serial
    run gives it."""
    needs_data()
    distributed = pytest.importorskip("distributed")

    def drive(i):
        return fleet.Drive(poses=str(DATA / "odometry" / "lidar" / "07.txt"),
                           output=str(tmp_path / f"07_{i}.txt"), preset="kiss-icp",
                           osm=str(DATA / "osm" / "kitti_07.osm"), anchor=anchor_of("07"),
                           projection="kitti", frame="kitti-camera")

    expected = fleet.correct_drive(drive("serial"))
    drives = [drive(i) for i in range(30)]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        victim = next(iter(client.run(os.getpid).values()))
        killed = []

        def kill_once_the_batch_runs():
            deadline = time.monotonic() + 60
            while not any(tmp_path.glob("07_[0-9]*.txt")) and time.monotonic() < deadline:
                time.sleep(0.005)
            os.kill(victim, signal.SIGKILL)
            killed.append(sum(1 for _ in tmp_path.glob("07_[0-9]*.txt")))

        killer = threading.Thread(target=kill_once_the_batch_runs)
        killer.start()
        got = fleet.correct_drives(client, drives)
        killer.join()
    assert killed and killed[0] < len(drives), f"the kill came after the batch: {killed}"
    assert [s["output"] for s in got] == [d.output for d in drives]
    for summary, d in zip(got, drives):
        assert {k: v for k, v in summary.items() if k != "output"} == \
            {k: v for k, v in expected.items() if k != "output"}, summary
        assert open(d.output).read() == open(expected["output"]).read()
    assert not list(tmp_path.glob("*.partial")), "a partial output was left behind"


def test_a_drive_that_kills_its_workers_is_told_and_the_others_come_back(tmp_path):
    distributed = pytest.importorskip("distributed")
    import dask

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                     dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = fleet._summaries(client, _exit_on_poison,
                               [fleet.Region(inputs=[], output=name)
                                for name in ("a", "poison", "b")])
    assert got[0] == {"output": "a"} and got[2] == {"output": "b"}, got
    assert got[1]["output"] == "poison" and got[1]["error"].startswith("KilledWorker: "), got


def _exit_on_poison(region):
    if region.output == "poison":
        os._exit(9)
    return {"output": region.output}


def test_a_log_saved_with_a_byte_order_mark_is_read_as_the_command_line_reads_it(tmp_path):
    """KITTI files that a Windows tool saved as UTF-8 with a byte-order mark (numpy refused their
    first number, `'\\ufeff1.0'`): the drive's log and its ground truth."""
    needs_data()

    def marked(path):
        copy = tmp_path / f"marked_{path.parent.name}_{path.name}"
        copy.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
        return str(copy)

    log, gt = DATA / "odometry" / "lidar" / "04.txt", DATA / "kitti" / "poses" / "04.txt"
    drive = fleet.Drive(poses=str(log), output=str(tmp_path / "plain_out.txt"), preset="kiss-icp",
                        osm=str(DATA / "osm" / "kitti_04.osm"), anchor=anchor_of("04"),
                        projection="kitti", frame="kitti-camera", gt=str(gt))
    plain = fleet.correct_drive(drive)
    from_marked = fleet.correct_drive(replace(drive, poses=marked(log), gt=marked(gt),
                                              output=str(tmp_path / "marked_out.txt")))
    assert {k: v for k, v in plain.items() if k != "output"} == \
        {k: v for k, v in from_marked.items() if k != "output"}
    assert plain["poses"] == 271 and plain["corrected"]["poses"] == 271
    # Written as the command line writes it (numpy's `%.17g` wrote other digits).
    cli_out = tmp_path / "cli_out.txt"
    subprocess.run([str(BIN), "correct", "--osm", drive.osm, "--anchor",
                    ",".join(repr(v) for v in anchor_of("04")), "--projection", "kitti",
                    "--preset", "kiss-icp", "--frame", "kitti-camera", str(log), "-o", str(cli_out)],
                   check=True, capture_output=True)
    assert (tmp_path / "plain_out.txt").read_bytes() == cli_out.read_bytes()


def test_tum_drives_are_read_corrected_and_written_as_the_command_line_does(tmp_path):
    """A drive logged in TUM (stamped, as a ROS bag gives it): its output equals `lanealign
    correct --format tum` byte for byte, and its figures are what `lanealign eval --format tum`
    reports (paired by time); the KITTI drives only could be corrected before."""
    needs_data()
    poses = lanealign.read_trajectory(DATA / "odometry" / "lidar" / "07.txt")[0]
    gt = lanealign.read_trajectory(DATA / "kitti" / "poses" / "07.txt")[0]
    # 10 Hz with a camera's jitter; the truth at its own stamps, 2 ms later.
    stamps = 1.7e9 + 0.1 * np.arange(len(poses)) + np.random.default_rng(7).uniform(0, 2e-3, len(poses))
    log, truth = tmp_path / "log.tum", tmp_path / "truth.tum"
    log.write_text(lanealign.format_trajectory(poses, format="tum", stamps=stamps))
    truth.write_text(lanealign.format_trajectory(gt, format="tum", stamps=stamps + 2e-3))
    drive = fleet.Drive(poses=str(log), output=str(tmp_path / "fleet.tum"), preset="kiss-icp",
                        osm=str(DATA / "osm" / "kitti_07.osm"), anchor=anchor_of("07"),
                        projection="kitti", frame="kitti-camera", gt=str(truth), format="tum",
                        status=str(tmp_path / "fleet.csv"))
    summary = fleet.correct_drive(drive)
    cli_out, cli_status = tmp_path / "cli.tum", tmp_path / "cli.csv"
    anchor = ",".join(repr(v) for v in anchor_of("07"))
    subprocess.run([str(BIN), "correct", "--format", "tum", "--osm", drive.osm, "--anchor", anchor,
                    "--projection", "kitti", "--preset", "kiss-icp", "--frame", "kitti-camera",
                    str(log), "-o", str(cli_out), "--status", str(cli_status)],
                   check=True, capture_output=True)
    assert (tmp_path / "fleet.tum").read_bytes() == cli_out.read_bytes()
    assert (tmp_path / "fleet.csv").read_bytes() == cli_status.read_bytes()

    def cli_eval(est, *status):
        out = subprocess.run([str(BIN), "eval", "--format", "tum", "--frame", "kitti-camera",
                              "--gt", str(truth), "--est", str(est), "--json", *status],
                             check=True, capture_output=True, text=True).stdout
        return json.loads(out)

    for key, expected in [("raw", cli_eval(log)),
                          ("corrected", cli_eval(cli_out, "--status", str(cli_status)))]:
        got = summary[key]
        assert got["poses"] == len(poses) and set(got) == set(expected), (key, got)
        for name, value in expected.items():
            if isinstance(value, list):
                assert np.allclose(got[name], value, rtol=1e-9, atol=0), (key, name)
            elif isinstance(value, str):
                assert got[name] == value, (key, name)
            else:
                assert math.isclose(got[name], value, rel_tol=1e-9, abs_tol=1e-12), (key, name)

    # A truth logged on a clock 5.05 s ahead pairs nowhere within 10 ms (its stamps fall between
    # the drive's), unless the drive says the offset, or a tolerance of 60 ms takes the nearest.
    ahead = tmp_path / "ahead.tum"
    ahead.write_text(lanealign.format_trajectory(gt, format="tum", stamps=stamps + 5.052))
    unpaired = fleet.correct_drive(replace(drive, gt=str(ahead)))
    assert "no estimate stamp lies within 0.01 s" in unpaired["raw"]["error"], unpaired
    paired = fleet.correct_drive(replace(drive, gt=str(ahead), gt_offset=5.05))
    for key in ("raw", "corrected"):
        assert math.isclose(paired[key]["ape2d_mean_m"], summary[key]["ape2d_mean_m"],
                            rel_tol=1e-9), key
    loose = fleet.correct_drive(replace(drive, gt=str(ahead), gt_max_dt=0.06))
    assert len(poses) - 60 <= loose["raw"]["poses"] < len(poses), loose
    # A pairing that is none fails the task by the drive's own names, and writes nothing (a NaN
    # offset was told as the estimate's stamps being no numbers, after the drive was corrected).
    never = tmp_path / "never.tum"
    for bad in ({"gt_offset": math.nan}, {"gt_offset": -math.inf}, {"gt_max_dt": math.nan},
                {"gt_max_dt": 0.0}):
        with pytest.raises(ValueError, match=f"^{next(iter(bad))}: "):
            fleet.correct_drive(replace(drive, gt=str(ahead), output=str(never), **bad))
        assert not never.exists(), bad


# KITTI's 10 Hz said to be 20 Hz doubles its accelerations, and the corrector says so.
@pytest.mark.filterwarnings("ignore:the odometry's speed changes")
def test_a_drive_takes_what_correct_takes_on_the_command_line(tmp_path):
    """A KITTI log said to be at 20 Hz, with overrides and smoothing: the output equals
    `lanealign correct --set odometry_rate_hz=20 --set ... --smooth` byte for byte (a drive could
    say none of these, so a log at another rate was corrected as if at 10 Hz)."""
    needs_data()
    log = DATA / "odometry" / "lidar" / "07.txt"
    drive = fleet.Drive(poses=str(log), output=str(tmp_path / "fleet.txt"), preset="kiss-icp",
                        osm=str(DATA / "osm" / "kitti_07.osm"), anchor=anchor_of("07"),
                        projection="kitti", frame="kitti-camera", odometry_rate_hz=20.0,
                        overrides={"max_window": 200, "trim_ratio": 0.2}, smooth=True)
    summary = fleet.correct_drive(drive)
    cli_out = tmp_path / "cli.txt"
    subprocess.run([str(BIN), "correct", "--osm", drive.osm, "--anchor",
                    ",".join(repr(v) for v in anchor_of("07")), "--projection", "kitti",
                    "--preset", "kiss-icp", "--frame", "kitti-camera", "--set", "odometry_rate_hz=20",
                    "--set", "max_window=200", "--set", "trim_ratio=0.2", "--smooth", str(log),
                    "-o", str(cli_out)], check=True, capture_output=True)
    assert (tmp_path / "fleet.txt").read_bytes() == cli_out.read_bytes()
    assert summary["accepted"] > 100, summary
    plain = fleet.correct_drive(fleet.Drive(poses=drive.poses, output=str(tmp_path / "plain.txt"),
                                            preset="kiss-icp", osm=drive.osm, anchor=drive.anchor,
                                            projection="kitti", frame="kitti-camera"))
    assert plain != {**summary, "output": plain["output"]}, "the options change the correction"
