"""pytest plugin `hil` (entry point `pytest11`): benches, drives and recordings as fixtures.

    pytest -m hil                          # the virtual bench (built in)
    pytest -m hil --hil-bench=bench.yaml   # a real bench (or HIL_BENCH=bench.yaml)

Plan files as tests: with the ini option `hil_plans = plans` (a directory, relative to the
ini file; several may be given) every `*.yaml` plan in it is collected as a test item, marked
`hil` and with its `tags:` as markers (`pytest -m "hil and brake"`; not a tag that is no
Python name or a marker pytest or a plugin gives a meaning), `-k` selects by name. It runs
through the same runner as `hil run`; a failing plan shows its failing steps and verdicts.
Works with pytest-xdist (`-n 2`) on a bench private to each worker (the virtual one); a
bench the workers would share errors each test that opens it.

Marker `hil`: the test uses a bench (given to every test whose fixtures use the bench, so
`-m hil` selects it and `-m "not hil"` leaves it out, written or not). Fixtures:

* `hil_bench`    the loaded bench file (session scope; `--hil-bench`, default: virtual)
* `hil_recorder` a `Recorder` writing `<hil-out>/<test id>.mcap`; its path is attached to the
                 JUnit XML as the property `recording`
* `hil_session`  the bench's resources opened for this test (virtual drives started); on
                 teardown the bench is driven to its declared safe state, and that is recorded
* `hil_drive`    the default drive of the session (`DriveIO`: DI/DO functions, parameters,
                 CiA 402 driver)
* `hil_run_plan` run a plan file by name or path through the same runner as `hil run`
* `hil_check`    check a timing spec on this test's recording so far; a failing window
                 raises `TimingFailure` whose message lists every violated window
"""

from __future__ import annotations

import hashlib
import json
import os
import time
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
        help="bench file for tests marked `hil` (default: $HIL_BENCH if set, else the "
        "built-in virtual bench)",
    )
    group.addoption(
        "--hil-clock",
        action="store",
        default=None,
        choices=("virtual", "real"),
        help="the bench's clock: virtual (deterministic, faster than real time) or real "
        "(default: the bench file's clock:, else virtual where the bench can run on it and "
        "names no CAN channel; docs/clock.md)",
    )
    parser.addini("hil_plans", "directories whose *.yaml plan files are collected as tests",
                  type="paths", default=[])
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
    for d in _plan_dirs(config):
        if not d.is_dir():  # a typo collects nothing, silently: say it
            config.issue_config_time_warning(pytest.PytestConfigWarning(
                f"hil_plans: {d} is not a directory: no plans collected from it"), stacklevel=2)
    for d in _plan_dirs(config):  # plan tags are markers: `pytest -m brake` stays strict-clean
        for tag in sorted(_tags_in(d)):
            if _markable(tag):
                config.addinivalue_line("markers", f"{tag}: plans tagged {tag} (hil_plans)")


# pytest's own markers and common plugins': a plan tag of that name would skip, xfail, rerun
# or time out the plan instead of selecting it, so it is not applied as a marker
PYTEST_MARKERS = frozenset({"skip", "skipif", "xfail", "parametrize", "usefixtures",
                            "filterwarnings", "tryfirst", "trylast", "flaky", "timeout",
                            "asyncio", "anyio", "xdist_group", "order", "dependency",
                            "benchmark", "django_db", "hil"})


def _markable(tag: str) -> bool:
    """A tag that can be a marker of its own: a Python name, not a marker with a meaning."""
    return tag.isidentifier() and tag not in PYTEST_MARKERS


def _marker_name(line: str) -> str:
    return line.split(":", 1)[0].split("(", 1)[0].strip()


def _foreign_markers(config: pytest.Config) -> set[str]:
    """Marker names registered by pytest or another plugin: not a plan tag's, and not one
    the project declares itself in its ini `markers` (a project may declare `brake`)."""
    lines = [str(x) for x in config.getini("markers")]  # the ini's and the plugins'
    # the project's own are those written in its config file (`config.inicfg`, which held
    # them apart, is deprecated since pytest 9 and warned on every run)
    path = getattr(config, "inipath", None)
    try:
        text = Path(path).read_text(encoding="utf-8") if path else ""
    except (OSError, UnicodeDecodeError):
        text = ""
    own = {_marker_name(x) for x in lines if x.strip() and x.strip() in text}
    return {_marker_name(line) for line in lines if "(hil_plans)" not in line} - own


