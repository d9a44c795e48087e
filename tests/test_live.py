"""The live path: LiveAligner, LiveBlocks, LivePair, LineReader, `gyrocal track` and the ROS 2 node's logic."""

import json
import socket
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from _shared import data_folder
from _examples import load_example

from fusion_gyrocal.cli import main
from fusion_gyrocal.errors import InputError
from fusion_gyrocal.evaluate.sim import general_rotation, simulate_drifting_pair
from fusion_gyrocal.online.live import LineReader, LiveAligner, LiveBlocks, LivePair
from fusion_gyrocal.online.steps import block_spans
from fusion_gyrocal.online.tracker import GyroPairTracker

STATE = ("R_1_2", "scale_1", "scale_2", "bias", "error_covariance")


def _pair(n=4000, rate=100.0, seed=0):
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(n) / rate
    w1, w2, _ = simulate_drifting_pair(t, general_rotation(rng, 15.0), np.ones(3), np.ones(3), rng=rng)
    return t, w1, w2


def _interleaved(n, rng):
    """A random order of n samples of gyro 1 and n of gyro 2, each stream in its own order."""
    order = np.repeat([1, 2], n)
    rng.shuffle(order)
    return order


def _batch(t, w1, w2, seed_s, mode, **kw):
    k = int(np.argmax(t - t[0] >= seed_s))
    gap = 5.0 * float(np.median(np.diff(t[:k + 1])))
    bt = GyroPairTracker.from_samples(t[:k + 1], w1[:k + 1], w2[:k + 1], history_max_rows=2000)
    bt.run(t[k + 1:], w1[k + 1:], w2[k + 1:], mode=mode, max_gap_s=gap, **kw)
    return bt


# ---------------------------------------------------------------------------------------------- aligner
def test_live_aligner_interpolates_gyro2_at_gyro1_instants():
    a = LiveAligner(time_offset_s=0.5)
    assert len(a.push(2, -0.5, [0.0, 0.0, 1.0])[0]) == 0      # gyro 2 at 0.0 on gyro 1's clock
    assert len(a.push(1, 0.025, [1.0, 0.0, 0.0])[0]) == 0     # waits for gyro 2 past 0.025
    t, w1, w2 = a.push(2, -0.4, [0.0, 0.0, 3.0])
    np.testing.assert_allclose(t, [0.025])
    np.testing.assert_allclose(w2, [[0.0, 0.0, 1.5]])
    np.testing.assert_allclose(w1, [[1.0, 0.0, 0.0]])


def test_live_aligner_shared_clock_pairs_exact_samples_in_any_order():
    t, w1, w2 = _pair(n=500)
    a, got = LiveAligner(), []
    i = {1: 0, 2: 0}
    for g in _interleaved(500, np.random.default_rng(3)):
        k = i[g]
        i[g] += 1
        got.append(a.push(g, t[k], (w1 if g == 1 else w2)[k]))
    tt = np.concatenate([x[0] for x in got])
    np.testing.assert_array_equal(tt, t)
    np.testing.assert_array_equal(np.concatenate([x[2] for x in got]), w2)
    np.testing.assert_array_equal(np.concatenate([x[1] for x in got]), w1)


def test_live_aligner_counts_late_unmatched_and_overflow():
    a = LiveAligner(max_gap_s=0.5, max_buffer=4)
    a.push(2, 1.0, [0, 0, 0])
    a.push(1, 0.5, [0, 0, 0])           # before gyro 2's first sample
    a.push(2, 0.9, [0, 0, 0])           # older than gyro 2's last: late
    a.push(2, 2.0, [0, 0, 0])           # a 1 s gap of gyro 2
    assert len(a.push(1, 1.5, [0, 0, 0])[0]) == 0
    assert a.dropped == {"late": 1, "unmatched": 2, "overflow": 0}
    for k in range(10):                 # gyro 2 stalls: gyro 1's buffer stays bounded
        a.push(1, 3.0 + k, [0, 0, 0])
    assert a.buffered[0] == 4 and a.dropped["overflow"] == 6


