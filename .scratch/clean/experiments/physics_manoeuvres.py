"""Manoeuvres at the default physics step and at a 5× finer one (mjxrow.physics.manoeuvres).

    python experiments/physics_manoeuvres.py [--seconds 4] [--unlimited] [--package DIR]
        [--json OUT.json]

Prints one table: every manoeuvre's figures at the default step (dt 0.01 s → 9.52 ms at
15 Hz) and at a fifth of it (1.90 ms), simulated in MJX (jit(vmap(scan(sim.step)))).
`--unlimited` drives the robot without its torque and acceleration limits (wheel_torque = 0,
max_accel = max_alpha = 0). `--package DIR` runs the same manoeuvres against the mjxrow
package in DIR (a checkout of an older commit: the model before the limits, with its own
defaults).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--unlimited", action="store_true")
    p.add_argument("--package", help="directory holding the mjxrow package to simulate")
    p.add_argument("--json", help="write the figures here too")
    args = p.parse_args(argv)
    if args.package:
        sys.path.insert(0, str(Path(args.package).resolve()))
    from mjxrow.physics import robot as R
    from mjxrow.physics import sim as S

    spec = importlib.util.spec_from_file_location(
        "manoeuvres", HERE / "mjxrow" / "physics" / "manoeuvres.py")
    MV = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(MV)
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
    print(f"mjxrow from {Path(R.__file__).resolve().parent.parent.parent}")
    print(robot_cfg)
    print(MV.table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