def _junit_dir(config: pytest.Config) -> Path | None:
    """The folder of `--junitxml` (recording paths are written relative to it), or None."""
    xml = getattr(config.option, "xmlpath", None)
    return Path(xml).resolve().parent if xml else None


def _recording_property(config: pytest.Config, path: str | Path) -> str:
    from hil.report.junit import recording_ref

    return recording_ref(path, _junit_dir(config))


def _bench_option(config: pytest.Config) -> str | None:
    return config.getoption("--hil-bench") or os.environ.get("HIL_BENCH") or None


def _load_bench(config: pytest.Config) -> Any:
    """The run's bench on the run's clock (`--hil-bench`, `--hil-clock`)."""
    from hil.bench.bench import load_bench, with_clock

    return with_clock(load_bench(_bench_option(config)), config.getoption("--hil-clock"))


def _plan_dirs(config: pytest.Config) -> list[Path]:
    """`hil_plans` (an ini `paths` value: pytest makes each relative to the ini file's
    directory, not to where pytest was started)."""
    return [Path(p).resolve() for p in config.getini("hil_plans")]


@pytest.hookimpl(tryfirst=True)  # before `-m` selects
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A test that uses the bench (`hil_bench`, which `hil_session`, `hil_drive` and
    `hil_run_plan` use) is marked `hil`, so `-m hil` selects it and `-m "not hil"` leaves
    it out, marker written or not. A bad `--hil-bench` / HIL_BENCH is one usage error
    before anything runs (not one traceback per test); unique output names for the
    collected plans (`hil run`'s rule)."""
    for i in items:
        if "hil_bench" in getattr(i, "fixturenames", ()) and i.get_closest_marker("hil") is None:
            i.add_marker("hil")
    uses_bench = any(isinstance(i, PlanItem) or "hil_bench" in getattr(i, "fixturenames", ())
                     for i in items)
    path = _bench_option(config)
    if uses_bench and path is not None:
        from hil.bench.bench import load_bench
        from hil.bench.yamlio import PlanFileError

        try:
            load_bench(path)
        except PlanFileError as e:
            where = "--hil-bench" if config.getoption("--hil-bench") else "HIL_BENCH"
            raise pytest.UsageError(f"{where}: {e}") from None
    if uses_bench and config.getoption("--hil-clock"):
        try:
            _load_bench(config)
        except ValueError as e:
            raise pytest.UsageError(f"--hil-clock: {e}") from None
    if uses_bench and config.pluginmanager.hasplugin("rerunfailures") \
            and _load_bench(config).clock == "virtual":
        # virtual time is deterministic: a failure is a failure, never rerun (issue 25),
        # whatever `--reruns` or a test's own `flaky` marker asks (this one is looked at first)
        for i in items:
            if isinstance(i, PlanItem) or "hil_bench" in getattr(i, "fixturenames", ()):
                i.add_marker(pytest.mark.flaky(reruns=0), append=False)
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    if uses_bench and workers > 1:  # xdist: each worker would open the bench at once
        from hil.plan.parallel import parallel_blocker

        why = parallel_blocker(_load_bench(config))
        if why is not None:  # what `hil run -j` refuses: two runs on one set of drives;
            # every test that opens the bench errors with it (a worker cannot stop the run)
            config.stash[_SHARED] = (f"pytest-xdist with {workers} workers: {why}; run it "
                                     "without -n (each worker would drive it at once)")
    out = config.getoption("--hil-out")
    if out is not None and any(isinstance(i, PlanItem) or "hil_recorder" in getattr(
            i, "fixturenames", ()) or "hil_run_plan" in getattr(i, "fixturenames", ())
            for i in items):
        from hil.fileio import dir_problem

        if (why := dir_problem(out)) is not None:
            raise pytest.UsageError(f"--hil-out {out}: {why}")
    plans = [i for i in items if isinstance(i, PlanItem)]
    if plans:
        from hil.plan.runner import output_stems

        for item, stem in zip(plans, output_stems([i.plan for i in plans]), strict=True):
            item.stem = stem


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    """A `*.yaml` file in a `hil_plans` directory is a plan: one test item."""
    if file_path.suffix not in (".yaml", ".yml"):
        return None
    dirs = _plan_dirs(parent.config)
    if not any(file_path.resolve().parent == d for d in dirs):
        return None
    return PlanFile.from_parent(parent, path=file_path)


class PlanFile(pytest.File):
    """One plan file: a single `PlanItem` named after the plan."""

    def collect(self) -> Iterator[pytest.Item]:
        from hil.bench.yamlio import PlanFileError
        from hil.plan.plan import load_plan

        try:
            plan = load_plan(self.path)
        except PlanFileError as e:
            raise self.CollectError(str(e)) from None
        item = PlanItem.from_parent(self, name=plan.name, plan=plan)
        item.add_marker("hil")
        foreign = _foreign_markers(self.config)
        for tag in plan.tags:
            if _markable(tag) and tag not in foreign:
                item.add_marker(tag)
            else:  # it would change how the plan runs, or is no marker name: said, not applied
                item.warn(pytest.PytestConfigWarning(
                    f"{plan.path}: tag {tag!r} is not applied as a marker (a pytest or plugin "
                    "marker of that name would change how the plan runs, or it is no Python "
                    "name); select the plan by name with -k"))
        yield item


class PlanItem(pytest.Item):
    """Runs one plan on the bench (`--hil-bench` / HIL_BENCH / virtual)."""

    def __init__(self, *, plan: Any, **kw: Any) -> None:
        super().__init__(**kw)
        self.plan = plan
        self.stem: str | None = None  # output name, unique in the session (collection)

    def runtest(self) -> None:
        from hil.plan.runner import run_plan

        if _SHARED in self.config.stash:
            pytest.fail(self.config.stash[_SHARED], pytrace=False)
        bench = _load_bench(self.config)
        from hil.report.data import load_run
        from hil.report.junit import case_properties

        try:
            result = run_plan(self.plan, bench, _out_dir(self.config), stem=self.stem)
        except BaseException as e:  # cut (Ctrl-C, pytest-timeout): its recording is kept
            cut = getattr(e, "plan_result", None)
            if cut is not None and cut.recording:
                self.user_properties.append(
                    ("recording", _recording_property(self.config, cut.recording)))
            raise
        # `hil run`'s JUnit shape: recording (relative to the JUnit file), steps, verdicts
        run = load_run(result.recording)
        self.user_properties.extend(case_properties(run, _junit_dir(self.config)))
        if not result.passed:
            raise PlanFailed(explain(result, run))

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None
                     ) -> str:
        if isinstance(excinfo.value, PlanFailed):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self) -> tuple[Path, int, str]:
        return self.path, 0, f"plan: {self.plan.name}"


