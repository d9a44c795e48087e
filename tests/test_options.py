import argparse
import dataclasses
import math

import numpy as np
import pytest

from fusion_gyrocal import OptionError, calibrate_pair
from fusion_gyrocal.cli import main
from fusion_gyrocal.core.solve import solve
from fusion_gyrocal.evaluate.sim import simulate_pair
from fusion_gyrocal.io import ImuStream, write_csv
from fusion_gyrocal.options import FLAGS, NAMES, Options, add_option_arguments, options_from_args

# ONE option set, given once as flags, as an Options, as keywords: every route must hand it to solve unchanged
REACH = {"min_snr": 3.5, "parallel_tol_deg": 7.0, "noise_std": (1.7e-3, 1.8e-3)}
REACH_FLAGS = ["--min-snr", "3.5", "--parallel-tol", "7", "--noise-std", "0.0017", "0.0018"]

# every option with a flag: (argv, the keywords it must equal); at 100 Hz for --bias-window
FLAG_EXAMPLES = {
    "method": (["--method", "direct"], {"method": "direct"}),
    "covariance": (["--covariance", "model"], {"covariance": "model"}),
    "noise_model": (["--noise-model", "residual"], {"noise_model": "residual"}),
    "noise_std": (["--noise-std", "0.001", "0.002"], {"noise_std": (0.001, 0.002)}),
    "gauge": (["--gauge", "fixed"], {"gauge": "fixed"}),
    "scale_prior_std": (["--scale-prior", "0.01"], {"scale_prior_std": 0.01}),
    "parallel_tol_deg": (["--parallel-tol", "3"], {"parallel_tol_deg": 3.0}),
    "skew_std": (["--skew-std", "0.002"], {"skew_std": 0.002}),
    "linear_map": (["--linear-map", "rigid"], {"linear_map": "rigid"}),
    "cross_axis_std": (["--cross-axis-std", "0.02"], {"cross_axis_std": 0.02}),
    "timing_model": (["--timing-model", "off"], {"timing_model": "off"}),
    "robust_weights": (["--robust-weights", "auto"], {"robust_weights": "auto"}),
    "min_snr": (["--min-snr", "20"], {"min_snr": 20.0}),
    "on_not_rigid": (["--allow-not-rigid"], {"on_not_rigid": "flag"}),
    "time_offset_s": (["--offset", "-0.25"], {"time_offset_s": -0.25}),
    "max_offset_s": (["--max-offset", "2"], {"max_offset_s": 2.0}),
    "rate_hz": (["--rate", "200"], {"rate_hz": 200.0}),
    "saturation_limit": (["--saturation-limit", "30", "35"], {"saturation_limit": (30.0, 35.0)}),
    "bias_window": (["--bias-window", "2.5"], {"bias_window": 250}),
    "bias_walk_std": (["--bias-walk", "1e-5", "--noise-std", "0.001"], {"bias_walk_std": 1e-5, "noise_std": 0.001}),
    "flex_rejection": (["--no-flex-rejection"], {"flex_rejection": False}),
    "max_rate": (["--max-rate", "5"], {"max_rate": 5.0}),
    "max_plausible_rate": (["--max-plausible-rate", "150"], {"max_plausible_rate": 150.0}),
}

