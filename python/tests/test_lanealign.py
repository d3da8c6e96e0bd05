"""lanealign for Python equals the command line bit for bit.

Needs the `lanealign` binary (LANEALIGN_BIN, else the workspace's target/release/lanealign);
`cargo test --release --workspace` builds it and runs these tests (tests/tests/python.rs).
"""

import contextlib
import csv
import json
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import lanealign

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("LANEALIGN_BIN", ROOT / "target" / "release" / "lanealign"))
MAP_BIN = BIN.with_name("lanealign-map")
DATA = Path(os.environ.get("LANEALIGN_DATA", ROOT.parent / "shared" / "data"))


def needs_data():
    if not (DATA / "kitti" / "georef.csv").is_file():
        if os.environ.get("LANEALIGN_REQUIRE_DATA") == "1":
            pytest.fail(f"no KITTI data at {DATA} (LANEALIGN_REQUIRE_DATA=1)")
        pytest.skip(f"SKIPPED: no KITTI data at {DATA}")


def cli(*args):
    return cli_run(*args).stdout


def cli_run(*args):
    out = subprocess.run([str(BIN), *map(str, args)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out


def test_the_client_speaks_the_daemons_wire():
    """The package's wire version is the one ``lanealignd --version`` prints."""
    out = subprocess.run([str(BIN.with_name("lanealignd")), "--version"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith(f"(wire {lanealign.WIRE_VERSION})"), out.stdout
    assert isinstance(lanealign.WIRE_VERSION, int) and lanealign.WIRE_VERSION >= 2


def write_kitti(path, poses):
    np.savetxt(path, poses.reshape(len(poses), 12), fmt="%.17g")


def write_tum(path, stamps, poses):
    """`poses` ((N, 3, 4), rotations the identity) stamped `stamps` as a TUM file, every number
    as Python writes it back exactly."""
    path.write_text("".join(f"{float(t)!r} {float(x)!r} {float(y)!r} {float(z)!r} 0 0 0 1\n"
                            for t, (x, y, z) in zip(stamps, poses[:, :, 3])))
    return path


def read_kitti(path):
    return np.loadtxt(path).reshape(-1, 3, 4)


def straight_lane_and_drift(tmp_path):
    lanes = tmp_path / "lanes.csv"
    lanes.write_text("lane_id,x,y\n" + "".join(f"1,{i * 3.0},0\n" for i in range(100)))
    poses = np.zeros((200, 3, 4))
    poses[:, :, :3] = np.eye(3)
    poses[:, 0, 3] = np.arange(200) * 1.2
    poses[:, 1, 3] = 0.8
    return lanes, poses


def test_correct_equals_the_command_line_without_data(tmp_path):
    lanes, poses = straight_lane_and_drift(tmp_path)
    write_kitti(tmp_path / "in.txt", poses)
    cli("correct", "--lanes", lanes, "--preset", "kiss-icp", "--method", "paper",
        tmp_path / "in.txt", "-o", tmp_path / "plain.txt")
    got = lanealign.correct(poses, lanes=str(lanes), preset="kiss-icp", method="paper")
    assert got.poses.shape == poses.shape
    assert np.array_equal(got.poses, read_kitti(tmp_path / "plain.txt"))
    assert got.status.shape == (200,) and got.covariance.shape == (200, 3, 3)
    assert lanealign.STATUS_NAMES[got.status[0]] == "warming_up"
    # A source faster than the presets' 10 Hz: nine of every ten poses are carried, as on the
    # command line.
    cli("correct", "--lanes", lanes, "--preset", "kiss-icp", "--method", "paper",
        "--set", "odometry_rate_hz=100", tmp_path / "in.txt", "-o", tmp_path / "fast.txt")
    # 200 poses at 100 Hz fill no window: no alignment is tried, and Python warns it as the
    # command line does.
    with pytest.warns(UserWarning, match="no alignment was tried in 200 poses"):
        fast = lanealign.correct(poses, lanes=str(lanes), preset="kiss-icp", method="paper",
                                 odometry_rate_hz=100)
    assert np.array_equal(fast.poses, read_kitti(tmp_path / "fast.txt"))
    assert [lanealign.STATUS_NAMES[c] for c in fast.status[1:10]] == ["carried"] * 9
    # (N, 4, 4) and planar (N, 3) inputs give the same correction in their own shape.
    homogeneous = np.zeros((200, 4, 4))
    homogeneous[:, :3, :] = poses
    homogeneous[:, 3, 3] = 1
    h = lanealign.correct(homogeneous, lanes=str(lanes), preset="kiss-icp", method="paper")
    assert np.array_equal(h.poses[:, :3, :], got.poses)
    assert np.array_equal(h.poses[:, 3], np.tile([0, 0, 0, 1.0], (200, 1)))
    # So do the rows of a KITTI file as np.loadtxt reads it, (N, 12), in any frame.
    rows = lanealign.correct(np.loadtxt(tmp_path / "in.txt"), lanes=str(lanes), preset="kiss-icp",
                             method="paper")
    assert rows.poses.shape == (200, 12)
    assert np.array_equal(rows.poses, got.poses.reshape(200, 12))
    assert np.array_equal(rows.status, got.status)
    # Read in the camera's axes the drive goes down: every alignment is refused, and Python says
    # what to check as the command line does.
    camera = dict(lanes=str(lanes), preset="kiss-icp", frame="kitti-camera")
    refused = ("no correction was accepted in 51 attempts over 200 poses, .*: check the anchor "
               r"\(YAW_DEG in degrees from East, counter-clockwise\), --frame")
    with pytest.warns(UserWarning, match=refused):
        assert np.array_equal(lanealign.correct(poses.reshape(200, 12), **camera).poses,
                              lanealign.correct(poses, **camera).poses.reshape(200, 12))
    assert lanealign.eval(poses, rows.poses) == lanealign.eval(poses, got.poses)


def test_overrides_and_smooth_are_the_command_lines_set_and_smooth(tmp_path):
    lanes, poses = straight_lane_and_drift(tmp_path)
    write_kitti(tmp_path / "in.txt", poses)
    cli("correct", "--lanes", lanes, "--preset", "kiss-icp", "--smooth",
        "--set", "min_window=50", "--set", "lane_tolerance_m=0.25",
        "--set", "max_match_distance_m=inf", "--set", "gate_widens_through_null_steps=false",
        tmp_path / "in.txt", "-o", tmp_path / "set.txt")
    args = dict(lanes=str(lanes), preset="kiss-icp")
    got = lanealign.correct(poses, smooth=True, overrides={
        "min_window": 50, "lane_tolerance_m": 0.25, "max_match_distance_m": float("inf"),
        "gate_widens_through_null_steps": False}, **args)
    assert np.array_equal(got.poses, read_kitti(tmp_path / "set.txt"))
    assert not np.array_equal(got.poses, lanealign.correct(poses, **args).poses)
    for overrides, says in [({"nope": 1}, "nope"), ({"min_window": 50.0}, "min_window"),
                            ({"min_window": 1}, "min_window = 1: must be at least 2"),
                            ({"min_window": "50"}, "not a number or a bool")]:
        with pytest.raises(ValueError, match=re.escape(says)):
            lanealign.correct(poses, overrides=overrides, **args)
    with pytest.raises(ValueError, match="given twice"):
        lanealign.correct(poses, odometry_rate_hz=100, overrides={"odometry_rate_hz": 100}, **args)


def test_poses_missing_are_motion_unless_the_stamps_say_too_fast(tmp_path):
    # Twenty poses missing (2 s of a drive at 12 m/s, 25 m): without stamps, or with stamps that
    # show the pause, the drive goes on; stamps that say only 0.2 s passed make the 25 m a jump
    # (125 m/s), and the odometry is continued from where it was, as `lanealign correct`
    # continues the TUM file with those stamps. Without stamps the gap is told as poses missing.
    lanes, poses = straight_lane_and_drift(tmp_path)
    kept = np.r_[0:100, 120:200]
    gap = list(kept).index(120)
    with pytest.warns(UserWarning, match=re.escape("1 step of the odometry (100) was longer")):
        unstamped = lanealign.correct(poses[kept], preset="kiss-icp", lanes=lanes)
    paused = lanealign.correct(poses[kept], preset="kiss-icp", lanes=lanes, stamps=kept * 0.1)
    for run in (unstamped, paused):
        assert "odometry_jump" not in [lanealign.STATUS_NAMES[c] for c in run.status]
    assert np.array_equal(unstamped.poses, paused.poses)
    stamps = np.r_[0:100, 101:181] * 0.1
    with pytest.warns(UserWarning, match=re.escape("the odometry jumped at 1 pose (100)")):
        jumped = lanealign.correct(poses[kept], preset="kiss-icp", lanes=lanes, stamps=stamps)
    names = [lanealign.STATUS_NAMES[c] for c in jumped.status]
    assert names.count("odometry_jump") == 1 and names[gap] == "odometry_jump"
    assert abs(jumped.poses[-1, 0, 3] - unstamped.poses[-1, 0, 3]) > 20.0
    tum = write_tum(tmp_path / "jumped.tum", stamps, poses[kept])
    out = tmp_path / "out.tum"
    cli("correct", "--lanes", lanes, "--preset", "kiss-icp", "--format", "tum", tum, "-o", out)
    corrected = np.loadtxt(out)
    assert np.array_equal(corrected[:, 1:3], jumped.poses[:, :2, 3])
    with pytest.raises(ValueError, match="stamps: 3 stamps for 180 poses"):
        lanealign.correct(poses[kept], preset="kiss-icp", lanes=lanes, stamps=stamps[:3])
    # Stamps are checked as `lanealign correct` checks a TUM file's (a NaN, a repeated or a
    # backward stamp was taken, and changed nothing).
    for i, value, says in [(7, math.nan, "timestamp NaN is not finite"),
                           (0, math.inf, "timestamp inf is not finite"),
                           (100, stamps[99], "timestamps must increase"),
                           (120, 5.0, "timestamp 5 does not follow 1")]:
        bad = stamps.copy()
        bad[i] = value
        with pytest.raises(ValueError, match=re.escape(f"stamps[{i}]: ") + ".*" + re.escape(says)):
            lanealign.correct(poses[kept], preset="kiss-icp", lanes=lanes, stamps=bad)


def test_eval_pairs_by_time_as_the_command_line_pairs_tum_files(tmp_path):
    """Ground truth at 20 Hz and an estimate at 10 Hz stamped 3 ms late: given both stamps,
    `eval` pairs them by time as `lanealign eval --format tum` pairs the two files, and takes the
    covariances of the estimated poses it paired (without stamps only equal counts pair)."""
    lanes, poses = straight_lane_and_drift(tmp_path)
    est_stamps = np.arange(len(poses)) * 0.1 + 0.003
    truth = np.zeros((2 * len(poses), 3, 4))
    truth[:, :, :3] = np.eye(3)
    truth[:, 0, 3] = np.arange(len(truth)) * 0.6
    gt_stamps = np.arange(len(truth)) * 0.05

    gt_file = write_tum(tmp_path / "gt.tum", gt_stamps, truth)
    est_file = write_tum(tmp_path / "est.tum", est_stamps, poses)
    cli("correct", "--lanes", lanes, "--preset", "kiss-icp", "--format", "tum", est_file,
        "-o", tmp_path / "out.tum", "--status", tmp_path / "status.csv")
    expected = json.loads(cli("eval", "--gt", gt_file, "--est", tmp_path / "out.tum", "--format",
                              "tum", "--status", tmp_path / "status.csv", "--json"))
    corrected = lanealign.correct(poses, preset="kiss-icp", lanes=lanes, stamps=est_stamps)
    got = lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps, est_stamps=est_stamps,
                         covariance=corrected.covariance, anchor_yaw=corrected.anchor_yaw)
    assert got.keys() == expected.keys() and got["poses"] == expected["poses"] == len(poses)
    for key, value in expected.items():
        if isinstance(value, float):
            # The command line reads the corrected heading back from a quaternion.
            assert math.isclose(got[key], value, rel_tol=1e-9, abs_tol=1e-12), key
        else:
            assert got[key] == value, key
    with pytest.raises(ValueError, match="400 poses and the estimate 200"):
        lanealign.eval(truth, corrected.poses)
    with pytest.raises(ValueError, match="go together"):
        lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps)
    with pytest.raises(ValueError, match=re.escape("est_stamps: 3 stamps for 200 poses")):
        lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps, est_stamps=est_stamps[:3])
    backwards = gt_stamps.copy()
    backwards[7] = 0.0
    with pytest.raises(ValueError, match=re.escape("gt_stamps[7]: timestamp 0 does not follow")):
        lanealign.eval(truth, corrected.poses, gt_stamps=backwards, est_stamps=est_stamps)
    # A clock 20 ms late pairs nowhere within 10 ms, and within 25 ms as --max-dt 0.025 pairs it.
    late = est_stamps + 0.02
    with pytest.raises(ValueError, match=re.escape(
            "no estimate stamp lies within 0.01 s of a ground-truth stamp: the ground truth's 400 "
            "stamps run from 0.000 to 19.950 s, the estimate's 200 stamps run from 0.023 to")):
        lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps, est_stamps=late)
    write_tum(tmp_path / "late.tum", late, corrected.poses)
    expected = json.loads(cli("eval", "--gt", gt_file, "--est", tmp_path / "late.tum", "--format",
                              "tum", "--max-dt", "0.025", "--json"))
    got = lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps, est_stamps=late, max_dt=0.025)
    assert got["poses"] == expected["poses"] == len(poses)
    assert math.isclose(got["ape2d_mean_m"], expected["ape2d_mean_m"], rel_tol=1e-9)
    for bad in (0.0, -1.0, math.nan, math.inf, 3601.0):
        with pytest.raises(ValueError, match="max_dt: .* must be a number of seconds above 0"):
            lanealign.eval(truth, corrected.poses, gt_stamps=gt_stamps, est_stamps=late, max_dt=bad)