class PlanFailed(AssertionError):
    """A plan collected from `hil_plans` did not pass (message: its failing steps)."""


def _out_dir(config: pytest.Config) -> Path:
    out = config.getoption("--hil-out") or Path(str(config.rootpath)) / "reports" / "pytest"
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _tags_in(directory: Path) -> set[str]:
    """The `tags:` of the plan files in `directory` (unparsable files are left to collection)."""
    from hil.bench.yamlio import PlanFileError
    from hil.plan.plan import load_plan

    tags: set[str] = set()
    for p in sorted(directory.glob("*.y*ml")):
        try:
            tags.update(load_plan(p).tags)
        except PlanFileError:
            continue
    return tags


def _safe_name(nodeid: str) -> str:
    """A file name for a test id: its path and name with `_` for what a file name should not
    hold. A parametrized id (`[...]`) also gets a short hash of the exact id, so
    `test_q[x y]`, `test_q[x_y]` and `test_q_x_y` keep one recording each, on any xdist
    worker (the name depends on the id alone)."""
    from hil.fileio import fit_name, safe_stem

    safe = safe_stem(nodeid, collapse=True).strip("_")
    _head, bracket, _params = nodeid.partition("[")  # bytes: a file name holds 255 of them
    return fit_name(safe, 150, nodeid if bracket or len(safe.encode()) > 150 else None)


