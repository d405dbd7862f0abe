"""``rig mutate --cluster``: the same campaign on a local Dask cluster (a scheduler and two
workers, each building its own copy of the tree) and on this machine alone give the same
verdicts and the same gate values per mutant.

Each worker builds the whole tree once (minutes on two cores), so the test runs only when
asked: HIL_MUTATE_CLUSTER=1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import dask_support
import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.environ.get("HIL_MUTATE_CLUSTER") != "1",
                       reason="builds the tree once per worker: set HIL_MUTATE_CLUSTER=1"),
]

# two mutants whose smoke values differ from the unmutated drive's (both survive its limits)
MUTANTS = "ctrl-ffd-sign,ctrl-ki-q-halved"


def _campaign(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "rig", "mutate", "--only", MUTANTS, "--suite", "quick",
         "--baseline", "off", "--detectors", "gate", "--out", str(out), *extra],
        capture_output=True, text=True, check=False, timeout=3600)


def _decided(out: Path) -> dict[str, Any]:
    data = json.loads((out / "results.json").read_text())
    got: dict[str, Any] = {"score": {k: v for k, v in data["score"].items()}}
    for m in data["mutants"]:
        folder = out / m["id"] / "quick"
        values = None
        if (folder / "result.json").is_file():
            suite = json.loads((folder / "result.json").read_text())
            values = {e["name"]: [(c["name"], c["value"], c["outcome"]) for c in e["criteria"]]
                      for e in suite["scenarios"]}
        got[m["id"]] = (m["status"], m["killed_by"], m["kill"], values)
    return got


@pytest.mark.timeout(3600)
def test_a_campaign_on_the_cluster_equals_the_local_one(tmp_path: Path) -> None:
    local = _campaign(tmp_path / "local")
    assert local.returncode == 0, local.stderr
    with dask_support.cluster(tmp_path / "dask", 2) as c:
        remote = _campaign(tmp_path / "cluster", "--cluster", c.address)
    assert remote.returncode == 0, remote.stderr
    assert _decided(tmp_path / "cluster") == _decided(tmp_path / "local")
    assert (tmp_path / "cluster" / "_control" / "quick" / "result.json").is_file()
