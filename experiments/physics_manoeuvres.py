"""Manoeuvres at the default physics step and at a 5× finer one (mjxrow.physics.manoeuvres).

    python experiments/physics_manoeuvres.py [--seconds 4] [--unlimited]

Prints one table: every manoeuvre's figures at the default step (dt 0.01 s → 9.52 ms at
15 Hz) and at a fifth of it (1.90 ms). `--unlimited` drives the robot without its torque and
acceleration limits (wheel_torque = 0, max_accel = max_alpha = 0), as the model was before
they existed.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from mjxrow.physics import manoeuvres as MV
from mjxrow.physics import robot as R
from mjxrow.physics import sim as S


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--unlimited", action="store_true")
    args = p.parse_args(argv)
    robot_cfg = R.RobotConfig()
    if args.unlimited:
        limits = {k: 0.0 for k in ("wheel_torque", "max_accel", "max_alpha")
                  if hasattr(robot_cfg, k)}
        robot_cfg = dataclasses.replace(robot_cfg, **limits)
    coarse = S.SimConfig()
    fine = dataclasses.replace(coarse, dt=coarse.physics_dt / 5)
    rows = {}
    for cfg in (coarse, fine):
        t0 = time.perf_counter()
        rows[f"dt {1000 * cfg.physics_dt:.2f} ms"] = MV.figures(MV.run(cfg, robot_cfg,
                                                                       args.seconds))
        print(f"dt {1000 * cfg.physics_dt:.2f} ms: {time.perf_counter() - t0:.1f} s")
    print(robot_cfg)
    print(MV.table(rows))


if __name__ == "__main__":
    main()