# every option: values its check must refuse
BAD_VALUES = {
    "method": ["fast", 1, None, True],
    "covariance": ["sandwich", 1, None],
    "noise_model": ["allan", 0, None],
    "noise_std": [0, -1e-3, math.nan, math.inf, [1.0, 2.0, 3.0], [], "x"],
    "gauge": ["free", 1, None],
    "scale_prior_std": [0, -1.0, math.nan, "x"],
    "parallel_tol_deg": [0, -1.0, 90, 95.0, math.nan, None],
    "intrinsics_1": [np.eye(2), [[1, 0, 0], [1, 1, 0], [0, 0, 1]], np.diag([1.0, 0.0, 1.0]), [[1, 2], [3]], "abc",
                     np.full((3, 3), math.nan)],
    "intrinsics_2": [np.zeros((3, 3))],
    "skew_std": [-0.1, math.nan, [1.0, 2.0, 3.0], None],
    "linear_map": ["affine", 1, None, True],
    "cross_axis_std": [0, -0.01, math.nan, None],
    "timing_model": ["sawtooth", 1, None, True],
    "robust_weights": ["on", 1, None, True],
    "min_snr": [0, -1.0, math.inf],
    "max_unexplained": [-0.1, 1.5, math.nan],
    "on_not_rigid": ["ignore", True],
    "target_snr": [0, -1.0],
    "time_offset_s": [math.nan, math.inf, "x"],
    "max_offset_s": [0, -1.0, math.inf],
    "rate_hz": [0, -100.0, math.nan],
    "saturation_limit": [0, -1.0, [1.0, 2.0, 3.0]],
    "bias_window": [1, 0, -5, 2.5, True, math.nan, "3.5"],
    "bias_walk_std": [0, -1.0, [1.0, 2.0, 3.0]],
    "flex_rejection": ["yes", 1, 0, None],
    "flex_margin": [-1, 1.5, True, math.nan],
    "min_kept_energy": [-0.1, 2.0],
    "max_rate": [0, -1.0],
    "max_plausible_rate": [0, -1.0, math.nan, None],
    "gyros": [1, 0, 2.5, True, None],
}


def _parse(argv, **kw):
    parser = argparse.ArgumentParser()
    add_option_arguments(parser, **kw)
    return parser.parse_args(argv)


def test_options_from_args_every_flag_parses_to_the_keyword():
    assert set(FLAG_EXAMPLES) == set(FLAGS)
    for name, (argv, keywords) in FLAG_EXAMPLES.items():
        expected = Options(**keywords)
        assert getattr(expected, name) != getattr(Options(), name), name  # the example is not the default
        assert options_from_args(_parse(argv), rate_hz=100.0) == expected, name


def test_options_from_args_without_flags_is_the_default():
    assert options_from_args(_parse([]), rate_hz=100.0) == Options()


def test_options_from_args_keywords_win_over_flags():
    opts = options_from_args(_parse(["--method", "direct", "--min-snr", "20"]), method="ml")
    assert (opts.method, opts.min_snr) == ("ml", 20.0)


def test_options_from_args_bias_window_uses_rate_flag_when_given():
    assert options_from_args(_parse(["--bias-window", "2", "--rate", "50"]), rate_hz=200.0).bias_window == 100
    assert options_from_args(_parse(["--bias-window", "2"]), rate_hz=200.0).bias_window == 400


@pytest.mark.parametrize("argv, match", [
    (["--bias-window", "-5"], r"^bias_window .*expected a positive number, got -5.0"),
    (["--bias-window", "0"], r"^bias_window .*expected a positive number"),
    (["--bias-window", "nan"], r"^bias_window .*expected a finite number"),
    (["--bias-window", "0.001"], r"^bias_window: expected a window of at least 2 samples \(0.02 s at 100 Hz\)"),
    (["--skew-std", "nan"], r"^skew_std: expected a finite number"),
    (["--skew-std", "-0.1"], r"^skew_std: expected a number >= 0"),
    (["--noise-std", "1", "2", "3"], r"^noise_std: expected one value or one per gyro \(2\), got 3 values"),
    (["--parallel-tol", "90"], r"^parallel_tol_deg: expected an angle in \(0, 90\) deg"),
    (["--rate", "0", "--bias-window", "1"], r"^rate_hz: expected a positive number"),
])
def test_options_from_args_bad_flag_raises_option_error_naming_the_option(argv, match):
    with pytest.raises(OptionError, match=match):
        options_from_args(_parse(argv), rate_hz=100.0)


def test_options_from_args_bias_window_without_rate_raises_option_error():
    with pytest.raises(OptionError, match="^bias_window: --bias-window is in seconds and needs the sample rate"):
        options_from_args(_parse(["--bias-window", "2"]))


