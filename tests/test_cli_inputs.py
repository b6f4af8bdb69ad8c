"""The command line under bad input, as a stranger types it (issue 12, "Input files"):
`hil drive --params` and `--node-id`, and output piped into `head`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

HIL = str(Path(sys.executable).with_name("hil"))


def _drive(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([HIL, "drive", "--can", "virtual:cli-inputs", *args],
                          capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("content, name, needle", [
    (None, "missing.yaml", "missing.yaml:0: (file): cannot read"),
    ("P1.042: [1, 2\n", "broken.yaml", "broken.yaml:2: (yaml)"),
    ("P1.042: fast\n", "word.yaml", "word.yaml:1: P1.042: 'fast' is not an integer"),
    ("- P1.042\n", "list.yaml", "expected a mapping"),
    ("{nope", "bad.json", "bad.json: not JSON"),
    ("P1.042: -5\n", "range.yaml", "P1.042"),
])
def test_drive_params_file_errors_name_the_file(tmp_path, content, name, needle):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    r = _drive("--params", str(path))
    assert r.returncode == 2, r.stdout + r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("value", ["0", "128", "999", "-1", "x"])
def test_node_id_outside_1_127_is_a_usage_error(value):
    r = _drive("--node-id", value)
    assert r.returncode == 2 and "--node-id" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("value", ["0", "128", "247"])
def test_station_outside_p3_000s_range_is_a_usage_error(value):
    """P3.000 (station and node id) is 01h-7Fh (L10497): 128-247, a Modbus station elsewhere,
    is none the A3 can be set to."""
    r = _drive("--station", value)
    assert r.returncode == 2 and "--station" in r.stderr, r.stderr


@pytest.mark.parametrize("argv", [["inspect", "{mcap}"], ["run", "--check"]])
def test_output_into_head_stops_quietly(tmp_path, argv):
    """`hil inspect x.mcap | head -1` and `hil run --check | head -1`: no BrokenPipeError."""
    from hil.record.recorder import Recorder

    mcap = tmp_path / "x.mcap"
    with Recorder(mcap) as rec:
        for i in range(200):
            rec.log("info", f"line {i}", name="test")
    cmd = [HIL, *(a.format(mcap=mcap) for a in argv)]
    # the reader is gone before the command writes its first line (as `head` is, soon)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout is not None
    p.stdout.close()
    _, err = p.communicate(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert p.returncode == 141, (p.returncode, err)


@pytest.mark.parametrize(("flag", "url", "needle"), [
    ("--rs485", "pty:/tmp/hil-cli-inputs?baud=abc", "baud='abc' is not an integer"),
    ("--rs485", "pty:?baud=115200", "pty: needs a target"),
    ("--dio", "nope:x", "scheme 'nope' is not a dio transport"),
])
def test_drive_malformed_transport_url_is_bad_input(flag, url, needle):
    """A URL that cannot be parsed is a usage error (2), named; one that parses but cannot
    be opened stays exit 1 (README exit-code table)."""
    r = subprocess.run([HIL, "drive", flag, url], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2, r.stdout + r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("fmt", ["candump", "asc"])
def test_export_into_head_stops_quietly(tmp_path, fmt):
    """README: "any | 141 | its output pipe closed early ... it stops quietly": `hil export
    x.mcap -o - | head -1` too (it said "cannot write -: Broken pipe", exit 2)."""
    import can

    from hil.record.recorder import Recorder

    mcap = tmp_path / "x.mcap"
    with Recorder(mcap) as rec:
        for i in range(20000):
            rec.can("can0", can.Message(arbitration_id=0x181, data=bytes([i % 256] * 8),
                                        is_extended_id=False), "rx", i * 100_000)
    p = subprocess.Popen([HIL, "export", str(mcap), "-o", "-", "-f", fmt],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout is not None
    p.stdout.close()
    _, err = p.communicate(timeout=60)
    assert "Traceback" not in err and "Broken pipe" not in err, err
    assert p.returncode == 141, (p.returncode, err)


def test_messages_name_the_options_the_user_gave(tmp_path):
    """`hil diff a b -o z.json` has no --json; `hil export -o x.mf4` without asammdf names
    the file it was asked for."""
    import importlib.util

    from hil.record.recorder import Recorder

    mcap = tmp_path / "a.mcap"
    with Recorder(mcap) as rec:
        rec.log("info", "x", name="test")
    r = subprocess.run([HIL, "diff", str(mcap), str(mcap), "-o", str(tmp_path / "z.json")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--json" not in r.stderr and "(-o" in r.stderr, r.stderr
    if importlib.util.find_spec("asammdf") is None:
        r = subprocess.run([HIL, "export", str(mcap), "-o", str(tmp_path / "x.mf4")],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "x.mf4: MF4 needs the asammdf package" in r.stderr
