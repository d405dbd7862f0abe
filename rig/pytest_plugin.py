"""pytest plugin ``hil``: run scenarios from tests in a few lines.

    def test_smoke(hil_run):
        result = hil_run("smoke")
        result.assert_passed()
        assert result.metric("pos_err_max_deg", window=(0.3, 0.5)) < 5

    @pytest.mark.hil_scenario("fig09_load_step_realtime")
    def test_load_step(hil_result):
        assert hil_result.criterion("speed drop")["passed"]

    def test_every_paper_scenario(hil_scenario_name, hil_run):   # parametrized over a suite
        hil_run(hil_scenario_name).assert_passed()

Each pytest-xdist worker gets its own bus channel (unixcan: ``vcan-<worker>-<pid>``;
SocketCAN: ``vcan<N>`` for worker ``gw<N>``, created when running as root), so workers never
see each other's frames. Tests that need the programs skip (with the reason) when
``plant_rt`` / ``fw_host`` are not built. Options: ``--hil-bus``, ``--hil-out``,
``--hil-realtime``, ``--hil-suite``. Imports of the rig itself are lazy: loading the plugin
costs nothing in unrelated test runs.

Every run a test makes is recorded as the test's properties (``record_property``: what
``--junitxml`` writes), named ``SCENARIO/CRITERION/KEY`` with the keys ``rig run --junit``
gives a criterion (metric, value, limit, comparison, unit, window, outcome) and
``SCENARIO/report``, ``SCENARIO/passed`` and, for a run that did not pass, ``SCENARIO/verdict``
(the message of ``rig run --junit``'s run testcase; a criterion's class against its baseline
is its ``baseline.class`` property); a failing test shows the reports of its runs, and why
each that did not pass did not, in a section of its own.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Generator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from rig.results.result import RunResult
    from rig.scenario import Scenario

DEFAULT_SUITE = "paper"
RUNS = pytest.StashKey[list["RunResult"]]()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hil", "hardware-in-the-loop rig")
    group.addoption("--hil-bus", default=None,
                    help="transport for scenario runs: auto, socketcan, unixcan or inproc "
                    "(the in-process bench; default: $HIL_BUS, else auto)")
    group.addoption("--hil-out", default=None,
                    help="keep every run's output (result.json, report.md, recording.rrd) "
                    "under this folder instead of pytest's temporary folders")
    group.addoption("--hil-realtime", action="store_true", default=False,
                    help="run scenarios in real-time mode instead of lockstep")
    group.addoption("--hil-suite", default=None,
                    help=f"suite whose scenarios parametrize hil_scenario_name "
                    f"(default: {DEFAULT_SUITE})")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "hil_scenario(name, **options): the scenario the hil_result fixture runs")
    config.addinivalue_line(
        "markers", "hil_suite(name): the suite that parametrizes hil_scenario_name")


def _opt(config: pytest.Config, name: str) -> Any:
    try:
        return config.getoption(name)
    except ValueError:  # the plugin was registered after option parsing
        return None


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "hil_scenario_name" not in metafunc.fixturenames:
        return
    from rig import scenario as sc

    marker = metafunc.definition.get_closest_marker("hil_suite")
    suite_name = (marker.args[0] if marker else None) or _opt(
        metafunc.config, "--hil-suite") or DEFAULT_SUITE
    suite = sc.load(suite_name)
    if isinstance(suite, sc.Suite):
        names = [s.name for s in suite.scenarios]
    else:
        names = [suite.name]
    metafunc.parametrize("hil_scenario_name", names, ids=names)


def worker_id(config: pytest.Config) -> str:
    """``gw0``, ``gw1``... under pytest-xdist, ``main`` otherwise."""
    wi = getattr(config, "workerinput", None)
    return str(wi["workerid"]) if wi else "main"


def channel_for(worker: str, transport: str) -> str:
    """The bus channel a worker uses on a transport."""
    m = re.fullmatch(r"gw(\d+)", worker)
    n = int(m.group(1)) if m else 0
    if transport == "socketcan":
        return f"vcan{n}"
    return f"vcan-{worker}-{os.getpid()}"


@pytest.fixture(scope="session")
def hil_bus(request: pytest.FixtureRequest) -> tuple[str, str]:
    """(transport, channel) for this worker; SocketCAN interfaces are created as root."""
    from rig import bus as rigbus

    wanted = _opt(request.config, "--hil-bus") or os.environ.get("HIL_BUS") or "auto"
    worker = worker_id(request.config)
    if wanted == "inproc":  # the in-process bench (rig.bench.sil): no bus, no channel
        return "inproc", ""
    if wanted in ("auto", "socketcan"):
        chan = channel_for(worker, "socketcan")
        if rigbus.kernel_has_can() and os.geteuid() == 0:
            try:
                rigbus.vcan_up(chan)
                return "socketcan", chan
            except RuntimeError as exc:
                if wanted == "socketcan":
                    pytest.skip(f"socketcan requested but {chan} is unavailable: {exc}")
        elif rigbus.kernel_has_can() and rigbus.interface_exists(chan):
            return "socketcan", chan
        elif wanted == "socketcan":
            pytest.skip("socketcan requested but this kernel has no CAN (or not root)")
    return "unixcan", channel_for(worker, "unixcan")


@pytest.fixture(scope="session")
def hil_binaries() -> dict[str, Path]:
    """Paths of plant_rt and fw_host; skips the test when they are not built."""
    from rig import _paths

    found: dict[str, Path] = {}
    for name in ("plant_rt", "fw_host"):
        try:
            found[name] = _paths.binary(name)
        except FileNotFoundError as exc:
            pytest.skip(f"{name} is not built: {exc}")
    return found


@pytest.fixture
def hil_out(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    """Where this test's runs write (``--hil-out/<test id>`` or a temporary folder)."""
    base = _opt(request.config, "--hil-out")
    if not base:
        return tmp_path
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", request.node.nodeid).strip("_")
    out = Path(base) / safe
    out.mkdir(parents=True, exist_ok=True)
    return out


