"""One stderr line per error: messages folded, errors without a message named, warnings captured."""

import dataclasses
import warnings

import numpy as np
import pytest

from fusion_gyrocal import FormatError
from fusion_gyrocal.cli import main
from fusion_gyrocal.cli.app import one_line

OOM = ("the recording is too large for this machine or its timestamps are corrupt (a huge span or gap makes a huge "
       "time grid)")


def _demo_run(monkeypatch, body):
    def run(args):
        body()
        print("result")
        return 0

    monkeypatch.setattr("fusion_gyrocal.cli.demo.run", run)


def _raise(exc):
    def body():
        raise exc
    return body


@pytest.mark.parametrize("exc, line", [
    (MemoryError(), f"gyrocal: error: out of memory (MemoryError): {OOM}\n"),
    (MemoryError("Unable to allocate 8.00 PiB for an array with shape (10**15,) and data type float64"),
     f"gyrocal: error: out of memory (MemoryError: Unable to allocate 8.00 PiB for an array with shape (10**15,) and "
     f"data type float64): {OOM}\n"),
    (OSError(), "gyrocal: error: OSError\n"),
    (RuntimeError(), "gyrocal: internal error: RuntimeError (rerun with --debug for the traceback)\n"),
])
def test_main_error_without_message_is_named_by_its_type(monkeypatch, capsys, exc, line):
    _demo_run(monkeypatch, _raise(exc))
    assert main(["demo"]) == (70 if isinstance(exc, RuntimeError) else 1)
    assert capsys.readouterr().err == line


def test_main_numpy_array_memory_error_reads_as_out_of_memory(monkeypatch, capsys):
    def body():
        np.ones((10**6, 10**6, 10**4))   # more than any address space: numpy's _ArrayMemoryError

    _demo_run(monkeypatch, body)
    assert main(["demo"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("gyrocal: error: out of memory (MemoryError: Unable to allocate ") and err.count("\n") == 1


def test_main_numpy_runtime_warning_prints_nothing_but_the_result(monkeypatch, capsys):
    def body():
        with np.errstate(all="warn"):
            np.log(np.zeros(3))                     # RuntimeWarning: divide by zero
            np.array([np.inf]) - np.array([np.inf])  # RuntimeWarning: invalid value

    _demo_run(monkeypatch, body)
    assert main(["demo"]) == 0
    out = capsys.readouterr()
    assert out.out == "result\n" and out.err == ""
    assert main(["--debug", "demo"]) == 0     # --debug shows them, one line each
    err = capsys.readouterr().err.splitlines()
    assert err == ["gyrocal: debug: warning: divide by zero encountered in log (RuntimeWarning)",
                   "gyrocal: debug: warning: invalid value encountered in subtract (RuntimeWarning)"]


def test_main_other_warning_is_one_line(monkeypatch, capsys):
    _demo_run(monkeypatch, lambda: warnings.warn("first line\n   second line", UserWarning))
    assert main(["demo"]) == 0
    out = capsys.readouterr()
    assert out.out == "result\n" and out.err == "gyrocal: warning: first line second line (UserWarning)\n"


def test_main_yaml_parser_message_is_one_line_without_its_markers(monkeypatch, capsys):
    yaml_text = ('Could not load YAML from m/metadata.yaml: while parsing a flow sequence\n'
                 '  in "<unicode string>", line 4, column 10:\n        files: [a: b\n             ^ (line: 4)\n'
                 "expected ',' or ']', but got '<stream end>'\n  in \"<unicode string>\", line 6, column 1:\n"
                 "    \n    ^ (line: 6)")
    _demo_run(monkeypatch, _raise(FormatError(yaml_text)))
    assert main(["demo"]) == 1
    assert capsys.readouterr().err == (
        'gyrocal: error: Could not load YAML from m/metadata.yaml: while parsing a flow sequence in "<unicode '
        'string>", line 4, column 10: files: [a: b expected \',\' or \']\', but got \'<stream end>\' in '
        '"<unicode string>", line 6, column 1:\n')


def test_main_broken_ros2_metadata_yaml_is_one_line(tmp_path, capsys):
    pytest.importorskip("rosbags")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n  files: [a: b\n   - x\n")
    (bag / "bag_0.db3").write_bytes(b"")
    assert main(["calibrate", str(bag), "--topic1", "/a", "--topic2", "/b"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"gyrocal: error: {bag}: could not read the bag: ") and err.count("\n") == 1
    assert "^" not in err and "  " not in err


def test_one_line_folds_lines_and_blanks():
    assert one_line("a\n  b   c\n\n   ^\nd ^ e") == "a b c d ^ e"


def test_monte_carlo_worker_warnings_are_returned_to_the_parent(monkeypatch):
    from fusion_gyrocal.evaluate import montecarlo
    from fusion_gyrocal.evaluate.registry import REGISTRY
    from fusion_gyrocal.options import Options

    real = REGISTRY["rotation_only"].run

    def run(w1, w2, rate_hz, options):
        warnings.warn("from a worker", RuntimeWarning)
        return real(w1, w2, rate_hz, options)

    monkeypatch.setitem(REGISTRY, "rotation_only", dataclasses.replace(REGISTRY["rotation_only"], run=run))
    record, caught = montecarlo._pool_task(("nominal", 1.0, None), (0, 0), ("rotation_only",), Options())
    assert record.estimates[0].ok
    assert ("from a worker", RuntimeWarning) in [(m, c) for m, c, _, _ in caught]


def test_run_command_closed_pipe_is_quiet(capsys):
    """A reader that closed the pipe (``gyrocal sessions ... | head``) ends the command with 141 and no message."""
    import argparse
    import subprocess
    import sys

    from fusion_gyrocal.cli.app import EXIT_PIPE_CLOSED, run_command

    def writes_to_a_closed_pipe(args):
        raise BrokenPipeError(32, "Broken pipe")

    assert run_command(writes_to_a_closed_pipe, argparse.Namespace()) == EXIT_PIPE_CLOSED
    assert capsys.readouterr().err == ""
    code = ("import sys; from fusion_gyrocal.cli.app import run_command\n"
            "def run(args):\n"
            "    for _ in range(200000):\n"
            "        print('x' * 60)\n"
            "sys.exit(run_command(run, None))\n")
    writer = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    writer.stdout.read(100)
    writer.stdout.close()                     # the reader goes away, as head does
    err = writer.stderr.read().decode()
    assert writer.wait(timeout=60) == EXIT_PIPE_CLOSED
    assert err == ""
