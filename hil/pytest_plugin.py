"""pytest plugin `hil` (entry point `pytest11`): benches, drives and recordings as fixtures.

    pytest -m hil                          # the virtual bench (built in)
    pytest -m hil --hil-bench bench.yaml   # a real bench

Marker `hil`: the test uses a bench. Fixtures:

* `hil_bench`    the loaded bench file (session scope; `--hil-bench`, default: virtual)
* `hil_recorder` a `Recorder` writing `<hil-out>/<test id>.mcap`; its path is attached to the
                 JUnit XML as the property `hil_recording`
* `hil_session`  the bench's resources opened for this test (virtual drives started); on
                 teardown the bench is driven to its declared safe state, and that is recorded
* `hil_drive`    the default drive of the session (`DriveIO`: DI/DO functions, parameters,
                 CiA 402 driver)
* `hil_run_plan` run a plan file by name or path through the same runner as `hil run`
* `hil_check`    check a timing spec on this test's recording so far; a failing window
                 raises `TimingFailure` whose message lists every violated window
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest


class TimingFailure(AssertionError):
    """A timing spec judged on a recording did not pass (message: one line per window)."""


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hil", "hardware-in-the-loop benches")
    group.addoption(
        "--hil-bench",
        action="store",
        default=None,
        metavar="FILE",
        help="bench file for tests marked `hil` (default: the built-in virtual bench)",
    )
    group.addoption(
        "--hil-out",
        action="store",
        default=None,
        metavar="DIR",
        help="where per-test recordings and plan reports go (default: reports/pytest)",
    )


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "hil: runs against a bench (virtual by default)")
    # Per-test properties (the recording path) need the xunit1 JUnit family; keep an
    # explicit `junit_family` setting of the project if it has one.
    with warnings.catch_warnings():  # inicfg: the only way to set a default before junitxml
        warnings.simplefilter("ignore")  # reads it (deprecated for pytest 10)
        if "junit_family" not in config.inicfg:
            config.inicfg["junit_family"] = "xunit1"


def _out_dir(config: pytest.Config) -> Path:
    out = config.getoption("--hil-out") or Path(str(config.rootpath)) / "reports" / "pytest"
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _safe_name(nodeid: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid).strip("_")[:150]


@pytest.fixture(scope="session")
def hil_bench(pytestconfig: pytest.Config) -> Any:
    """The bench of this pytest run (`--hil-bench FILE`, default: the virtual bench)."""
    from hil.plan.bench import load_bench

    return load_bench(pytestconfig.getoption("--hil-bench"))


@pytest.fixture
def hil_recorder(request: pytest.FixtureRequest, record_property: Callable) -> Iterator[Any]:
    """One MCAP recording per test, attached to the JUnit XML as `hil_recording`."""
    from hil.record.recorder import Recorder

    path = _out_dir(request.config) / f"{_safe_name(request.node.nodeid)}.mcap"
    record_property("hil_recording", str(path))
    rec = Recorder(path, metadata={"pytest_nodeid": request.node.nodeid})
    yield rec
    rec.close()


@pytest.fixture
def hil_session(hil_bench: Any, hil_recorder: Any) -> Iterator[Any]:
    """Bench resources for one test; the bench goes to its safe state afterwards."""
    from hil.plan.safety import go_safe
    from hil.plan.session import open_session

    session = open_session(hil_bench, hil_recorder)
    try:
        session.idle()
        yield session
    finally:
        try:
            go_safe(session, "end of test", hil_recorder)
        finally:
            session.close()


@pytest.fixture
def hil_drive(hil_session: Any) -> Any:
    """The bench's default drive (`hil.plan.session.DriveIO`)."""
    return hil_session.drive(None)


@pytest.fixture
def hil_run_plan(
    hil_bench: Any, request: pytest.FixtureRequest, record_property: Callable
) -> Callable[[str | Path], Any]:
    """Run a plan (name or path) on the bench; returns the `PlanResult`."""
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan

    def run(plan: str | Path) -> Any:
        path = Path(plan)
        if not path.exists():
            path = find_plans([str(plan)])[0]
        result = run_plan(load_plan(path), hil_bench, _out_dir(request.config))
        record_property("hil_recording", result.recording)
        return result

    return run


@pytest.fixture
def hil_check(hil_recorder: Any) -> Callable[..., list]:
    """Check a shipped timing spec (id or path) on this test's recording so far."""
    from hil.paths import fixture
    from hil.timing.checker import check
    from hil.timing.source import RecordingSource
    from hil.timing.spec import load_spec

    def run(spec: str | Path, *, binding: dict | None = None, allow_inconclusive: bool = False,
            **kw: Any) -> list:
        path = Path(spec)
        if not path.exists():
            path = fixture("timing", f"{spec}.yaml")
        hil_recorder.flush()
        verdicts = check(load_spec(path), RecordingSource(hil_recorder.path), binding=binding,
                         **kw)
        bad = [v for v in verdicts if v.status == "fail"
               or (v.status == "inconclusive" and not allow_inconclusive)]
        if bad:
            lines = [f"{v.spec}: {v.constraint}: {v.status.upper()}: {v.message}" for v in bad]
            raise TimingFailure("timing spec violated:\n  " + "\n  ".join(lines))
        return verdicts

    return run


def explain(result: Any) -> str:
    """A plan result as lines a test failure can show: failing steps and verdicts."""
    lines = [f"plan {result.plan}: {result.status} (recording {result.recording})"]
    for step in result.steps:
        if step.status not in ("pass", "skipped"):
            lines.append(f"  step {step.index} {step.label}: {step.status}: {step.message}")
        for v in step.verdicts:
            if v.get("status") != "pass":
                lines.append(f"    {v.get('spec')}: {v.get('constraint')}: {v.get('status')}: "
                             f"{v.get('message')}")
    if result.error:
        lines.append(f"  error: {result.error}")
    return "\n".join(lines)