def test_errors_are_value_errors_with_the_command_lines_messages(tmp_path):
    lanes, poses = straight_lane_and_drift(tmp_path)
    with pytest.raises(ValueError, match="preset"):
        lanealign.correct(poses, lanes=str(lanes), preset="nope")
    with pytest.raises(ValueError, match=re.escape("overrides: max_window = '800': not a number")):
        lanealign.correct(poses, lanes=str(lanes), preset="kiss-icp", overrides={"max_window": "800"})
    # A name is quoted to 80 characters (a source of 1000 was quoted whole: 1132 characters).
    with pytest.raises(ValueError, match=r'source "x{80}\.\.\.": ') as refused:
        lanealign.Client("x" * 1000)
    assert len(str(refused.value)) < 300, str(refused.value)
    with pytest.raises(ValueError, match="exactly one"):
        lanealign.correct(poses, preset="kiss-icp")
    with pytest.raises(ValueError, match="shape"):
        lanealign.correct(np.zeros((3, 5)), lanes=str(lanes), preset="kiss-icp")
    # Each cause once, as the command line says it (the file's error came twice).
    with pytest.raises(ValueError, match="No such file") as missing:
        lanealign.correct(poses, lanes=str(tmp_path / "missing.csv"), preset="kiss-icp")
    assert str(missing.value).count("No such file") == 1, str(missing.value)
    with pytest.raises(ValueError, match="lat"):
        lanealign.correct(poses, osm="x.osm", anchor=(91, 0, 0, 0, 0), preset="kiss-icp")
    with pytest.raises(ValueError, match=r"anchor is \(lat, lon, yaw_deg\) or .* not 4 values"):
        lanealign.correct(poses, osm="x.osm", anchor=(49, 8, 0, 0), preset="kiss-icp")
    with pytest.raises(ValueError, match=r"shape \(N, 3, 4\).* not \[200, 11\]"):
        lanealign.correct(poses.reshape(200, 12)[:, :11], lanes=str(lanes), preset="kiss-icp",
                          frame="kitti-camera")
    with pytest.raises(ValueError, match="planar"):
        lanealign.correct(np.zeros((3, 3)), lanes=str(lanes), preset="kiss-icp",
                          frame="kitti-camera")
    osm = tmp_path / "road.osm"
    osm.write_text('<?xml version="1.0"?>\n<osm version="0.6"><node id="1" lat="49" lon="8"/>'
                   '<node id="2" lat="49.001" lon="8"/><way id="3"><nd ref="1"/><nd ref="2"/>'
                   '<tag k="highway" v="residential"/></way></osm>\n')
    text = osm.read_text()
    with pytest.raises(ValueError, match="is the input"):
        lanealign.compile_map(osm, osm)
    with pytest.raises(ValueError, match=r"inputs: none given"):
        lanealign.compile_map([], tmp_path / "road.tile")
    assert osm.read_text() == text
    # A NaN origin compiled a map of no lane ("the lane map is empty"); no laps, or 2^62 of them,
    # panicked (an index out of bounds, a capacity overflow).
    with pytest.raises(ValueError, match=r"origin: latitude NaN is outside \[-90, 90\] degrees"):
        lanealign.compile_map(osm, tmp_path / "road.tile", origin=(math.nan, 8.0))
    for laps in (0, 2**62):
        with pytest.raises(ValueError, match=f"laps: {laps}, expected 1 to 4000"):
            lanealign.synthetic_town(tmp_path / "town.tile", laps=laps)
    # A spacing of 1e300 m compiled a map of one point a lane, which no pose can match.
    for spacing in (0.0, -1.0, math.nan, 10.5, 1e300):
        with pytest.raises(ValueError, match=r"spacing: the lane point spacing .* m is outside"):
            lanealign.compile_map(osm, tmp_path / "road.tile", spacing=spacing)
    assert not (tmp_path / "road.tile").exists()


