"""What a commissioning step found: identified quantities, pass/fail checks, tables."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class Quantity:
    key: str  # parameter name of protocols/parameters.csv when it is one (rs_ohm, ...)
    label: str
    value: float
    unit: str
    method: str
    nominal: float | None = None  # parameters.csv default
    truth: float | None = None  # the virtual plant's value (None on a real bench)

    @property
    def vs_nominal(self) -> float | None:
        if self.nominal in (None, 0.0) or not math.isfinite(self.value):
            return None
        return self.value / self.nominal - 1.0  # type: ignore[operator]

    @property
    def vs_truth(self) -> float | None:
        if self.truth in (None, 0.0) or not math.isfinite(self.value):
            return None
        return self.value / self.truth - 1.0  # type: ignore[operator]


@dataclass
class Check:
    name: str
    passed: bool
    detail: str


@dataclass
class Table:
    title: str
    columns: list[str]
    rows: list[list[Any]]


@dataclass
class StepResult:
    step: str
    title: str
    passed: bool = False
    error: str | None = None
    quantities: list[Quantity] = field(default_factory=list)
    checks: list[Check] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    facts: dict[str, Any] = field(default_factory=dict)  # machine-readable verdicts
    bench_s: float = 0.0
    wall_s: float = 0.0

    def check(self, name: str, passed: bool, detail: str) -> bool:
        self.checks.append(Check(name, bool(passed), detail))
        return bool(passed)

    def quantity(self, q: Quantity) -> Quantity:
        self.quantities.append(q)
        return q

    def value(self, key: str) -> float:
        for q in self.quantities:
            if q.key == key:
                return q.value
        raise KeyError(key)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        for q, qd in zip(self.quantities, d["quantities"], strict=True):
            qd["vs_nominal"] = q.vs_nominal
            qd["vs_truth"] = q.vs_truth
        return d