_STEMS = pytest.StashKey[dict[str, str]]()
_SHARED = pytest.StashKey[str]()  # why xdist workers must not open this bench


def _unique_stem(config: pytest.Config, stem: str, nodeid: str) -> str:
    """`stem`, or `stem-<hash of the test id>` when another test of this session took it
    (`tests/a/test_b.py::t` and `tests/a_test_b.py::t` both read `tests_a_test_b.py_t`)."""
    taken = config.stash.setdefault(_STEMS, {})
    key = stem.casefold()
    if taken.setdefault(key, nodeid) != nodeid:
        stem = f"{stem}-{hashlib.sha1(nodeid.encode()).hexdigest()[:8]}"
        taken[stem.casefold()] = nodeid
    return stem


@pytest.fixture(scope="session")
def hil_bench(pytestconfig: pytest.Config) -> Any:
    """The bench of this pytest run (`--hil-bench FILE`, default: the virtual bench), on its
    clock (`--hil-clock`)."""
    if _SHARED in pytestconfig.stash:
        pytest.fail(pytestconfig.stash[_SHARED], pytrace=False)
    return _load_bench(pytestconfig)


@pytest.fixture
def hil_recorder(request: pytest.FixtureRequest) -> Iterator[Any]:
    """One MCAP recording per test, attached to the JUnit XML as the property `recording`
    (relative to the JUnit file), as `hil run` names it."""
    from hil.record.recorder import Recorder

    nodeid = request.node.nodeid
    path = _out_dir(request.config) / (
        _unique_stem(request.config, _safe_name(nodeid), nodeid) + ".mcap")
    request.node.user_properties.append(("recording", _recording_property(request.config,
                                                                         path)))
    rec = Recorder(path, metadata={"pytest_nodeid": request.node.nodeid})
    request.node.stash[_T0] = time.monotonic()  # the test's wall time, as a plan's
    yield rec
    # closed once every fixture of the test is torn down (`pytest_runtest_teardown`), so
    # that a teardown error of a fixture torn down after this one still reaches `hil.result`
    request.node.stash[_OPEN] = rec
    request.config.stash.setdefault(_UNFINISHED, []).append(request.node)


_REPORTS = pytest.StashKey[dict[str, pytest.TestReport]]()
_OPEN = pytest.StashKey[Any]()  # the test's recorder, closed after its teardown
_T0 = pytest.StashKey[float]()  # when the test's recording opened (monotonic s)
_SIGNALS = pytest.StashKey[Any]()  # the test's `Interrupts` while its session is open
_RESULT = pytest.StashKey[dict]()  # `hil.result` as `hil_session` left it
_UNFINISHED = pytest.StashKey[list]()  # items whose recording is still open


@pytest.hookimpl(wrapper=True)
def pytest_sessionfinish(session: pytest.Session) -> Any:
    """A run stopped inside a test (Ctrl-C) tears its fixtures down here, not in
    `pytest_runtest_teardown`: close those recordings too."""
    try:
        return (yield)
    finally:
        for item in list(session.config.stash.get(_UNFINISHED, [])):
            _finish_recording(item, None, stopped=True)


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Any:
    """After every fixture of the test is torn down: write `hil.result` (a teardown error
    makes a passing test's result `error`) and close the recording."""
    error: BaseException | None = None
    try:
        return (yield)
    except BaseException as e:
        error = e
        raise
    finally:
        _finish_recording(item, error)


