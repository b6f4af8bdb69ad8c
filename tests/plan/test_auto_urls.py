"""`auto` transport targets of virtual benches: unique names, keys and loopback ports."""

from __future__ import annotations

from hil.bench.bench import load_bench
from hil.paths import fixture
from hil.transport.urls import parse_url
from hil.virtual.world import harness_side, resolve_auto


def test_zenoh_auto_gets_a_unique_key_and_a_free_loopback_port(tmp_path):
    bench = load_bench(fixture("benches", "virtual-zenoh.yaml"))
    a, b = resolve_auto(bench, tmp_path), resolve_auto(bench, tmp_path)
    for urls in (a, b):
        can, dio = parse_url(urls["can:can0"], "can"), parse_url(urls["dio:drive1"], "dio")
        assert can.target != dio.target and "auto" not in can.target + dio.target
        eps = can.zenoh().listen + dio.zenoh().listen
        assert all(e.startswith("tcp/127.0.0.1:") and e.rsplit(":", 1)[1].isdigit() for e in eps)
        assert len(set(eps)) == 2  # CAN and DI/DO each their own port
        assert urls["rs485:rs485"].startswith(f"pty:{tmp_path}/")
    assert a["can:can0"] != b["can:can0"]  # unique per run


def test_harness_connects_where_the_drive_listens():
    url = "zenoh:hil/1-0/can?listen=tcp/127.0.0.1:7447&mode=peer"
    assert harness_side(url) == "zenoh:hil/1-0/can?connect=tcp/127.0.0.1:7447&mode=peer"
    assert harness_side("pty:/tmp/x?baud=38400") == "serial:/tmp/x?baud=38400"
    assert harness_side("zenoh:k?connect=tcp/127.0.0.1:1") == "zenoh:k?connect=tcp/127.0.0.1:1"


def test_every_shipped_plan_checks_on_every_shipped_virtual_bench():
    """docs/plans.md: every plan runs on virtual.yaml, virtual-zenoh.yaml (the nightly
    fallback) and virtual-vcan.yaml; an outside review found the PLC plans refused by the
    last two (no `pulse:` line), so the nightly workflow's `--check` failed before any run."""
    from hil.plan.plan import check_plan, find_plans, load_plan

    plans = [load_plan(p) for p in find_plans(None)]
    for name in ("virtual.yaml", "virtual-zenoh.yaml", "virtual-vcan.yaml"):
        bench = load_bench(fixture("benches", name))
        for plan in plans:
            check_plan(plan, bench)  # raises PlanFileError naming the plan's line


def test_a_killed_runs_scratch_folder_is_removed_by_the_next_run(tmp_path, monkeypatch):
    """`kill -9` of a runner leaves its `hil-bench-<pid>-*` folder (ptys, sockets): the next
    run removes the folders of processes that are gone, not those of live ones."""
    import os
    import subprocess
    import sys
    import tempfile

    from hil.virtual.world import bench_tmpdir

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    dead = tmp_path / f"hil-bench-{gone}-abc"
    (dead / "sub").mkdir(parents=True)
    live = tmp_path / f"hil-bench-{os.getppid()}-def"
    live.mkdir()
    other = tmp_path / "hil-bench-xyz"  # an older name without a pid: left alone
    other.mkdir()
    t = bench_tmpdir()
    try:
        assert not dead.exists() and live.exists() and other.exists()
        assert os.path.basename(t.name).startswith(f"hil-bench-{os.getpid()}-")
    finally:
        t.cleanup()