def test_live_aligner_bad_sample_is_input_error():
    with pytest.raises(InputError, match="expected 1 or 2"):
        LiveAligner().push(3, 0.0, [0, 0, 0])
    with pytest.raises(InputError, match="3 finite rates"):
        LiveAligner().push(1, 0.0, [0, np.nan, 0])


# ---------------------------------------------------------------------------------------------- blocks
@pytest.mark.parametrize("size", [1, 2, 7, 100])
def test_live_blocks_cut_as_block_spans(size):
    rng = np.random.default_rng(size)
    steps = np.where(rng.random(900) < 0.01, 0.5, 0.01)     # a few gaps
    t = np.cumsum(steps)
    lb, got = LiveBlocks(size, 0.05), []
    for k in range(0, len(t), 13):                          # aligned samples arrive in bursts
        got += lb.push(t[k:k + 13], np.zeros((len(t[k:k + 13]), 3)), np.zeros((len(t[k:k + 13]), 3)))
    got += lb.close()
    spans = block_spans(t, size, 0.05)
    assert [(float(b[0][0]), len(b[0])) for b in got] == [(float(t[s]), e - s) for s, e in spans]


# ---------------------------------------------------------------------------------------------- LivePair
@pytest.mark.parametrize("mode", ["fast", "sample"])
def test_live_pair_any_interleaving_equals_batch_tracker(mode):
    t, w1, w2 = _pair(n=3000)
    live = LivePair(seed_s=10.0, mode=mode)
    i = {1: 0, 2: 0}
    events = []
    for g in _interleaved(len(t), np.random.default_rng(7)):
        k = i[g]
        i[g] += 1
        events += live.push(g, t[k], (w1 if g == 1 else w2)[k])
    events += live.close()
    assert events[0]["type"] == "seeded"
    bt = _batch(t, w1, w2, 10.0, mode)
    assert live.tracker.n_samples == bt.n_samples == len(t) - int(np.argmax(t - t[0] >= 10.0)) - 1
    for name in STATE:
        np.testing.assert_allclose(getattr(live.tracker, name), getattr(bt, name), rtol=0, atol=1e-9)
    state = live.state()
    assert state["seeded"] and state["n_samples"] == bt.n_samples
    json.dumps(state)


def test_live_pair_reports_a_step_alarm():
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 120.0, 0.01)
    R = general_rotation(rng, 15.0)
    w1, w2, _ = simulate_drifting_pair(t, R, np.ones(3), np.ones(3), rng=rng)
    from fusion_gyrocal.lie import exp
    w1[6000:] = w1[6000:] @ exp(np.radians([3.0, 0.0, 0.0])).T      # the mount turns by 3 deg at 60 s
    live, events = LivePair(seed_s=20.0), []
    for k in range(len(t)):
        events += live.push(1, t[k], w1[k])
        events += live.push(2, t[k], w2[k])
    events += live.close()
    kinds = [e["type"] for e in events]
    assert "alarm" in kinds
    alarm = next(e for e in events if e["type"] == "alarm")
    assert 60.0 <= alarm["t_detected"] < 70.0


# ---------------------------------------------------------------------------------------------- lines
def test_line_reader_ros2_topic_echo_rows_by_frame_id():
    def row(sec, nsec, frame, w):
        return ",".join([str(sec), str(nsec), frame, "0.0", "0.0", "0.0", "1.0"] + ["0.0"] * 9
                        + [repr(x) for x in w] + ["0.0"] * 3 + ["0.0"] * 9)
    r = LineReader("auto", names=("imu1_link", "imu0_link"))
    s = r.samples(row(12, 500_000_000, "imu0_link", [0.1, 0.2, 0.3]))
    assert s[0][0] == 2 and s[0][1] == pytest.approx(12.5)
    np.testing.assert_array_equal(s[0][2], [0.1, 0.2, 0.3])
    assert r.samples(row(12, 0, "other", [0, 0, 0])) == [] and r.skipped == 1


def test_line_reader_pair_rows_and_a_bad_row_names_its_line():
    r = LineReader(time_scale=1e-3)
    assert r.samples("t,w1x,w1y,w1z,w2x,w2y,w2z") == []
    s = r.samples("1500,1,2,3,4,5,6")
    assert [(g, t) for g, t, _ in s] == [(1, 1.5), (2, 1.5)]
    with pytest.raises(InputError, match="line 3"):
        r.samples("1501,1,2,x,4,5,6")


