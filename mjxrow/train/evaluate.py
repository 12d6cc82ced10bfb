"""Evaluation of a trained policy beside SegZeros and the oracle, through the run builder (the
sweep's episodes, keys and metrics): `n` episodes per (preset, controller) at the preset's
default geometry in the Table 3 scenario (`mjxrow/sweep/presets.yaml`), success with its 95 % Wilson
interval and the other navigation metrics.

The programs can be compiled ahead (`Evaluation.prepare`, e.g. in a thread while the policy
trains: the network's weights are traced, so a checkpoint of the same architecture written
later runs in the program compiled for an earlier one) and run later (`Evaluation.run`).
"""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from mjxrow.rollout import aggregate as rollout_aggregate
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout.config import RunConfig, build_run

SCENARIO = Path(__file__).resolve().parents[1] / "sweep" / "presets.yaml"  # the Table 3 scenario
SECTIONS = ("sim", "robot", "camera", "render", "episode", "perception")
CONTROLLERS: dict[str, tuple[str, dict[str, Any]]] = {
    "policy": ("learned policy", {"controller.name": "policy"}),
    "segzeros": ("SegZeros, learned segmenter", {"controller.name": "segzeros",
                                                 "controller.variant": "paper",
                                                 "perception.source": "learned"}),
    "segzeros_gt": ("SegZeros, ground-truth mask", {"controller.name": "segzeros",
                                                    "controller.variant": "paper",
                                                    "perception.source": "ground_truth"}),
    "oracle": ("oracle pure pursuit", {"controller.name": "oracle"}),
}


def scenario_values(path: str | Path = SCENARIO) -> dict[str, Any]:
    """The dotted run keys of a sweep YAML's sections (sim, robot, camera, render, episode,
    perception): the Table 3 scenario by default. The controller and the axes are left out."""
    raw = yaml.safe_load(Path(path).read_text()) or {}
    out = {}
    for sec in SECTIONS:
        for k, v in (raw.get(sec) or {}).items():
            out[f"{sec}.{k}"] = v
    return out


def run_config(preset: str, controller: str, values: dict[str, Any], checkpoint: str = "",
               seed: int = 0) -> RunConfig:
    """The RunConfig of one evaluation block (controller: a CONTROLLERS name)."""
    sets = {"preset": preset, **values, **CONTROLLERS[controller][1]}
    if controller == "policy":
        sets["controller.checkpoint"] = checkpoint
    return build_run(sets, seed=seed)


@dataclasses.dataclass
class Block:
    preset: str
    controller: str
    run: RunConfig
    n: int
    exe: Any = None
    compile_s: float = 0.0
    run_s: float = 0.0
    summary: dict | None = None
    label: str | None = None  # the table's name for the controller (None: its usual name)


