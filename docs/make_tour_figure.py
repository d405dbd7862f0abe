"""Draws docs/tour.png, the README's picture, from the capture of a `rig run` output folder.

    rig run fig09_load_step_realtime --keep-all --out out/fig09
    python docs/make_tour_figure.py out/fig09 docs/tour.png

Needs matplotlib (pip install 'sensorless-hil[docs]'). Reads the capture columns the rig
writes (DIR/capture/*.npy, DIR/result.json): a run that kept them (a failing one, or any with
`rig run --keep-all`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from rig import protocols

TS = protocols.timebase().ts  # PWM period


def main(run_dir: Path, out: Path) -> None:
    cap = run_dir / "capture"

    def col(name: str) -> np.ndarray:
        return np.load(cap / f"{name}.npy")

    result = json.loads((run_dir / "result.json").read_text())
    period = col("period")
    t = (period - period[0]) * TS
    theta = np.mod(col("theta_true_claim"), 2 * np.pi)
    theta_hat = col("fw.theta_hat")
    err = col("pos_err_deg")
    fig, ax = plt.subplots(2, 2, figsize=(11, 6.5), constrained_layout=True)
    fig.suptitle(f"{result['scenario']} ({result['profile']} profile): "
                 f"{result.get('description', '')}", fontsize=10)

    mid = len(t) // 2
    w = slice(mid, min(len(t), mid + 300))
    a = ax[0, 0]
    a.plot(t[w] * 1e3, np.degrees(theta[w]), label="true θe (plant)")
    a.plot(t[w] * 1e3, np.degrees(theta_hat[w]), "--", label="estimated θ̂e (firmware)")
    a.set(xlabel="time (ms)", ylabel="electrical angle (°)", title="rotor position, 30 ms")
    a.legend(loc="upper right", fontsize=8)

    a = ax[0, 1]
    a.plot(t, err, lw=0.5)
    a.set(xlabel="time (s)", ylabel="θ̂ - θ (electrical °)",
          title="position error, every PWM period")
    a.set_ylim(-10, 10)

    a = ax[1, 0]
    a.plot(t, col("speed_ref_rpm"), label="reference")
    a.plot(t, col("speed_true_rpm"), label="true (plant)")
    a.plot(t, col("speed_hat_rpm"), lw=0.5, alpha=0.7, label="estimated")
    a.set(xlabel="time (s)", ylabel="speed (r/min)", title="speed")
    a.legend(fontsize=8)

    a = ax[1, 1]
    a.plot(t, col("fw.id"), lw=0.5, label="id (firmware)")
    a.plot(t, col("fw.iq"), lw=0.5, label="iq (firmware)")
    a.plot(t, col("truth.tl"), label="load torque (N·m)")
    a.set(xlabel="time (s)", ylabel="A, N·m", title="currents and load")
    a.legend(fontsize=8)
    fig.savefig(out, dpi=90)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