def test_poses_of_nans_are_flagged_and_the_others_corrected(tmp_path):
    # A pose of NaNs first, and one in the middle: each is answered invalid_input with its NaNs
    # echoed, as the daemon answers one, and the others are what they are without it. The first
    # used to panic (the anchor check asked the lanes what was near a NaN).
    lanes, poses = straight_lane_and_drift(tmp_path)
    clean = lanealign.correct(poses[1:], lanes=str(lanes), preset="kiss-icp")
    broken = poses.copy()
    broken[0] = np.nan
    broken[120] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = lanealign.correct(broken, lanes=str(lanes), preset="kiss-icp")
    names = [lanealign.STATUS_NAMES[s] for s in got.status]
    assert [i for i, n in enumerate(names) if n == "invalid_input"] == [0, 120]
    assert np.isnan(got.poses[[0, 120]]).all() and np.isnan(got.covariance[[0, 120]]).all()
    assert np.array_equal(got.poses[1:120], clean.poses[:119])
    assert np.isfinite(got.poses[121:]).all()
    everything = np.full((5, 3, 4), np.nan)
    every = lanealign.correct(everything, lanes=str(lanes), preset="kiss-icp")
    assert [lanealign.STATUS_NAMES[s] for s in every.status] == ["invalid_input"] * 5


