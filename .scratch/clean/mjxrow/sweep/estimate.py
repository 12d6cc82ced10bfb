"""Memory and time of a sweep, estimated before it starts, from its static shapes alone.

Memory of one group = its batch (episodes per call) × the bytes of one episode, doubled for XLA's
temporaries, plus a fixed overhead for the program and the model. The bytes of one episode are
counted from the arrays it holds: the per-step log (every control step), the field (plants,
rows, terrain), the terrain patch of its MJX model, the MJX state (PHYSICS_BYTES, measured on the
robot model) and the renderer's working set per pixel (RENDER_BYTES_PER_PIXEL, an upper figure
for the ray caster's candidate buffers). The estimate is an upper figure: it is meant to refuse
`camera.width: 2048` at batch 256 on a laptop, not to predict the last megabyte.

Time is the number of control steps (episodes × steps to the timeout: an upper figure, most
episodes end earlier) over the best closed-loop rate of `benchmarks.jsonl` measured on this kind
of device, plus its compile time once per group; without a measurement, only the step count.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import os
from pathlib import Path

import jax

from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import episode as rollout_episode
from mjxrow.sweep import groups as sweep_groups

PHYSICS_BYTES = 1 << 20  # MJX model data + state of one world, with the solver's temporaries
RENDER_BYTES_PER_PIXEL = 512  # rays, depth, colour, candidate plants per tile
LOG_FLOATS_PER_STEP = 10  # pose 3, cmd 2, vel 2, alive, event, slack
FIELD_FLOATS_PER_PLANT = 12  # position 3, size 3, yaw, phase, active, row, slack
# peak = overhead + factor × batch × episode_bytes, fitted to measured peaks per platform: on a
# CPU, the process's RSS (Python, JAX, XLA compiling the closed loop, the MJX model); on an
# accelerator, the device's peak bytes in use (report.md's `memory peak` gives both)
CALIBRATION = {"cpu": (1.83 * 2**30, 3.84),  # sweeps.yaml --smoke 2.00 GB at B = 8, the full
                                             # sweep 4.85 GB at B = 216 (2-core CPU, 2026-11-26)
               "gpu": (64 * 2**20, 0.70)}  # device peak 0.55 GiB at B = 216, 9.31 GiB at
                                           # B = 4,104 (sweeps.yaml, one H100, 2026-11-26)
# the closed-loop figures of benchmarks.jsonl the estimate uses (`rates`), as package data
THROUGHPUT = Path(str(importlib.resources.files("mjxrow.sweep").joinpath("throughput.json")))


@dataclasses.dataclass(frozen=True)
class Estimate:
    peak_bytes: int  # largest group: overhead + factor × batch × per-episode bytes
    episode_bytes: int  # per episode, of the largest group
    batch: int  # episodes per call of that group
    control_steps: int  # every episode to its timeout
    seconds: float | None  # None: no closed-loop measurement for this device
    groups: int
    basis: str = ""  # what the time assumes: device, measured rate or none

    def text(self) -> str:
        t = (f", at most about {_duration(self.seconds)} ({self.control_steps:,} control steps "
             f"if every episode ran to its timeout, {self.basis})"
             if self.seconds is not None else
             f", {self.control_steps:,} control steps at most ({self.basis}: no time estimate)")
        return (f"estimated peak memory {_gib(self.peak_bytes)} (batch {self.batch} × "
                f"{_gib(self.episode_bytes)} per episode){t}")


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def episode_bytes(cell_cfg, shape) -> int:
    """Upper figure of the bytes one episode of a cell holds during its rollout."""
    ep = cell_cfg.episode.static()
    steps = -(-ep.n_steps // rollout_episode.CHUNK) * rollout_episode.CHUNK
    log = steps * LOG_FLOATS_PER_STEP * 4 * 2
    ny, nx = shape.terrain_cells
    field = (shape.max_rows * shape.max_plants_per_row * FIELD_FLOATS_PER_PLANT
             + ny * nx + 8 * shape.obstacle_slots) * 4
    py, px = ep.sim.patch_cells
    patch = py * px * 4 * 2
    pixels = cell_cfg.camera.width * cell_cfg.camera.height
    return int(log + field + patch + PHYSICS_BYTES + pixels * RENDER_BYTES_PER_PIXEL)


def available_bytes() -> tuple[int, str]:
    """Memory the batch can use and where: the first accelerator's limit, else the host's
    available memory."""
    dev = jax.devices()[0]
    if dev.platform != "cpu":
        stats = dev.memory_stats() or {}
        limit = stats.get("bytes_limit")
        if limit:
            n = len(jax.devices())
            return int(limit) * n, f"{n} × {dev.device_kind}"
    try:
        import psutil

        return int(psutil.virtual_memory().available), "this machine's available memory"
    except ImportError:
        pages = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        return int(pages), "this machine's free memory"


def rates(lines: list[str]) -> dict[str, list[float]]:
    """{device: [control steps/s, compile s]} for the estimate, from `lines` (benchmarks.jsonl):
    the latest sweep's own rate on the device where one is recorded (`control_steps_per_s` of a
    `sweep` row: a sweep runs as the estimate assumes, e.g. on one XLA device of a CPU), else
    the fastest closed-loop benchmark there. `THROUGHPUT` (package data) holds these figures of
    the repository's benchmarks.jsonl (tests/test_sweep.py checks that it is current)."""
    bench: dict[str, list[float]] = {}
    sweep: dict[str, list[float]] = {}
    for line in lines:
        try:
            r = json.loads(line)
        except json.JSONDecodeError:
            continue
        d = r.get("device")
        if r.get("stage") == "sweep" and "control_steps_per_s" in r:
            sweep[d] = [float(r["control_steps_per_s"]), float(r.get("compile_s") or 0.0)]
        elif r.get("stage") == "closed_loop" and r.get("unit") == "control steps/s" and \
                (d not in bench or r["value"] > bench[d][0]):
            bench[d] = [float(r["value"]), float(r.get("compile_s") or 0.0)]
    return dict(sorted((bench | sweep).items()))