def _finish_recording(item: pytest.Item, error: BaseException | None,
                      stopped: bool = False) -> None:
    rec = item.stash.get(_OPEN, None)
    result = item.stash.get(_RESULT, None)
    if result is not None:
        del item.stash[_RESULT]  # a rerun of this item starts without it
    if rec is None:
        return
    unfinished = item.config.stash.get(_UNFINISHED, [])
    if item in unfinished:
        unfinished.remove(item)
    if result is None:  # no `hil_session` (a test of `hil_recorder` alone): its outcome
        status, reason = ("aborted", "interrupted (Ctrl-C)") if stopped else _outcome(item)
        result = {"status": status, "reason": reason}
    try:
        if error is not None and result["status"] in ("pass", "skipped"):
            result = {**result, **_teardown_outcome(error)}
        if (t0 := item.stash.get(_T0, None)) is not None:  # wall ms, as a plan's
            result = {**result, "duration_ms": round((time.monotonic() - t0) * 1e3, 3)}
        rec.add_metadata("hil.result", result)
    finally:
        del item.stash[_OPEN]
        rec.close()


def _teardown_outcome(error: BaseException) -> dict[str, str]:
    """`hil.result`'s status and reason for an error raised while the test's fixtures were
    torn down (the first of several)."""
    while isinstance(error, BaseExceptionGroup) and error.exceptions:
        error = error.exceptions[0]
    if isinstance(error, pytest.skip.Exception):  # pytest reports the test skipped
        return {"status": "skipped", "reason": f"skipped in teardown: {error}"[:300]}
    if isinstance(error, KeyboardInterrupt):
        return {"status": "aborted", "reason": "interrupted (SIGINT) during teardown"}
    from hil.plan.runner import first_line

    return {"status": "error", "reason": f"teardown failed: {first_line(error)}"[:300]}


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Any:
    """Keep each phase's report on the item: `hil_session` records why the bench went safe."""
    rep = yield
    item.stash.setdefault(_REPORTS, {})[rep.when] = rep
    return rep


@pytest.hookimpl(wrapper=True, trylast=True)  # inside pytest-timeout's own wrapper
def pytest_runtest_call(item: pytest.Item) -> Any:
    """pytest-timeout with `func_only` installs its SIGALRM handler only now, after the
    fixtures: wrap it as `hil_session` wrapped one installed before it (`wrap_alarm`)."""
    signals = item.stash.get(_SIGNALS, None)
    old = signals.wrap_alarm() if signals is not None else None
    try:
        return (yield)
    finally:
        if old is not None:
            import signal

            if getattr(signal.getsignal(signal.SIGALRM), "_hil_deferred", False):
                signal.signal(signal.SIGALRM, old)


def _crash(rep: pytest.TestReport) -> str:
    """The first line of what made a phase fail ("RuntimeError: boom")."""
    crash = getattr(rep.longrepr, "reprcrash", None)
    what = crash.message.splitlines()[0] if crash is not None and crash.message else ""
    if not what and isinstance(rep.longrepr, str):  # "[XPASS(strict)] reason"
        what = rep.longrepr.splitlines()[0] if rep.longrepr else ""
    return what


def _outcome(node: pytest.Item) -> tuple[str, str]:
    """(status, reason) of a test whose teardown is running: its call phase's report (its
    setup's where a fixture set up after the bench skipped it or failed under xfail)."""
    reports = node.stash.get(_REPORTS, {})
    rep = reports.get("call")
    if rep is None:
        setup = reports.get("setup")
        if setup is not None and setup.failed:  # a fixture after the bench's, say: the
            return "error", f"setup failed: {_crash(setup)}"[:300].rstrip(": ")  # bench moved
        if setup is None or not setup.skipped:
            return "error", "the test did not run"
        rep = setup
    if rep.failed:
        return "fail", f"test failed: {_crash(rep)}"[:300].rstrip(": ")
    xfail = getattr(rep, "wasxfail", None)
    if xfail is not None:  # `pytest.xfail("why")` reads "reason: why"
        xfail = str(xfail).removeprefix("reason: ")
    if rep.skipped and xfail is not None:  # pytest's "xfailed": it failed, as expected
        return "skipped", f"expected failure (xfail): {xfail}"[:300].rstrip(": ")
    if rep.skipped:  # `pytest.skip()` in the test: (path, line, message)
        longrepr = rep.longrepr
        why = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else ""
        return "skipped", f"skipped: {str(why).removeprefix('Skipped: ')}"[:300].rstrip(": ")
    if xfail is not None:  # "xpassed" (not strict): it passed although expected to fail
        return "pass", f"passed, although expected to fail (xfail): {xfail}"[:300].rstrip(": ")
    return "pass", "end of test"