def test_synthetic_town_equals_the_command_line_bit_for_bit(tmp_path):
    town = tmp_path / "town.tile"
    truth, odometry = lanealign.synthetic_town(town)
    assert truth.shape == odometry.shape and odometry.shape[1:] == (3, 4)
    write_kitti(tmp_path / "odometry.txt", odometry)
    anchor = (49.0, 8.4, 0.0, 0.0, 0.0)
    raw = lanealign.eval(truth, odometry)["ape2d_mean_m"]
    for method in ("robust", "paper"):
        out = tmp_path / f"{method}.txt"
        cli("correct", "--map", town, "--anchor", "49,8.4,0,0,0", "--preset", "kiss-icp",
            "--method", method, tmp_path / "odometry.txt", "-o", out)
        got = lanealign.correct(odometry, tile=str(town), anchor=anchor, preset="kiss-icp",
                                method=method)
        assert np.array_equal(got.poses, read_kitti(out)), method
        assert lanealign.eval(truth, got.poses)["ape2d_mean_m"] < raw / 3, method
    # The anchor's offsets may be left out, as on the command line.
    cli("correct", "--map", town, "--anchor", "49,8.4,0", "--preset", "kiss-icp",
        tmp_path / "odometry.txt", "-o", tmp_path / "short.txt")
    short = lanealign.correct(odometry, tile=str(town), anchor=(49.0, 8.4, 0.0), preset="kiss-icp")
    assert np.array_equal(short.poses, read_kitti(tmp_path / "short.txt"))
    assert np.array_equal(short.poses, read_kitti(tmp_path / "robust.txt"))


def anchor_of(seq):
    row = next(l for l in (DATA / "kitti" / "georef.csv").read_text().splitlines()
               if l.startswith(f"{seq},"))
    f = row.split(",")
    return (float(f[1]), float(f[2]), float(f[4]), float(f[5]), float(f[6]))