def _rate(device: str) -> tuple[float, float] | None:
    """(control steps/s, compile s) of the fastest closed-loop benchmark on `device`."""
    rate = json.loads(THROUGHPUT.read_text()).get(device)
    return None if rate is None else (rate[0], rate[1])


def estimate(groups, seeds: int, batch_size: int | str, device: str, platform: str = "cpu",
             devices: int = 1) -> Estimate:
    """The estimate of a planned sweep (`groups.plan` groups; only the episodes still to run),
    with `batch_size` (an int or `auto`) resolved as the run resolves it (`groups.batch_size`);
    device: its name in benchmarks.jsonl (`cpu` or the accelerator's kind)."""
    peak, per, batch, steps, n_groups = 0, 0, 0, 0, 0
    for g in groups:
        if not g.episodes:
            continue
        n_groups += 1
        cfg = g.cells[0].cfg
        b = sweep_groups.batch_size(batch_size, seeds, len(g.episodes), platform, devices)
        e = episode_bytes(cfg, g.shape)
        steps += len(g.episodes) * cfg.episode.static().n_steps
        if b * e > batch * per:
            per, batch = e, b
        overhead, factor = CALIBRATION["cpu" if platform == "cpu" else "gpu"]
        peak = max(peak, int(factor * b * e + overhead))
    rate = _rate(device)
    seconds = None if rate is None or not steps else steps / rate[0] + n_groups * rate[1]
    basis = (f"at {rate[0]:,.0f} control steps/s and {rate[1]:.0f} s of compiling per group, "
             f"measured on {device} (benchmarks.jsonl)"
             if rate is not None else f"no closed-loop measurement on {device}")
    return Estimate(peak, per, batch, steps, seconds, n_groups, basis)


def check(est: Estimate, force: bool = False, key: str = "batch_size") -> str:
    """The estimate as a line; ValueError (with the estimate) when the peak memory exceeds what
    the machine has, unless `force`."""
    have, where = available_bytes()
    line = est.text()
    if est.peak_bytes > have and not force:
        raise ValueError(f"{key}: {line}, more than {where} ({_gib(have)}); lower {key} or "
                         f"the image size, or pass --force to run anyway")
    return line + ("" if est.peak_bytes <= have else f" (beyond {where}: --force)")


def check_episodes(run, n: int, force: bool = False) -> str:
    """`check` for one batch of `n` episodes of one RunConfig (the episode command)."""

    e = episode_bytes(run, rollout_build.fit_shape([run]))
    steps = n * run.episode.static().n_steps
    overhead, factor = CALIBRATION["cpu" if jax.default_backend() == "cpu" else "gpu"]
    return check(Estimate(int(factor * n * e + overhead), e, n, steps, None, 1), force, "--n")


__all__ = ["check_episodes", "Estimate", "available_bytes", "check", "episode_bytes", "estimate"]