@pytest.fixture
def hil_session(hil_bench: Any, hil_recorder: Any,
                request: pytest.FixtureRequest) -> Iterator[Any]:
    """Bench resources for one test, on the bench's clock (virtual time: wait with
    `hil.clock.sleep` / the drivers' waits, not `time.sleep`); the bench goes to its safe
    state afterwards, and the recording says why (the test's failure, or its end) and how
    the test ended (`hil.result`), as a plan's does."""
    from hil.plan.runner import (
        Interrupts,
        bench_clock,
        first_line,
        record_bench,
        record_dut,
        safe_tail,
    )
    from hil.plan.safety import go_safe_watched
    from hil.plan.session import open_session

    with bench_clock(hil_bench) as clk, Interrupts(clk) as signals:
        request.node.stash[_SIGNALS] = signals  # pytest-timeout's func_only handler too
        record_bench(hil_recorder, hil_bench)
        session = open_session(hil_bench, hil_recorder)
        try:
            session.idle()
            record_dut(session, hil_recorder, hil_bench)  # as a plan's: `hil.dut`
            yield session
        finally:
            signals.shield = True  # the safe state and the recording's close run to the end
            signals.drop_pending()  # one deferred but not yet raised must not cut it
            status, reason = _outcome(request.node)
            if signals.cause:
                status, reason = "aborted", f"interrupted ({signals.cause})"
            elif signals.alarm is not None and status in ("pass", "skipped"):  # a timeout
                status, reason = "fail", f"test failed: {first_line(signals.alarm)}"  # not seen
            safe = None
            try:
                # the drive's reaction on the record after it, as after a plan (safe_tail)
                safe = go_safe_watched(session, reason, hil_recorder, safe_tail)
            finally:
                session.close()
                unsafe = "; ".join(f"{a['drive']}: {a['action']}: {a['detail']}"
                                   for a in safe.actions if not a["ok"]) if safe else ""
                if signals.alarm is not None and status in ("pass", "skipped"):  # came while
                    status, reason = "fail", f"test failed: {first_line(signals.alarm)}"  # shielded
                if unsafe and status == "pass":  # a test passes only if it leaves the bench
                    status, reason = "error", f"safe state not confirmed: {unsafe}"  # safe
                # written when the recording closes, after the other fixtures' teardown
                request.node.stash[_RESULT] = {
                    "status": status, "reason": reason,
                    "safe_state_ok": safe.ok if safe is not None else ""}
                if _SIGNALS in request.node.stash:
                    del request.node.stash[_SIGNALS]
            if unsafe and not signals.cause:
                also = f" ({first_line(signals.alarm)})" if signals.alarm is not None else ""
                pytest.fail(f"hil: the bench's safe state was not confirmed after the test: "
                            f"{unsafe}{also}", pytrace=False)
            if signals.alarm is not None and not signals.cause:
                raise signals.alarm  # the timeout, once the bench is safe and on the record


@pytest.fixture
def hil_drive(hil_session: Any) -> Any:
    """The bench's default drive (`hil.plan.session.DriveIO`)."""
    return hil_session.drive(None)


@pytest.fixture
def hil_run_plan(hil_bench: Any, request: pytest.FixtureRequest) -> Callable[[str | Path], Any]:
    """Run a plan (name or path) on the bench; returns the `PlanResult`."""
    from hil.bench.yamlio import PlanFileError
    from hil.fileio import fit_bytes, safe_stem
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import plan_stem, run_plan

    runs: list[str] = []

    def run(plan: str | Path) -> Any:
        # a path (from where pytest runs, else from the rootdir), else a name in the
        # project's `hil_plans` directories, else in hil's plans directory
        path = Path(plan)
        if not path.exists() and (request.config.rootpath / path).exists():
            path = request.config.rootpath / path
        if not path.exists():
            for d in [*_plan_dirs(request.config), None]:
                try:
                    path = find_plans([str(plan)], d)[0]
                    break
                except (FileNotFoundError, PlanFileError, IndexError):
                    if d is None:
                        raise
        loaded = load_plan(path)
        # named after the test and the plan: never the name of a plan collected as a test
        # (`hil_plans`) or of this plan run by another test
        nodeid = request.node.nodeid
        stem = f"{_safe_name(nodeid)}-{fit_bytes(safe_stem(plan_stem(loaded)), 80)}"
        runs.append(stem)
        if runs.count(stem) > 1:
            stem = f"{stem}-{runs.count(stem)}"
        stem = _unique_stem(request.config, stem, nodeid)
        try:
            result = run_plan(loaded, hil_bench, _out_dir(request.config), stem=stem)
        except BaseException as e:  # cut (Ctrl-C, pytest-timeout): its recording is kept
            result = getattr(e, "plan_result", None)
            if result is not None and result.recording:
                request.node.user_properties.append(
                    ("recording", _recording_property(request.config, result.recording)))
            raise
        request.node.user_properties.append(
            ("recording", _recording_property(request.config, result.recording)))
        return result

    return run