# ---------------------------------------------------------------------------------------------- gyrocal track
def _write_tagged(path, t, w1, w2):
    with open(path, "w") as f:
        f.write("gyro,t,wx,wy,wz\n")
        for k in range(len(t)):
            for g, w in ((1, w1), (2, w2)):
                f.write(f"{g},{float(t[k])!r},{float(w[k, 0])!r},{float(w[k, 1])!r},{float(w[k, 2])!r}\n")


def _final(path):
    lines = [json.loads(x) for x in Path(path).read_text().splitlines()]
    assert lines[-1]["type"] == "final"
    return lines


@pytest.mark.shared_data
def test_cli_track_mimu_session_equals_batch_tracker(tmp_path):
    p = data_folder("mimu_8imu_array/npz") / "exp_1.npz"
    from fusion_gyrocal.io import read_npz
    imus = read_npz(p)
    n = 6000
    t, w1, w2 = imus[0].t[:n], imus[0].omega[:n], imus[2].omega[:n]
    src = tmp_path / "pair.csv"
    _write_tagged(src, t, w1, w2)
    out = tmp_path / "track.jsonl"
    assert main(["track", str(src), "--seed-s", "30", "-o", str(out)]) == 0
    lines = _final(out)
    final = lines[-1]
    bt = _batch(t, w1, w2, 30.0, "fast")
    assert final["n_samples"] == bt.n_samples
    np.testing.assert_allclose(final["R_1_2"], bt.R_1_2, rtol=0, atol=1e-9)
    for name in ("scale_1", "scale_2", "bias"):
        np.testing.assert_allclose(final[name], getattr(bt, name), rtol=0, atol=1e-9)
    assert lines[0]["type"] == "seeded"


def test_cli_track_seed_file_and_udp_source(tmp_path, capsys):
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.io import write_json
    t, w1, w2 = _pair(n=1500)
    seed = tmp_path / "cal.json"
    write_json(calibrate_pair(w1[:500], w2[:500]), seed)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "udp.jsonl"
    args = ["track", f"udp://127.0.0.1:{port}", "--seed", str(seed), "--idle-timeout", "2", "-o", str(out),
            "--format", "pair"]
    th = threading.Thread(target=main, args=(args,))
    th.start()
    deadline = time.monotonic() + 60
    while True:                        # wait until the command has bound the port
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            break
        finally:
            probe.close()
        assert time.monotonic() < deadline, "gyrocal track never bound its UDP port"
        time.sleep(0.02)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rows = [",".join(repr(float(x)) for x in (t[k], *w1[k], *w2[k])) for k in range(500, 1500)]
    for a in range(0, len(rows), 50):   # 50 lines per datagram
        tx.sendto("\n".join(rows[a:a + 50]).encode(), ("127.0.0.1", port))
        time.sleep(0.002)
    tx.close()
    th.join(60)
    final = _final(out)[-1]
    assert final["aligned"] == 1000 and final["n_samples"] == 1000


def test_cli_track_bad_line_is_one_line_error(tmp_path, capsys):
    src = tmp_path / "bad.csv"
    src.write_text("1,0.0,1,2,3\n2,0.0,1,2,3\n1,0.01,1,zz,3\n")
    assert main(["track", str(src)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("gyrocal: error: line 3") and "Traceback" not in err


# ---------------------------------------------------------------------------------------------- ROS 2 node
def test_ros2_node_logic_publishes_states_and_equals_batch():
    mod = load_example("ros2_node")    # rclpy is imported only when the node runs, not here
    t, w1, w2 = _pair(n=2500)
    published = []
    logic = mod.GyroPairNodeLogic(publish=published.append, seed_s=10.0, every_s=1.0)

    def msg(tk, w):
        sec = int(tk)
        return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=int(round((tk - sec) * 1e9)))),
                               angular_velocity=SimpleNamespace(x=w[0], y=w[1], z=w[2]))
    for k in range(len(t)):
        logic.on_imu(2, msg(t[k], w2[k]))
        logic.on_imu(1, msg(t[k], w1[k]))
    logic.finish()
    kinds = [json.loads(p)["type"] for p in published]
    assert kinds[0] == "seeded" and kinds[-1] == "final" and kinds.count("state") >= 10
    tn = np.array([int(x) + round((x - int(x)) * 1e9) * 1e-9 for x in t])   # the stamps' round trip
    bt = _batch(tn, w1, w2, 10.0, "fast")
    final = json.loads(published[-1])
    np.testing.assert_allclose(final["R_1_2"], bt.R_1_2, rtol=0, atol=1e-9)