def test_add_option_arguments_names_and_exclude_select_flags():
    args = _parse([], names=("time_offset_s", "rate_hz"))
    assert sorted(k for k in vars(args)) == ["option_rate_hz", "option_time_offset_s"]
    args = _parse([], exclude=("bias_window",))
    assert "option_bias_window" not in vars(args) and "option_method" in vars(args)
    with pytest.raises(SystemExit):
        _parse(["--method", "direct"], names=("rate_hz",))
    with pytest.raises(OptionError, match="intrinsics_1"):
        _parse([], names=("intrinsics_1",))  # no flag


def test_options_bad_value_raises_option_error_naming_the_option():
    assert set(BAD_VALUES) == set(NAMES)
    for name, values in BAD_VALUES.items():
        for v in values:
            with pytest.raises(OptionError, match=rf"^{name}: expected ") as e:
                Options(**{name: v})
            assert "\n" not in str(e.value)


@pytest.mark.parametrize("keywords, match", [
    ({"bias_walk_std": 1e-5}, "^bias_walk_std: the drifting-bias filter needs noise_std"),
    ({"bias_walk_std": 1e-5, "noise_std": 1e-3, "bias_window": 100}, "^bias_window and bias_walk_std: expected one"),
    ({"scale_prior_std": 0.01, "method": "direct"}, "^scale_prior_std: expected method='ml'"),
    ({"no_such_option": 1}, r"^unknown option\(s\) \['no_such_option'\]"),
])
def test_options_of_inconsistent_or_unknown_raises_option_error(keywords, match):
    with pytest.raises(OptionError, match=match):
        Options.of(**keywords)


def test_options_good_values_are_normalised():
    o = Options(noise_std=np.array([1e-3, 2e-3]), bias_window=50.0, flex_margin="3", intrinsics_1=np.eye(3),
                parallel_tol_deg=89.9)
    assert o.noise_std == (1e-3, 2e-3) and o.bias_window == 50 and o.flex_margin == 3
    assert o.intrinsics_1 == tuple(map(tuple, np.eye(3).tolist()))
    assert dataclasses.replace(o, method="direct").noise_std == (1e-3, 2e-3)


@pytest.fixture
def solve_spy(monkeypatch):
    """The Options every solve of the pipeline and of the chunked fleet received (the real solve still runs)."""
    seen = []

    def spy(moments, options=None, **keywords):
        seen.append(options)
        return solve(moments, options, **keywords)

    monkeypatch.setattr("fusion_gyrocal.pipeline.pipeline.solve", spy)
    monkeypatch.setattr("fusion_gyrocal.distributed.fleet.solve", spy)
    return seen


def _assert_reached(seen, expected=None):
    assert seen, "solve was not called"
    for o in seen:
        assert isinstance(o, Options)
        if expected is not None:
            assert o is expected
        assert {k: getattr(o, k) for k in REACH} == REACH
        assert o == Options(**REACH)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("reach")
    sim = simulate_pair(rng=3, n=4000)
    for name, w in (("gyro1.csv", sim.omega_1), ("gyro2.csv", sim.omega_2)):
        write_csv(ImuStream(sim.t, w), d / name)
    return d, sim


def test_options_reach_solve_unchanged_from_calibrate_pair(solve_spy, recording):
    _, sim = recording
    opts = Options(**REACH)
    calibrate_pair(sim.omega_1, sim.omega_2, options=opts)
    _assert_reached(solve_spy, opts)
    solve_spy.clear()
    calibrate_pair(sim.omega_1, sim.omega_2, **REACH)
    _assert_reached(solve_spy)


def test_options_reach_solve_unchanged_from_the_command_line(solve_spy, recording, tmp_path):
    d, _ = recording
    assert main(["calibrate", str(d / "gyro1.csv"), str(d / "gyro2.csv"), *REACH_FLAGS,
                 "-o", str(tmp_path / "c.json")]) == 0
    _assert_reached(solve_spy)