@pytest.mark.parametrize("seq", ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"])
def test_shared_kitti_runs_equal_the_command_line_bit_for_bit(tmp_path, seq):
    needs_data()
    anchor = anchor_of(seq)
    osm = DATA / "osm" / f"kitti_{seq}.osm"
    anchor_flag = ",".join(repr(v) for v in anchor)
    for run, preset in (("lidar", "kiss-icp"), ("stereo_vo", "orb-slam3")):
        odometry = DATA / "odometry" / run / f"{seq}.txt"
        poses = np.loadtxt(odometry).reshape(-1, 3, 4)
        for method in ("robust", "paper"):
            out = tmp_path / f"{run}_{method}.txt"
            told = cli_run("correct", "--osm", osm, "--anchor", anchor_flag, "--projection",
                           "kitti", "--preset", preset, "--method", method, "--frame",
                           "kitti-camera", odometry, "-o", out).stderr
            with warnings.catch_warnings(record=True) as warned:
                warnings.simplefilter("always")
                got = lanealign.correct(poses, osm=str(osm), anchor=anchor, projection="kitti",
                                        preset=preset, method=method, frame="kitti-camera")
            assert np.array_equal(got.poses, read_kitti(out)), (run, method)
            # The command line's WARN lines are Python's warnings: on the shared runs only the
            # visual odometry of 01 that loses track on the highway (docs/method.md).
            assert all(w.category is UserWarning for w in warned)
            assert [f"WARN {w.message}" for w in warned] == re.findall(r"WARN .*", told)
            stalls = (run, seq) == ("stereo_vo", "01")
            assert len(warned) == stalls, (run, [str(w.message) for w in warned])
            if stalls:
                assert "pose 808 (19.0 -> 2.9 m/s)" in str(warned[0].message)


def test_the_odometry_scale_is_estimated_where_asked_and_said_as_the_command_line_says(tmp_path):
    needs_data()
    anchor = anchor_of("01")
    osm = DATA / "osm" / "kitti_01.osm"
    odometry = DATA / "odometry" / "stereo_vo" / "01.txt"
    poses = np.loadtxt(odometry).reshape(-1, 3, 4)
    common = dict(osm=str(osm), anchor=anchor, projection="kitti", frame="kitti-camera")
    # Its visual odometry loses track on the highway, whatever the preset (docs/method.md).
    stall = "the odometry's speed changes faster than a car's can"
    with pytest.warns(UserWarning, match=stall):
        visual = lanealign.correct(poses, preset="orb-slam3", **common)
    # 01's visual odometry measures 0.917 of the road: its steps are lengthened.
    assert visual.odometry_scale.shape == (len(poses),)
    assert visual.odometry_scale[0] == 1.0 and visual.odometry_scale[-1] > 1.02
    # Its uncertainty starts at the preset's scale_sigma and shrinks as the lanes tell it.
    assert visual.odometry_scale_sd[0] == 0.05 and 0 < visual.odometry_scale_sd[-1] < 0.05
    out = tmp_path / "out.txt"
    run = subprocess.run([str(BIN), "correct", "--osm", str(osm), "--anchor",
                          ",".join(repr(v) for v in anchor), "--projection", "kitti",
                          "--preset", "orb-slam3", "--frame", "kitti-camera", str(odometry),
                          "-o", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert f"multiplied by {visual.odometry_scale[-1]:.4f} at the end" in run.stderr
    assert np.array_equal(visual.poses, read_kitti(out))
    # The LiDAR preset leaves the scale alone unless asked.
    with pytest.warns(UserWarning, match=stall):
        lidar = lanealign.correct(poses, preset="kiss-icp", **common)
    assert np.all(lidar.odometry_scale == 1.0) and np.all(lidar.odometry_scale_sd == 0.0)
    with pytest.warns(UserWarning, match=stall):
        asked = lanealign.correct(poses, preset="kiss-icp", overrides={"scale_sigma": 0.05},
                                  **common)
    assert asked.odometry_scale[-1] != 1.0


def test_a_grid_corrects_as_its_tile(tmp_path):
    needs_data()
    anchor = anchor_of("00")
    osm = DATA / "osm" / "kitti_00.osm"
    info = lanealign.compile_map(osm, tmp_path / "grid", origin=anchor[:2], projection="kitti",
                                 grid=200)
    lanealign.compile_map(osm, tmp_path / "00.tile", origin=anchor[:2], projection="kitti")
    out = subprocess.run([str(MAP_BIN), "compile", str(osm), "--origin", f"{anchor[0]!r},{anchor[1]!r}",
                          "--projection", "kitti", "--grid", "200", "-o", str(tmp_path / "cli")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert info["cells"] == len(list((tmp_path / "cli" / "cells").iterdir()))
    for name in ["manifest.toml", *sorted(p.name for p in (tmp_path / "cli" / "cells").iterdir())]:
        rel = name if name == "manifest.toml" else f"cells/{name}"
        assert (tmp_path / "grid" / rel).read_bytes() == (tmp_path / "cli" / rel).read_bytes(), rel
    poses = np.loadtxt(DATA / "odometry" / "lidar" / "00.txt").reshape(-1, 3, 4)
    on_grid = lanealign.correct(poses, tile=str(tmp_path / "grid"), anchor=anchor,
                                preset="kiss-icp", frame="kitti-camera")
    on_tile = lanealign.correct(poses, tile=str(tmp_path / "00.tile"), anchor=anchor,
                                preset="kiss-icp", frame="kitti-camera")
    assert np.array_equal(on_grid.poses, on_tile.poses)
    assert np.array_equal(on_grid.covariance, on_tile.covariance)


def test_kitti_07_equals_correct_and_eval_bit_for_bit(tmp_path):
    """Correction, APE and the covariances' calibration are the command line's."""
    needs_data()
    anchor = anchor_of("07")
    odometry = DATA / "odometry" / "lidar" / "07.txt"
    gt_path = DATA / "kitti" / "poses" / "07.txt"
    osm = DATA / "osm" / "kitti_07.osm"
    anchor_flag = ",".join(repr(v) for v in anchor)
    start = time.perf_counter()
    cli("correct", "--osm", osm, "--anchor", anchor_flag, "--projection", "kitti",
        "--preset", "kiss-icp", "--frame", "kitti-camera", odometry, "-o", tmp_path / "out.txt",
        "--status", tmp_path / "status.csv")
    cli_s = time.perf_counter() - start
    poses = np.loadtxt(odometry).reshape(-1, 3, 4)
    start = time.perf_counter()
    got = lanealign.correct(poses, osm=str(osm), anchor=anchor, projection="kitti",
                            preset="kiss-icp", frame="kitti-camera")
    py_s = time.perf_counter() - start
    assert np.array_equal(got.poses, read_kitti(tmp_path / "out.txt"))
    figures = lanealign.eval(np.loadtxt(gt_path).reshape(-1, 3, 4), got.poses, frame="kitti-camera")
    expected = json.loads(cli("eval", "--gt", gt_path, "--est", tmp_path / "out.txt",
                              "--frame", "kitti-camera", "--json"))
    assert figures == expected
    # With the covariances, what `eval --status` reports: the map plane's covariances turned into
    # the odometry frame by the anchor's yaw (the map plane's origin is the anchor: 07's -32.0
    # degrees).
    assert math.isclose(got.anchor_yaw, math.radians(anchor[2]), rel_tol=0, abs_tol=1e-12)
    calibrated = lanealign.eval(np.loadtxt(gt_path).reshape(-1, 3, 4), got.poses,
                                frame="kitti-camera", covariance=got.covariance,
                                anchor_yaw=got.anchor_yaw)
    expected = json.loads(cli("eval", "--gt", gt_path, "--est", tmp_path / "out.txt",
                              "--status", tmp_path / "status.csv", "--frame", "kitti-camera",
                              "--json"))
    assert calibrated == expected
    assert {"cov95_coverage", "nees_mean", "independent_samples", "cov95_coverage_if_exact",
            "nees_mean_if_exact", "calibration_verdict"} <= set(calibrated)
    # Turned by another yaw, the same covariances describe the errors differently.
    turned = lanealign.eval(np.loadtxt(gt_path).reshape(-1, 3, 4), got.poses, frame="kitti-camera",
                            covariance=got.covariance, anchor_yaw=got.anchor_yaw + math.pi / 2)
    assert turned["nees_mean"] != calibrated["nees_mean"]
    with pytest.raises(ValueError, match="go together"):
        lanealign.eval(got.poses, got.poses, covariance=got.covariance)
    with pytest.raises(ValueError, match=r"expected \(\d+, 3, 3\)"):
        lanealign.eval(got.poses, got.poses, covariance=got.covariance[1:], anchor_yaw=0.0)
    for yaw in (math.nan, 7.0, 1e300):
        with pytest.raises(ValueError, match=r"anchor_yaw: .* is not an angle in \[-2 pi, 2 pi\]"):
            lanealign.eval(got.poses, got.poses, covariance=got.covariance, anchor_yaw=yaw)
    # A matrix that is not symmetric is no covariance (one was read as its symmetric part).
    for r, k in [(0, 1), (2, 0)]:
        skewed = got.covariance.copy()
        skewed[9, r, k] += 0.5
        with pytest.raises(ValueError, match=re.escape(
                f"the covariance of pose 9 is not symmetric: [{min(r, k)}, {max(r, k)}] = ")):
            lanealign.eval(got.poses, got.poses, covariance=skewed, anchor_yaw=0.0)
    # A covariance far smaller than its error (1e-307 m^2 across a metre or so) is refused: the
    # normalised errors squared were summed to inf and reported as the mean NEES.
    tiny = np.zeros_like(got.covariance)
    tiny[:, 0, 0], tiny[:, 1, 1], tiny[:, 2, 2] = 1e-307, 1e290, 1.0
    with pytest.raises(ValueError, match="too small for its error"):
        lanealign.eval(np.loadtxt(gt_path).reshape(-1, 3, 4), got.poses, frame="kitti-camera",
                       covariance=tiny, anchor_yaw=0.0)
    rounded = got.covariance.copy()
    rounded[9, 0, 1] *= 1 + 1e-12
    assert lanealign.eval(got.poses, got.poses, covariance=rounded, anchor_yaw=0.0)["poses"] == \
        len(got.poses)
    print(f"KITTI 07: lanealign correct {cli_s * 1e3:.1f} ms (whole process), "
          f"lanealign.correct {py_s * 1e3:.1f} ms (call, file read by numpy not included)")


def test_compile_map_writes_the_tile_the_command_line_writes(tmp_path):
    needs_data()
    osm = DATA / "osm" / "kitti_00.osm"
    origin = "48.9825452359,8.3903661"
    out = subprocess.run([str(MAP_BIN), "compile", str(osm), "--origin", origin, "--projection",
                          "kitti", "-o", str(tmp_path / "cli.tile")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    info = lanealign.compile_map(osm, tmp_path / "py.tile", origin=(48.9825452359, 8.3903661),
                                 projection="kitti")
    assert (tmp_path / "py.tile").read_bytes() == (tmp_path / "cli.tile").read_bytes()
    assert info["lanes"] == 228 and info["bytes"] == (tmp_path / "py.tile").stat().st_size
    with pytest.raises(ValueError, match="No such file|missing|read"):
        lanealign.compile_map(tmp_path / "missing.osm", tmp_path / "x.tile")


def test_compile_map_signs_as_the_command_line_signs(tmp_path):
    # Signatures are deterministic (ed25519), so a signed tile and a signed grid (its cells and
    # its manifest) from the package equal the command line's byte for byte.
    osm = tmp_path / "road.osm"
    nodes = "".join(f'<node id="{k}" lat="{49 + 0.001 * k}" lon="8"/>' for k in range(1, 6))
    osm.write_text('<?xml version="1.0"?>\n<osm version="0.6">' + nodes + '<way id="9">'
                   + "".join(f'<nd ref="{k}"/>' for k in range(1, 6))
                   + '<tag k="highway" v="residential"/></way></osm>\n')
    key = tmp_path / "builder.key"
    out = subprocess.run([str(MAP_BIN), "keygen", "-o", str(key)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    public = out.stdout.strip()
    for name, grid in (("road.tile", []), ("grid", ["--grid", "200"])):
        cli, py = tmp_path / f"cli-{name}", tmp_path / f"py-{name}"
        out = subprocess.run([str(MAP_BIN), "compile", str(osm), "--origin", "49,8", "--classes",
                              "residential", "--sign", str(key), "--map-version", "20261207",
                              *grid, "-o", str(cli)],
                             capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        info = lanealign.compile_map(osm, py, origin=(49.0, 8.0), classes="residential",
                                     sign=key, grid=float(grid[1]) if grid else None,
                                     map_version=20261207)
        assert info["signer"] == public and info["map_version"] == 20261207
        if grid:
            files = sorted(p.relative_to(cli) for p in cli.rglob("*") if p.is_file())
            assert len(files) == info["cells"] + 1, files
            pairs = [(cli / f, py / f) for f in files]
        else:
            pairs = [(cli, py)]
        for a, b in pairs:
            assert a.read_bytes() == b.read_bytes(), a
    assert "signer" not in lanealign.compile_map(osm, tmp_path / "plain.tile", origin=(49.0, 8.0))
    # A key others may read signs, with a warning; keygen's (mode 0600) gives none.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lanealign.compile_map(osm, tmp_path / "quiet.tile", sign=key)
    key.chmod(0o644)
    with pytest.warns(UserWarning, match=r"may be read by others \(mode 644\)"):
        lanealign.compile_map(osm, tmp_path / "exposed.tile", sign=key)
    with pytest.raises(ValueError, match="not a key file from `lanealign-map keygen`"):
        lanealign.compile_map(osm, tmp_path / "x.tile", sign=osm)
    with pytest.raises(ValueError, match="classes: "):
        lanealign.compile_map(osm, tmp_path / "x.tile", classes="footway")
    with pytest.raises(ValueError, match="map_version: map version 9223372036854775808: at most"):
        lanealign.compile_map(osm, tmp_path / "x.tile", map_version=2**63)
    with pytest.raises(ValueError, match="map_version: map version 18446744073709551616: at most"):
        lanealign.compile_map(osm, tmp_path / "x.tile", map_version=2**64)
    with pytest.raises(ValueError, match="map_version: -1: a map version counts builds, 0 or more"):
        lanealign.compile_map(osm, tmp_path / "x.tile", map_version=-1)
    assert not (tmp_path / "x.tile").exists()


def remove_namespace_files(namespace):
    """iceoryx2 keeps a namespace's files after its last process has left (the root folder and
    the shared-memory files, named as `Namespace::remove_files` in wire/src/service.rs removes
    them); a test's namespace goes with the test."""
    shutil.rmtree(f"/dev/shm/lanealign-{namespace}", ignore_errors=True)
    ours = re.compile(rf"lanealign_{re.escape(namespace)}_[0-9a-fA-F]{{40}}.*")
    for f in Path("/dev/shm").iterdir():
        if ours.fullmatch(f.name):
            f.unlink(missing_ok=True)


ANCHOR_00 = (48.9825452359, 8.3903661, 59.5584, 0.806, 0.365)


@contextlib.contextmanager
def kitti_00_daemon(tmp_path, namespace):
    """A `lanealignd` serving source `lidar` (KITTI 00, kiss-icp preset) in `namespace`; yields
    the daemon's process and a client connected to it."""
    lanealign.compile_map(DATA / "osm" / "kitti_00.osm", tmp_path / "00.tile",
                          origin=ANCHOR_00[:2], projection="kitti")
    lat, lon, yaw, east, north = ANCHOR_00
    (tmp_path / "d.toml").write_text(f"""
tile = "00.tile"
namespace = "{namespace}"
state_dir = "{tmp_path / 'state'}"
[[source]]
name = "lidar"
frame = "kitti-camera"
anchor = {{ lat = {lat}, lon = {lon}, yaw_deg = {yaw}, east_m = {east}, north_m = {north} }}
[source.corrector]
preset = "kiss-icp"
""")
    log = open(tmp_path / "daemon.log", "w")
    daemon = subprocess.Popen([str(BIN.with_name("lanealignd")), "--config", str(tmp_path / "d.toml")],
                              stderr=log)
    client = None
    try:
        client = lanealign.Client("lidar", namespace=namespace)
        deadline = time.monotonic() + 20
        while not client.daemon_connected():
            assert time.monotonic() < deadline and daemon.poll() is None, "the daemon did not come up"
            time.sleep(0.05)
        yield daemon, client
    finally:
        daemon.send_signal(signal.SIGCONT)
        daemon.terminate()
        daemon.wait(20)
        log.close()
        client = None  # its iceoryx2 node goes before the namespace's files
        remove_namespace_files(namespace)


def kitti_00_lidar(n):
    return np.loadtxt(DATA / "odometry" / "lidar" / "00.txt").reshape(-1, 3, 4)[:n]


def test_client_through_the_daemon_equals_correct(tmp_path):
    needs_data()
    namespace = f"py-{os.getpid()}"
    poses = kitti_00_lidar(600)
    with kitti_00_daemon(tmp_path, namespace) as (daemon, client):
        assert not client.session_opened(), "the daemon opens a session at its first pose"
        other = lanealign.Client("lidar2", namespace=namespace)
        assert not other.daemon_connected()
        why = other.why_unserved()
        assert f"the daemon of namespace '{namespace}' serves 'lidar', not 'lidar2'" in why, why
        del other
        answers = []
        # A pose as a (3, 4) array, a KITTI row, a (4, 4) matrix and a list (the last three
        # were refused: a shape error, or a TypeError for a list).
        forms = [lambda p: p, lambda p: p.reshape(12), lambda p: np.vstack([p, [0, 0, 0, 1]]),
                 lambda p: p.tolist()]
        for i, pose in enumerate(poses[:590]):
            assert client.publish(i, forms[i % len(forms)](pose)) == i + 1
            # A wait longer than any instant is a wait without end (it panicked on the overflow).
            answer = client.recv(10.0 if i else 9.3e18)
            assert answer is not None and answer["seq"] == i + 1
            assert client.session_opened()
            answers.append(answer)
        for shape in [(5,), (3, 3), (2, 3, 4)]:
            with pytest.raises(ValueError, match=re.escape(
                    f"a pose has shape (3, 4), (4, 4) or (12,), not {list(shape)}")):
                client.publish(590, np.zeros(shape))
        for i, pose in enumerate(poses[590:], start=590):
            assert client.publish(i, pose) == i + 1
        closed = client.close(10.0)
        assert closed["daemon_told"] and closed["unanswered"] == []
        answers += closed["answers"]
        assert [a["seq"] for a in answers] == list(range(1, 601))
        with pytest.raises(ValueError, match="closed"):
            client.recv(0.0)
        journals = tmp_path / "state" / namespace / "lidar"
        deadline = time.monotonic() + 5
        while any(journals.iterdir()) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not any(journals.iterdir()), "the daemon forgot the closed session"
    offline = lanealign.correct(poses, osm=str(DATA / "osm" / "kitti_00.osm"), anchor=ANCHOR_00,
                                projection="kitti", preset="kiss-icp", frame="kitti-camera")
    assert np.array_equal(np.stack([a["pose"] for a in answers]), offline.poses)
    assert [a["status"] for a in answers] == [lanealign.STATUS_NAMES[c] for c in offline.status]
    assert {a["reason"] for a in answers if a["status"] not in ("rejected", "reset")} == {""}
    assert answers[-1]["covariance"].shape == (3, 3)
    assert all(a["warnings"] == [] for a in answers), "the drive is set up as a vehicle's"
    # The tile's origin is the anchor's, so the map plane is the anchor's East-North plane.
    yaw = math.radians(ANCHOR_00[2])
    assert all(math.isclose(a["anchor_yaw"], yaw, rel_tol=0, abs_tol=1e-12) for a in answers)
    assert [a["odometry_scale"] for a in answers] == list(offline.odometry_scale)
    assert all(a["odometry_scale_sd"] == 0.0 for a in answers), "kiss-icp does not estimate it"
    # What the status CSV says of each step, as `lanealign correct --status` says it.
    write_kitti(tmp_path / "600.txt", poses)
    cli("correct", "--osm", DATA / "osm" / "kitti_00.osm", "--anchor", ",".join(map(str, ANCHOR_00)),
        "--projection", "kitti", "--preset", "kiss-icp", "--frame", "kitti-camera",
        tmp_path / "600.txt", "-o", tmp_path / "600_out.txt", "--status", tmp_path / "600.csv")
    with open(tmp_path / "600.csv") as f:
        rows = list(csv.DictReader(f))
    for key, kind in [("residual_m", float), ("match_ratio", float), ("window_len", int),
                      ("applied_directions", int)]:
        expected = [kind(r[key]) for r in rows]
        got = [a[key] for a in answers]
        assert np.array_equal(np.array(got, dtype=float), np.array(expected, dtype=float),
                              equal_nan=True), key
    assert all(a["sent_mono_ns"] <= a["received_mono_ns"] <= a["published_mono_ns"]
               for a in answers)
    assert all(a["published_mono_ns"] <= time.monotonic_ns() for a in answers)
    assert len({a["daemon_epoch"] for a in answers}) == 1
    assert [a["expected_seq"] for a in answers] == list(range(2, 602))


# An odometry process: publishes the poses of POSES (.npy) one at a time, keeps what its
# restarted self needs (its session and next sequence number) with the answers, and dies by
# SIGKILL without closing.
KILLED_CLIENT = """
import json, os, signal, sys
import numpy as np
import lanealign

namespace, poses, out = sys.argv[1:]
client = lanealign.Client("lidar", namespace=namespace)
answers = []
for i, pose in enumerate(np.load(poses)):
    assert client.publish(i, pose) == i + 1
    answers.append(client.recv(10.0))
np.save(out + ".npy", np.stack([a["pose"] for a in answers]))
with open(out + ".json", "w") as f:
    json.dump({"session": client.session, "next_seq": client.next_seq,
               "status": [a["status"] for a in answers]}, f)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_restarted_process_continues_its_session(tmp_path):
    """An odometry process killed (kill -9) after 300 poses; its restarted self continues the
    session with the session id and sequence number it kept, and every answer is what one
    process that ran on gets (a new session would start its corrector afresh)."""
    needs_data()
    namespace = f"py-resume-{os.getpid()}"
    poses = kitti_00_lidar(600)
    np.save(tmp_path / "poses.npy", poses[:300])
    with kitti_00_daemon(tmp_path, namespace) as (daemon, _):
        killed = subprocess.run([sys.executable, "-c", KILLED_CLIENT, namespace,
                                 str(tmp_path / "poses.npy"), str(tmp_path / "first")],
                                capture_output=True, text=True, timeout=120)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
        kept = json.loads((tmp_path / "first.json").read_text())
        assert kept["next_seq"] == 301 and kept["session"] > 0
        client = lanealign.Client("lidar", namespace=namespace, session=kept["session"],
                                  next_seq=kept["next_seq"])
        assert (client.session, client.next_seq) == (kept["session"], 301)
        answers = []
        for i, pose in enumerate(poses[300:], start=300):
            assert client.publish(i, pose) == i + 1
            answer = client.recv(10.0)
            assert answer is not None and answer["seq"] == i + 1
            answers.append(answer)
        assert client.close(10.0)["unanswered"] == []
    offline = lanealign.correct(poses, osm=str(DATA / "osm" / "kitti_00.osm"), anchor=ANCHOR_00,
                                projection="kitti", preset="kiss-icp", frame="kitti-camera")
    got = np.concatenate([np.load(tmp_path / "first.npy"),
                          np.stack([a["pose"] for a in answers])])
    assert np.array_equal(got, offline.poses)
    assert kept["status"] + [a["status"] for a in answers] == \
        [lanealign.STATUS_NAMES[c] for c in offline.status]
    with pytest.raises(ValueError, match="0 is no session"):
        lanealign.Client("lidar", namespace=namespace, session=0)
    with pytest.raises(ValueError, match="give the session too"):
        lanealign.Client("lidar", namespace=namespace, next_seq=301)


def test_one_client_publishes_on_one_thread_and_receives_on_another(tmp_path):
    """The client, made on this thread, is used by two others at once: one publishes a pose
    every 2 ms, the other waits in `recv`. Every pose is answered once, as `correct` gives it,
    and no publish waits for the other thread's wait (it would for up to 0.1 s, the wait's
    slice, were the connection held while waiting). A client was bound to its thread before."""
    needs_data()
    poses = kitti_00_lidar(300)
    with kitti_00_daemon(tmp_path, f"pt-{os.getpid()}") as (daemon, client):
        answers, longest, failures = [], [0.0], []

        def receive():
            try:
                deadline = time.monotonic() + 30
                while len(answers) < len(poses) and time.monotonic() < deadline:
                    answer = client.recv(1.0)
                    if answer is not None:
                        answers.append(answer)
            except BaseException as e:  # a PanicException is not an Exception
                failures.append(e)

        def publish():
            try:
                for i, pose in enumerate(poses):
                    started = time.monotonic()
                    client.publish(i, pose)
                    longest[0] = max(longest[0], time.monotonic() - started)
                    time.sleep(0.002)
            except BaseException as e:
                failures.append(e)

        threads = [threading.Thread(target=receive), threading.Thread(target=publish)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert failures == []
        assert [a["seq"] for a in answers] == list(range(1, len(poses) + 1))
        assert longest[0] < 0.05, longest[0]
    offline = lanealign.correct(poses, osm=str(DATA / "osm" / "kitti_00.osm"), anchor=ANCHOR_00,
                                projection="kitti", preset="kiss-icp", frame="kitti-camera")
    assert np.array_equal(np.stack([a["pose"] for a in answers]), offline.poses)


def freeze(pid):
    """Stops process `pid` (SIGSTOP) and returns once every thread of it has stopped."""
    os.kill(pid, signal.SIGSTOP)
    tasks = Path(f"/proc/{pid}/task")
    deadline = time.monotonic() + 5
    while not all((t / "stat").read_text().rsplit(")", 1)[1].split()[0] == "T" for t in tasks.iterdir()):
        assert time.monotonic() < deadline, "the daemon did not stop"
        time.sleep(0.001)


def test_a_close_that_fails_keeps_the_answers_it_received(tmp_path):
    """Closing fails when the client cannot tell whether the daemon lives (injected: the daemon
    frozen with a pose in flight, the client out of file descriptors, so that listing the
    namespace's nodes fails); the error holds every answer that arrived while closing and names
    the pose that got none: each pose published is counted out once."""
    needs_data()
    poses = kitti_00_lidar(40)
    with kitti_00_daemon(tmp_path, f"py-{os.getpid()}") as (daemon, client):
        for i, pose in enumerate(poses[:10]):
            client.publish(i, pose)
            assert client.recv(10.0)["seq"] == i + 1
        for i, pose in enumerate(poses[10:39], start=10):
            client.publish(i, pose)
        time.sleep(1.0)  # the daemon answers them meanwhile; the client takes none yet
        freeze(daemon.pid)
        client.publish(39, poses[39])
        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        lowest_free = os.dup(0)
        os.close(lowest_free)
        resource.setrlimit(resource.RLIMIT_NOFILE, (lowest_free, hard))
        try:
            with pytest.raises(lanealign.CloseError) as raised:
                client.close(10.0)
        finally:
            resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
        failed = raised.value
        assert isinstance(failed, ValueError)
        assert "waiting for the answers in flight failed" in str(failed), str(failed)
        answered = [a["seq"] for a in failed.answers]
        assert sorted(answered + failed.unanswered) == list(range(11, 41)), str(failed)
        assert answered and 40 in failed.unanswered and failed.daemon_told is False
        assert failed.answers[-1]["pose"].shape == (3, 4)
        with pytest.raises(ValueError, match="closed"):
            client.recv(0.0)


def test_a_with_block_ends_its_session_and_keeps_the_blocks_exception(tmp_path):
    needs_data()
    namespace = f"py-with-{os.getpid()}"
    poses = kitti_00_lidar(20)
    journals = tmp_path / "state" / namespace / "lidar"

    def forgotten():
        deadline = time.monotonic() + 5
        while any(journals.iterdir()) and time.monotonic() < deadline:
            time.sleep(0.02)
        return not any(journals.iterdir())

    with kitti_00_daemon(tmp_path, namespace) as (daemon, _):
        with lanealign.Client("lidar", namespace=namespace) as client:
            for i, pose in enumerate(poses):
                assert client.publish(i, pose) == i + 1
                assert client.recv(10.0)["seq"] == i + 1
            assert any(journals.iterdir()), "the daemon journals an open session"
        assert forgotten(), "leaving the block told the daemon the session is over"
        with pytest.raises(ValueError, match="closed"):
            client.recv(0.0)
        # An odometry process that fails in the block: its exception comes out, not the
        # close's, and the session still ends.
        with pytest.raises(KeyError, match="the odometry failed"):
            with lanealign.Client("lidar", namespace=namespace) as client:
                client.publish(0, poses[0])
                assert client.recv(10.0)["seq"] == 1
                raise KeyError("the odometry failed")
        assert forgotten(), "a block that raised ended its session too"
        # Closed in the block (to keep the answers in flight), leaving it closes nothing more.
        with lanealign.Client("lidar", namespace=namespace) as client:
            for i, pose in enumerate(poses[:5]):
                client.publish(i, pose)
            closed = client.close(10.0)
        assert [a["seq"] for a in closed["answers"]] == [1, 2, 3, 4, 5]
        assert closed["daemon_told"] and forgotten()


def test_a_waiting_recv_lets_other_threads_run_and_ctrl_c_in():
    """`Client.recv` waits without the GIL: another Python thread runs as much meanwhile as
    while the caller sleeps (it got 0.6 % when recv held the GIL), and Ctrl-C (SIGINT) stops a
    10 s wait within a fraction of a second (it came after the 10 s). No daemon needed: with
    nothing in flight, recv waits out its timeout."""
    namespace = f"pw-{os.getpid()}"
    client = lanealign.Client("lidar", namespace=namespace)
    assert client.why_unserved().startswith(f"no daemon runs in namespace '{namespace}'")
    try:
        turns, stop = [0], [False]

        def spin():
            while not stop[0]:
                turns[0] += 1

        spinner = threading.Thread(target=spin)
        spinner.start()
        try:
            start = turns[0]
            assert client.recv(1.0) is None
            during_recv = turns[0] - start
            start = turns[0]
            time.sleep(1.0)
            during_sleep = turns[0] - start
        finally:
            stop[0] = True
            spinner.join()
        assert during_recv > 0.25 * during_sleep, (during_recv, during_sleep)
        # Python's own Ctrl-C handler, whatever this process inherited (a background job of a
        # shell starts with SIGINT ignored, and Python then installs none).
        inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
            started = time.monotonic()
            with pytest.raises(KeyboardInterrupt):
                client.recv(10.0)
            assert time.monotonic() - started < 2.0
        finally:
            signal.signal(signal.SIGINT, inherited)
        assert client.recv(0.0) is None, "the client is usable after the interruption"
    finally:
        client = None
        remove_namespace_files(namespace)
