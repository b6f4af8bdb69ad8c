"""SIGTERM stops `hil run` as Ctrl-C does, outside a plan too (helper-140: between plans and
while the run's files were written it killed the process, exit -15, leaving no junit.xml or
index.html). Each run is a subprocess: on the old code the signal kills what receives it."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.virtual_time

DRIVER = textwrap.dedent("""
    import os, signal, sys
    import hil.plan.cli as cli
    where = sys.argv[1]
    real = getattr(cli, where)

    def patched(*a, **kw):
        os.kill(os.getpid(), signal.SIGTERM)  # the handler runs here, at once
        return real(*a, **kw)

    setattr(cli, where, patched)
    from hil.cli import main
    sys.exit(main(["run", "emgs", "--out", sys.argv[2], "-q"]))
""")


@pytest.mark.parametrize("where", ["run_plans", "write_junit"])
def test_sigterm_outside_a_plan_is_exit_130_with_the_runs_files(tmp_path, where) -> None:
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-c", DRIVER, where, str(out)],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 130, (run.returncode, run.stderr[-2000:])
    assert "hil: interrupted" in run.stderr and "Traceback" not in run.stderr
    assert (out / "junit.xml").exists() and (out / "index.html").exists()
    if where == "write_junit":  # the plan had run: its result is in the run's files
        assert "emgs" in (out / "index.html").read_text(encoding="utf-8")