def test_options_reach_solve_unchanged_from_the_fleet(solve_spy, recording, tmp_path):
    pytest.importorskip("pandas")
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    pytest.importorskip("dask")
    from fusion_gyrocal.distributed.fleet import run_fleet

    d, sim = recording
    opts = Options(**REACH)
    df = run_fleet([d], options=opts)  # a gyro1/gyro2 device, threads in this process
    assert df["ok"].tolist() == [True]
    _assert_reached(solve_spy, opts)
    solve_spy.clear()
    assert main(["fleet", str(d), "--workers", "0", "-o", str(tmp_path / "f.parquet"), *REACH_FLAGS]) == 0
    _assert_reached(solve_spy)
    solve_spy.clear()
    data = {"t": sim.t, **{f"w{g}{ax}": w[:, a] for g, w in (("1", sim.omega_1), ("2", sim.omega_2))
                             for a, ax in enumerate("xyz")}}
    pq.write_table(pa.table(data), tmp_path / "log.parquet", row_group_size=1000)
    df = run_fleet([tmp_path / "log.parquet"], chunked=True, options=opts)  # the chunked path solves from moments
    assert df["ok"].tolist() == [True]
    _assert_reached(solve_spy, opts)


# ------------------------------------------------------------------------------------------ what applies where
def test_options_require_refuses_what_the_consumer_does_not_apply():
    from fusion_gyrocal.options import CONSUMERS, applying_to

    for consumer in CONSUMERS:
        accepted = set(applying_to(consumer))
        for name, (_, keywords) in FLAG_EXAMPLES.items():
            o = Options(**keywords)
            if set(o.to_dict()) <= accepted:
                assert o.require(consumer) is o
            else:
                with pytest.raises(OptionError, match=rf"^who: {CONSUMERS[consumer]} and cannot apply \[.*'{name}'"):
                    o.require(consumer, "who")
    assert Options().require("moments") == Options()


def test_options_applies_to_moments_is_what_solve_reads():
    from fusion_gyrocal.options import applying_to

    assert set(applying_to("moments")) == {"method", "noise_std", "gauge", "scale_prior_std", "parallel_tol_deg",
                                           "intrinsics_1", "intrinsics_2", "skew_std", "linear_map", "cross_axis_std",
                                           "covariance", "min_snr", "max_unexplained", "on_not_rigid", "target_snr"}
    assert set(applying_to("pair")) == set(NAMES) - {"gyros"}
    assert set(applying_to("array")) < set(applying_to("streams"))


def test_options_gyros_takes_one_or_n_per_gyro_values():
    o = Options(gyros=3, noise_std=[1e-3, 2e-3, 3e-3], saturation_limit=30.0)
    assert o.noise_std == (1e-3, 2e-3, 3e-3) and o.saturation_limit == (30.0,) * 3 and o.skew_std == (0.0,) * 3
    assert o.to_dict() == {"noise_std": (1e-3, 2e-3, 3e-3), "saturation_limit": (30.0,) * 3, "gyros": 3}
    assert Options.of(None, gyros=4, noise_std=1e-3).noise_std == (1e-3,) * 4
    assert Options(gauge="fixed").for_gyros(3) == Options(gauge="fixed", gyros=3)
    with pytest.raises(OptionError, match=r"^noise_std: expected one value or one per gyro \(3\), got 2 values"):
        Options(gyros=3, noise_std=[1e-3, 2e-3])
    with pytest.raises(OptionError, match=r"^noise_std: given for 2 gyros, expected values for 3 gyros"):
        Options(noise_std=1e-3).for_gyros(3)
    with pytest.raises(OptionError, match=r"^pair: calibrates two gyros from samples and cannot apply \['gyros'\]"):
        Options(gyros=3).replace(noise_std=1e-3).require("pair")


def test_add_option_arguments_consumer_selects_its_flags():
    args = _parse([], consumer="recordings")
    assert sorted(vars(args)) == sorted(f"option_{n}" for n in ("time_offset_s", "max_offset_s", "rate_hz",
                                                                 "saturation_limit", "max_rate"))
    assert sorted(vars(_parse([], consumer="pair"))) == sorted(f"option_{n}" for n in FLAGS)