HilRun = Callable[..., "RunResult"]


@pytest.fixture
def hil_run(
    request: pytest.FixtureRequest, hil_bus: tuple[str, str], hil_binaries: dict[str, Path],
    hil_out: Path,
) -> Iterator[HilRun]:
    """``hil_run(scenario, *, realtime=None, **options) -> RunResult``.

    ``scenario``: a name, a path or a ``Scenario``. Options are ``rig.run.runner.RunOptions``
    fields (``timeout_s``, ``record``, ``bus="inproc"`` for the in-process bench, ...). Each
    call writes to its own sub-folder."""
    from rig import scenario as sc
    from rig.run import runner

    transport, channel = hil_bus
    default_rt = bool(_opt(request.config, "--hil-realtime"))
    counter = [0]

    def run(target: str | Path | Scenario, *, realtime: bool | None = None,
            **options: Any) -> RunResult:
        scen = target if isinstance(target, sc.Scenario) else sc.load(target)
        if isinstance(scen, sc.Suite):
            raise TypeError("hil_run runs one scenario; parametrize over a suite instead")
        counter[0] += 1
        out = hil_out / (scen.name if counter[0] == 1 else f"{scen.name}-{counter[0]}")
        bus = options.pop("bus", transport)
        opts = runner.RunOptions(
            out=out, bus=bus, channel=channel,
            realtime=default_rt if realtime is None else realtime, progress=False,
            **options,
        )
        result = runner.run_scenario(scen, opts)
        record(request.node, result)
        return result

    yield run


def record(item: pytest.Item, result: RunResult) -> None:
    """The run's verdict as the test's properties, as rig run --junit names them."""
    from rig.results import junit

    item.stash.setdefault(RUNS, []).append(result)
    name = result.scenario
    item.user_properties.append((f"{name}/report", str(result.report_path)))
    item.user_properties.append((f"{name}/status", result.status))
    item.user_properties.append((f"{name}/passed", str(result.passed).lower()))
    verdict = junit.run_verdict(result.to_json())
    if verdict is not None:  # why the run did not pass, as rig run --junit says it
        item.user_properties.append((f"{name}/verdict", verdict[2]))
    for c in result.criteria:
        for key, value in junit.criterion_properties(c):
            item.user_properties.append((f"{name}/{c['name']}/{key}", value))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]
                              ) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report: pytest.TestReport = yield
    runs = item.stash.get(RUNS, [])
    if report.failed and runs:
        lines = [line for r in runs for line in (
            f"{r.scenario}: {r.status} -> {r.report_path}",
            *([] if r.passed else r.explain().splitlines()[1:]))]
        report.sections.append(("hil runs (reports)", "\n".join(lines)))
    return report


@pytest.fixture
def hil_result(request: pytest.FixtureRequest, hil_run: HilRun) -> RunResult:
    """The result of the scenario named by ``@pytest.mark.hil_scenario(name, **options)``
    (or by the ``hil_scenario_name`` parameter)."""
    marker = request.node.get_closest_marker("hil_scenario")
    if marker is not None and marker.args:
        return hil_run(marker.args[0], **marker.kwargs)
    name = None
    if "hil_scenario_name" in request.fixturenames:
        name = request.getfixturevalue("hil_scenario_name")
    if not name:
        raise pytest.UsageError(
            "hil_result needs @pytest.mark.hil_scenario(name) or a hil_scenario_name parameter")
    return hil_run(name)