@pytest.fixture
def hil_check(hil_recorder: Any, request: pytest.FixtureRequest) -> Callable[..., list]:
    """Check a shipped timing spec (id or path) on this test's recording so far."""
    from hil.paths import fixture
    from hil.timing.checker import check
    from hil.timing.source import RecordingSource
    from hil.timing.spec import load_spec, shipped_specs

    recorded: set[str] = set()  # a verdict judged again by a later call is recorded once

    def run(spec: str | Path, *, binding: dict | None = None, allow_inconclusive: bool = False,
            **kw: Any) -> list:
        path = Path(spec)
        if not path.exists() and (request.config.rootpath / path).exists():
            path = request.config.rootpath / path  # as `hil_run_plan` finds a plan
        if not path.exists():
            if path.parent != Path("."):  # a path, not a shipped spec's id or file name
                raise ValueError(f"timing spec {spec!r}: no such file (from "
                                 f"{Path.cwd()} nor from the rootdir {request.config.rootpath})")
            name = path.stem if path.suffix in (".yaml", ".yml") else path.name
            path = fixture("timing", f"{name}.yaml")
            if not path.is_file():
                known = ", ".join(sorted(p.stem for p in shipped_specs()))
                raise ValueError(f"timing spec {spec!r}: no such file, and no shipped spec "
                                 f"has that id (shipped: {known})")
        hil_recorder.flush()
        loaded = load_spec(path)
        verdicts = check(loaded, RecordingSource(hil_recorder.path), binding=binding, **kw)
        for v in verdicts:  # on the recording, as a plan's check_timing records them
            key = json.dumps([v.to_dict(), binding or {}], sort_keys=True, default=str)
            if v.status != "skipped" and key not in recorded:
                recorded.add(key)
                hil_recorder.verdict(v.to_dict(), binding=binding or {})
        if not any(v.status != "skipped" for v in verdicts):  # nothing judged is not a pass
            why = "; ".join(dict.fromkeys(v.message for v in verdicts)) or "no occurrence"
            raise TimingFailure(f"timing spec {loaded.id}: nothing judged: {why}")
        bad = [v for v in verdicts if v.status == "fail"
               or (v.status == "inconclusive" and not allow_inconclusive)]
        if bad:
            lines = [f"{v.spec}: {v.constraint}: {v.status.upper()}: {v.message}" for v in bad]
            raise TimingFailure("timing spec violated:\n  " + "\n  ".join(lines))
        return verdicts

    return run


def explain(result: Any, run: Any = None) -> str:
    """A plan result as lines a test failure can show: the failure text `hil run`'s JUnit
    gives (every step and verdict that did not pass, with its plan file and line), and where
    the recording is. `run`: the recording already read (`load_run`)."""
    from hil.report.data import load_run
    from hil.report.junit import failure_text

    lines = [f"plan {result.plan}: {result.status}"]
    try:
        lines.append(failure_text(run if run is not None else load_run(result.recording))[1])
    except Exception as e:  # an unreadable recording: the result's own error says more
        lines.append(f"(recording not readable: {e})")
    if result.error:
        lines.append(f"error: {result.error}")
    lines.append(f"recording: {result.recording}")
    return "\n".join(lines)