class Evaluation:
    """Blocks of `n` episodes for every (preset, controller); `prepare` compiles, `run` runs
    (compiling what was not prepared) with the checkpoint as it is on disk then."""

    def __init__(self, presets, controllers, values: dict[str, Any], checkpoint: str, n: int,
                 seed: int = 0, compile_checkpoint: str | None = None):
        self.blocks = [Block(p, c, run_config(p, c, values, checkpoint, seed), n)
                       for p in presets for c in controllers]
        self.values, self.seed, self.checkpoint = values, seed, checkpoint
        self.compile_checkpoint = compile_checkpoint

    def _build(self, b: Block, run: RunConfig):
        built = rollout_build.build(run)
        batch = built.batch([(run, e) for e in range(b.n)])
        return built, batch

    def prepare(self, log=print) -> None:
        """Compile every block's program (the policy's with `compile_checkpoint`, a checkpoint
        of the same architecture, when the trained one does not exist yet): each block is
        built and traced in turn, and compiled in a thread of its own, so that XLA compiles
        the blocks side by side where the machine has the cores."""
        def compile_one(b, lowered, t0):
            b.exe = lowered.compile()
            b.compile_s = time.perf_counter() - t0
            log(f"compiled {b.controller} on {b.preset} in {b.compile_s:.1f} s")

        todo = [b for b in self.blocks if b.exe is None]
        with ThreadPoolExecutor(max(1, len(todo))) as ex:
            jobs = []
            for b in todo:
                run = b.run
                if b.controller == "policy" and self.compile_checkpoint:
                    run = run_config(b.preset, "policy", self.values, self.compile_checkpoint,
                                     self.seed)
                t0 = time.perf_counter()
                built, batch = self._build(b, run)
                args = batch.args(built.mx)
                lowered = built.program(args).lower(*args)  # or the one an earlier run kept
                jobs.append(ex.submit(compile_one, b, lowered, t0))
            for j in jobs:
                j.result()

    def run(self, log=print) -> list[Block]:
        for b in self.blocks:
            if b.exe is None:
                t0 = time.perf_counter()
                built, batch = self._build(b, b.run)
                b.exe = built.executable(batch.args(built.mx))
                b.compile_s = time.perf_counter() - t0
            self._run_one(b, log)
        return list(self.blocks)  # a new list: a caller's additions stay out of self.blocks

    def _run_one(self, b: Block, log) -> None:
        """Run block `b`'s episodes in its compiled program; log its success under its label
        (else its controller's name)."""
        t0 = time.perf_counter()
        built, batch = self._build(b, b.run)
        b.summary = built.summarise(b.exe(*batch.args(built.mx)), b.n)
        b.run_s = time.perf_counter() - t0
        a = rollout_aggregate.aggregate({"success": b.summary["success"]})["success"]
        log(f"{b.label or b.controller} on {b.preset}: success {a['mean']:.2f} "
            f"[{a['lo']:.2f}, {a['hi']:.2f}] ({b.n} episodes, {b.run_s:.1f} s)")

    def run_policy(self, label: str, checkpoint: str | None = None,
                   values: dict[str, Any] | None = None, log=print) -> list[Block]:
        """The policy's blocks again, in the programs `run` compiled, with another checkpoint
        of the same architecture (e.g. the last weights beside their moving average) and/or
        other values of traced run keys (e.g. `{"perception.sun_azimuth": 80.0}`): new blocks
        named `label` in the table."""
        extra = []
        sets = {**self.values, **(values or {})}
        for b in self.blocks:
            if b.controller != "policy" or b.exe is None:
                continue
            e = Block(b.preset, "policy", run_config(b.preset, "policy", sets,
                                                     checkpoint or self.checkpoint, self.seed),
                      b.n, exe=b.exe, label=label)
            self._run_one(e, log)
            extra.append(e)
        return extra


def table(blocks: list[Block]) -> tuple[str, list[dict]]:
    """A markdown table (success [95 % Wilson CI], collisions, MAE, CHA, ω std per block) and
    its rows as dicts."""
    rows = []
    for b in blocks:
        s = b.summary
        agg = rollout_aggregate.aggregate({k: s[k] for k in ("success", "collision", "mae", "cha",
                                                           "omega_std")})
        rows.append(
            {
                "preset": b.preset,
                "controller": b.controller,
                "label": b.label or CONTROLLERS[b.controller][0],
                "episodes": b.n,
                **{f"{k}_{q}": agg[k][q] for k in agg for q in ("mean", "lo", "hi")},
                "reasons": rollout_aggregate.reason_counts(s["reason"]),
                "compile_s": b.compile_s,
                "run_s": b.run_s,
            }
        )
    lines = ["| preset | controller | success [95 % CI] | collision | MAE [m] | CHA [rad] | "
             "ω std [rad/s] | episodes |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['label']} | {r['success_mean']:.2f} "
                     f"[{r['success_lo']:.2f}, {r['success_hi']:.2f}] | "
                     f"{r['collision_mean']:.2f} | {r['mae_mean']:.3f} | {r['cha_mean']:.3f} | "
                     f"{r['omega_std_mean']:.3f} | {r['episodes']} |")
    return "\n".join(lines), [_plain(r) for r in rows]


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x