def test_cli_track_follows_a_growing_file(tmp_path):
    t, w1, w2 = _pair(n=2000)
    src = tmp_path / "growing.csv"
    rows = [",".join(repr(float(x)) for x in (t[k], *w1[k], *w2[k])) + "\n" for k in range(len(t))]
    src.write_text("".join(rows[:1200]) + rows[1200][:10])        # the last line still being written
    out = tmp_path / "follow.jsonl"
    th = threading.Thread(target=main, args=(["track", str(src), "--follow", "--idle-timeout", "3", "--seed-s", "5",
                                              "-o", str(out)],))
    th.start()
    time.sleep(0.5)
    with open(src, "a") as f:
        f.write(rows[1200][10:])
        f.writelines(rows[1201:])
    th.join(120)
    final = _final(out)[-1]
    assert final["aligned"] == 2000
    bt = _batch(t, w1, w2, 5.0, "fast")
    np.testing.assert_allclose(final["R_1_2"], bt.R_1_2, rtol=0, atol=1e-9)


def test_cli_track_zmq_without_pyzmq_says_so(capsys):
    try:
        import zmq  # noqa: F401
        pytest.skip("pyzmq is installed: the zmq source is available")
    except ImportError:
        pass
    assert main(["track", "zmq+tcp://127.0.0.1:5999"]) == 1
    err = capsys.readouterr().err
    assert "a ZeroMQ source needs pyzmq" in err and "Traceback" not in err


def test_cli_track_zmq_source(tmp_path):
    zmq = pytest.importorskip("zmq")
    t, w1, w2 = _pair(n=1500)
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    out = tmp_path / "zmq.jsonl"
    th = threading.Thread(target=main, args=(["track", f"zmq+tcp://127.0.0.1:{port}", "--format", "pair",
                                              "--seed-s", "5", "--idle-timeout", "2", "-o", str(out)],))
    th.start()
    time.sleep(1.0)                    # a SUB socket misses what is published before it connects
    for k in range(len(t)):
        pub.send((",".join(repr(float(x)) for x in (t[k], *w1[k], *w2[k]))).encode())
    th.join(60)
    pub.close(0)
    assert _final(out)[-1]["aligned"] == len(t)


def test_live_pair_refuses_tracker_options_beside_a_tracker():
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.errors import OptionError
    t, w1, w2 = _pair(n=600)
    tracker = GyroPairTracker(calibrate_pair(w1, w2), t0=t[-1])
    with pytest.raises(OptionError, match="cusum_threshold: tracker options configure"):
        LivePair(tracker=tracker, cusum_threshold=9.0)
    with pytest.raises(InputError, match="expected a GyroPairTracker, got dict"):
        LivePair(tracker={})


def test_live_pair_seed_waits_for_motion():
    t, w1, w2 = _pair(n=4000)
    w1 = w1.copy()
    w2 = w2.copy()
    rng = np.random.default_rng(9)
    w1[:1500] = 1e-3 * rng.normal(size=(1500, 3))             # 15 s at rest first: nothing to seed from
    w2[:1500] = 1e-3 * rng.normal(size=(1500, 3))
    live, events = LivePair(seed_s=10.0), []
    for k in range(len(t)):
        events += live.push(1, t[k], w1[k])
        events += live.push(2, t[k], w2[k])
    events += live.close()
    kinds = [e["type"] for e in events]
    assert kinds[0] == "seed_failed" and "seeded" in kinds
    seeded = next(e for e in events if e["type"] == "seeded")
    assert seeded["t"] > t[1500] and live.n_aligned == len(t)
    assert live.tracker.n_samples == int(np.sum(t > seeded["t"]))
