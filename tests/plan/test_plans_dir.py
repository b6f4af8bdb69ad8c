"""`hil run` uses the plans the user is editing (issue 12): `--plans DIR`, else the `plans/` of
the hil checkout the current directory is in, else the installed copy; it says which on stderr.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hil.paths import plans_dir
from hil.plan.plansdir import checkout_root

PLAN = "edited_brake"  # a plan that exists only in the user's checkout


def hil_run(cwd: Path, *args: str, quiet: bool = True) -> subprocess.CompletedProcess:
    flags = ["-q"] if quiet else []  # -q hides the "plans: <dir> (<why>)" line
    return subprocess.run([sys.executable, "-m", "hil.cli", "run", *flags, *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def checkout(tmp_path) -> Path:
    """A checkout-like tree: pyproject.toml naming the project hil, plans/ with an edited plan."""
    root = tmp_path / "hil-src"
    (root / "plans").mkdir(parents=True)
    (root / "docs").mkdir()
    (root / "pyproject.toml").write_text('[project]\nname = "hil"\nversion = "0"\n')
    shutil.copy(plans_dir() / "servo_on_off_brake.yaml", root / "plans" / f"{PLAN}.yaml")
    return root


def test_checkout_root_needs_project_name_hil_and_plans(checkout, tmp_path):
    assert checkout_root(checkout / "docs") == checkout.resolve()
    other = tmp_path / "other"
    (other / "plans").mkdir(parents=True)
    (other / "pyproject.toml").write_text('[project]\nname = "not-hil"\n')
    assert checkout_root(other) is None
    (checkout / "plans").rename(checkout / "plans.old")
    assert checkout_root(checkout) is None


def test_inside_a_checkout_runs_its_plans(checkout, tmp_path):
    out = tmp_path / "out"
    res = hil_run(checkout / "docs", PLAN, "--out", str(out), quiet=False)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"plans: {checkout.resolve() / 'plans'} (checkout {checkout.resolve()})" in res.stderr
    assert (out / f"{PLAN}.mcap").is_file()


def test_outside_a_checkout_runs_the_installed_plans(checkout, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    res = hil_run(elsewhere, PLAN, "--out", str(tmp_path / "out"), quiet=False)
    assert res.returncode == 2
    assert f"plans: {plans_dir()} (installed)" in res.stderr
    assert f"{PLAN}:0: (plan): no such plan file, nor a plan of that name in" in res.stderr
    # --plans DIR: the user's directory from anywhere
    res = hil_run(elsewhere, PLAN, "--plans", str(checkout / "plans"), "--out",
                  str(tmp_path / "out"), quiet=False)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"plans: {checkout.resolve() / 'plans'} (--plans)" in res.stderr


def test_plans_must_be_a_directory(tmp_path):
    res = hil_run(tmp_path, "--plans", str(tmp_path / "missing"))
    assert res.returncode == 2
    assert "--plans" in res.stderr and "not a directory" in res.stderr
