"""The paper's Table 3 (row navigation in each crop at its default geometry) beside ours, for
three controllers: oracle pure pursuit on the true lane centre line, SegZeros on the renderer's
ground-truth plant mask, and SegZeros on the learned segmenter's mask (shipped checkpoint);
`--controllers ... policy` adds the shipped learned policy (experiments/train_policy.py).

    python experiments/table3_navigation.py [--episodes 100] [--presets zucchini ...]
        [--controllers oracle segzeros_gt segzeros_learned policy] [--out runs/table3]
        [--image 64] [--batch-size 256] [--separate] [--smoke] [--doc docs/table3.md]

Scenario (the paper's Table 3): every preset at its default geometry (Table 1 values; typical
ones for the vineyard), a 20 m path inside the row with the goal at the row's end, control at
15 Hz, v ≤ 0.5 m/s, ω ≤ 1.0 rad/s. The episode, controller and camera settings are read from
`mjxrow/sweep/presets.yaml` (`--base`), so this table and that sweep describe one scenario; the
script replaces its preset axis by one preset at a time and sets the controller and perception
source.

Each (controller, preset) pair is one sweep (`mjxrow.sweep.run`) into
`OUT/<controller>/<preset>/`. The blocks of one preset run in one compiled program
(`SharedBlocks`: every episode runs the renderer, the segmenter and every controller, and
is driven by its own; the learned policy keeps its own program), so the table compiles one
program per preset instead of one per block; `--separate` gives each block its own. Each
block writes per-episode `results.csv`, `summary.csv`, `report.md`, and one
file per finished cell, so an interrupted run resumes where it stopped and a finished one is
only re-assembled. The markdown table goes to `OUT/table3.md`, is printed, and goes to a page
only when asked: `--doc docs/table3.md` (no default run rewrites docs/).

Metrics (rollout.metrics, as the authors' public code computes them): CHA [rad], the mean over
steps of the goal's signed bearing atan2(y_g, x_g) in the robot frame; MAE [m] and MSE [m²],
mean |dev| and mean dev² of the lateral offset from the lane centre line; ω std [rad/s], the
population std of the ω commands; success, the episode ended within 0.40 m of the goal. Each is
given as the mean over episodes with its 95 % interval (Student t; Wilson for the success rate).

SegZeros on the learned segmenter needs a checkpoint in `mjxrow/checkpoints/<crop>/` (or the
all-crop `all/`); where none is shipped the script says so and leaves that block out.
"""

from __future__ import annotations

import datetime
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from tqdm.auto import tqdm

from mjxrow import control, crops, runtime, stopwatch
from mjxrow.rollout import aggregate as rollout_aggregate
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import groups as sweep_groups
from mjxrow.sweep import run as sweep_run
from paper import cli

ROOT = Path(__file__).resolve().parents[1]  # the checkout

BASE_YAML = cli.BASE_YAML  # mjxrow/sweep/presets.yaml (package data)

# name → (label, config overrides)
CONTROLLERS: dict[str, tuple[str, dict[str, Any]]] = {
    "oracle": ("oracle pure pursuit", {"controller": {"name": "oracle"}}),
    "segzeros_gt": ("SegZeros, ground-truth mask", {
        "controller": {"name": "segzeros", "variant": "paper"},
        "perception": {"source": "ground_truth"}}),
    "segzeros_learned": ("SegZeros, learned segmenter", {
        "controller": {"name": "segzeros", "variant": "paper"},
        "perception": {"source": "learned", "checkpoint": "shipped"}}),
    "policy": ("learned policy (images → v, ω)", {
        "controller": {"name": "policy", "checkpoint": "shipped"}}),
}

# (column, title, unit, format); every cell shows mean [95 % CI].
COLUMNS: tuple[tuple[str, str, str, str], ...] = (
    ("success", "success", "", "{:.2f}"),
    ("cha", "CHA", "rad", "{:.4f}"),
    ("mae", "MAE", "m", "{:.4f}"),
    ("mse", "MSE", "m²", "{:.5f}"),
    ("omega_std", "ω std", "rad/s", "{:.3f}"),
    ("time", "time to goal", "s", "{:.1f}"),
)
DEFAULT_CONTROLLERS = cli.DEFAULT_CONTROLLERS  # `policy` on request
PAPER_METRICS = ("cha", "mae", "mse", "omega_std")
PAPER_CONTROLLERS = ("SegZeros",)  # the paper's Table 3 has one controller's row per crop
# the paper's pear values, which cannot go together (NOTES)
PEAR_MSE, PEAR_MAE = (crops.get("pear").paper["table3"][m] for m in ("mse", "mae"))


# ---------------------------------------------------------------------------------------------
# Configs


def _merge(a: dict, b: dict) -> dict:
    """Nested dict `a` updated by `b` (sections merged key by key)."""
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_base(path: str | Path = BASE_YAML) -> dict:
    """The scenario's YAML (yaml.safe_load) as a plain dict."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except OSError as e:
        raise sweep_config.ConfigError(f"{path}: cannot read ({e.strerror})") from None
    if not isinstance(raw, dict):
        raise sweep_config.ConfigError(f"{path}: expected a mapping of keys")
    return raw


def build_config(controller: str, preset: str, episodes: int, image: int | None = None,
                 base: dict | None = None, batch_size: int = 256, seed: int = 0,
                 smoke: bool = False) -> sweep_config.SweepConfig:
    """The one-cell sweep of `controller` (a CONTROLLERS key) on `preset`: the base scenario
    with `episodes` seeds, an `image` × `image` camera (None: the base's), the controller and
    perception overrides. With `smoke`, config.SMOKE shrinks it (2 episodes, 16 × 16 images,
    1.5 m paths). Raises ConfigError (e.g. a missing checkpoint) naming the dotted key."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller: unknown {controller!r}; expected one of "
                         f"{', '.join(CONTROLLERS)}")
    raw = _merge(base if base is not None else load_base(), CONTROLLERS[controller][1])
    raw.update(name=f"table3 {controller} {preset}", preset=preset, seeds=int(episodes),
               seed=int(seed), batch_size=int(max(1, min(batch_size, episodes))),
               out=f"runs/table3/{controller}/{preset}")
    if image is not None:
        raw = _merge(raw, {"camera": {"width": int(image), "height": int(image)}})
    cfg = sweep_config.from_dict(raw, BASE_YAML.parent, smoke=smoke)
    if cfg.axis_order:
        raise sweep_config.ConfigError(
            f"{', '.join(cfg.axis_order)}: the base scenario must not have grid axes besides preset"
        )
    return cfg


def checkpoint_missing(preset: str) -> str | None:
    """None if a segmenter checkpoint serves `preset`, else why not (one line)."""

    try:
        seg_checkpoint.resolve(preset)
    except ValueError:
        d = Path(seg_checkpoint.CHECKPOINT_DIR)
        d = d.relative_to(ROOT) if d.is_relative_to(ROOT) else d
        return (f"none in {d / preset}/ or {d / 'all'}/; train one with `python -m "
                f"mjxrow.seg.train --crop {preset} --export-to {d / preset}`")
    return None


# ---------------------------------------------------------------------------------------------
# Statistics and the markdown table


def block_stats(results: pd.DataFrame) -> dict[str, Any]:
    """Per metric of COLUMNS its rollout.aggregate entry (mean, lo, hi, n), plus `episodes`
    and `ends` (termination reason → count) of one block's per-episode results."""
    table = {m: results[m].to_numpy() for m, *_ in COLUMNS if m in results}
    stats: dict[str, Any] = dict(rollout_aggregate.aggregate(table))
    stats["episodes"] = len(results)
    stats["ends"] = {str(k): int(v) for k, v in results["reason"].value_counts().items()}
    return stats


def _cell(agg: dict | None, fmt: str) -> str:
    if agg is None or agg["n"] == 0 or not math.isfinite(agg["mean"]):
        return "–"
    s = fmt.format(agg["mean"])
    if math.isfinite(agg["lo"]):
        s += f" [{fmt.format(agg['lo'])}, {fmt.format(agg['hi'])}]"
    return s


def _ends(ends: dict[str, int]) -> str:
    order = [r for r in rollout_metrics.REASONS[1:] if ends.get(r)]
    return ", ".join(f"{r} {ends[r]}" for r in order) or "–"


def _paper_value(v: float | None) -> str:
    return "n/a" if v is None else f"{v:g}"


def table_markdown(stats: dict[tuple[str, str], dict], presets: list[str],
                   controllers: list[str]) -> str:
    """One pipe table: per preset the paper's row (SegZeros) then ours (one per controller
    with results); cells `mean [lo, hi]`. `stats`: (controller, preset) → block_stats."""
    head = ["crop", "controller", "episodes"] + [
        f"{t} [{u}]" if u else t for _, t, u, _ in COLUMNS] + ["how episodes ended"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for preset in presets:
        for pc in PAPER_CONTROLLERS:
            # Martini et al., Table 3 as printed (mjxrow.crops): one SegZeros row per crop
            vals = crops.get(preset).paper.get("table3") if pc == "SegZeros" else None
            if vals is None:
                cells = ["not in the paper"] + ["–"] * (len(COLUMNS) - 1)
            else:
                cells = [_paper_value(vals.get(m)) if m in PAPER_METRICS else "n/a"
                         for m, *_ in COLUMNS]
            lines.append(f"| {preset} | paper: {pc} | – | " + " | ".join(cells) + " | – |")
        for c in controllers:
            s = stats.get((c, preset))
            if s is None:
                continue
            cells = [_cell(s.get(m), fmt) for m, _, _, fmt in COLUMNS]
            lines.append(f"| {preset} | ours: {CONTROLLERS[c][0]} | {s['episodes']} | " +
                         " | ".join(cells) + f" | {_ends(s['ends'])} |")
    return "\n".join(lines)


def failures_markdown(stats: dict[tuple[str, str], dict], threshold: float = 0.95) -> str:
    """The blocks whose success rate is below `threshold`, with how their episodes ended."""
    bad = [(k, s) for k, s in stats.items() if s["success"]["mean"] < threshold]
    if not bad:
        return f"Every block succeeds in at least {threshold:.0%} of its episodes."
    lines = [f"Blocks below {threshold:.0%} success:", ""]
    for (c, p), s in bad:
        lines.append(f"- {p}, {CONTROLLERS[c][0]}: success {s['success']['mean']:.2f} "
                     f"({_ends(s['ends'])})")
    return "\n".join(lines)


NOTES = f"""\
Units: CHA in radians (the mean over control steps of the goal's signed bearing atan2(y_g, x_g)
in the robot frame, positive: goal to the left), MAE in metres, MSE in square metres (mean of
the squared lateral offset from the lane centre line), ω std in rad/s (population std of the
ω commands), time to goal in seconds (successful episodes only). Every value is the mean over
episodes with its 95 % interval: Student t for the metrics, Wilson score for the success rate.

The paper's rows are Martini et al.'s Table 3 as printed (`mjxrow.crops`): one row per crop,
the vineyard's included, for SegZeros on their learned segmenter in Gazebo; CHA in rad as its
header says (the authors' metric code computes the bearing with atan2). It gives no success
rate or time to goal ("n/a").

The paper's pear row (MSE {PEAR_MSE} with MAE {PEAR_MAE}) cannot be one set of lateral
errors in metres: for any offsets, mean dev² ≤ max|dev| · mean|dev|, so an MSE of {PEAR_MSE} m²
with an MAE of {PEAR_MAE} m would need an offset of at least {PEAR_MSE / PEAR_MAE:.0f} m inside
a 5 m wide lane. One of the two is in other units (an MSE
in cm² would be {PEAR_MSE * 1e-4:.2e} m², consistent with the MAE since MSE ≥ MAE² =
{PEAR_MAE ** 2:.2e} m²) or misprinted. Ours is MSE = mean dev² in m².
"""


def document(stats: dict[tuple[str, str], dict], presets: list[str], controllers: list[str],
             info: dict[str, Any], left_out: list[str], timings: list[str]) -> str:
    """The whole markdown page: run facts, table, failures, notes, blocks left out, timings."""
    parts = ["# Table 3: navigation at each preset's default geometry", "",
             "The paper's Table 3 scenario (20 m path inside the row, goal at the row's end, "
             "15 Hz control, v ≤ 0.5 m/s, ω ≤ 1.0 rad/s) for every preset at its default "
             "geometry, beside the paper's values. Generated by "
             "`experiments/table3_navigation.py`.", ""]
    parts += [f"- **{k}**: {v}" for k, v in info.items()]
    parts += ["", table_markdown(stats, presets, controllers), "",
              "## Where it fails", "", failures_markdown(stats), "", "## Notes", "", NOTES]
    if left_out:
        parts += ["## Blocks left out", ""] + [f"- {x}" for x in left_out] + [""]
    if timings:
        parts += ["## Run time per block (wall clock, compilation included)", ""]
        parts += [f"- {t}" for t in timings] + [""]
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------------
# Driver


def block_timing(folder: Path, cell_hash: str, ran: int, wall: float, device: str,
                 shared: str = "") -> str:
    """One line on a block's run time. A run that ran episodes records it in
    `folder/timing_<cell_hash>.json`; a resumed run (nothing left to run) reports that record,
    so the page keeps the time of the run that produced its numbers. `shared`: how the block
    shared its program (then `ran` and `wall` are those of all the blocks in it)."""
    path = folder / f"timing_{cell_hash}.json"
    if ran:
        rec = {"episodes": ran, "wall_s": round(wall, 1), "device": device,
               "date": datetime.datetime.now().isoformat(timespec="seconds"), "shared": shared}
        path.write_text(json.dumps(rec) + "\n")
        return f"{ran} episodes in {wall:.1f} s on {device}" + (f" ({shared})" if shared
                                                                 else "")
    if path.is_file():
        rec = json.loads(path.read_text())
        how = f"{rec['shared']}; " if rec.get("shared") else ""
        return (f"{rec['episodes']} episodes in {rec['wall_s']:.1f} s on {rec['device']} "
                f"({how}{rec['date']}; reused now)")
    return "finished cells reused (no timing recorded)"


def mixable(controller: str) -> bool:
    """Whether a CONTROLLERS entry can share a program with the others (rollout.build's mixed
    groups): not the learned policy, which renders its own images."""

    name = CONTROLLERS[controller][1]["controller"]["name"]
    return getattr(control.get(name), "make_policy", None) is None


class SharedBlocks:
    """sweep.run's evaluator for the blocks of one preset that share a program: the first
    block asked runs the unfinished episodes of all of them in one mixed program
    (rollout.build: every episode runs every controller's stages and is driven by its own);
    each block then takes its own rows. Blocks whose groups would differ in field shape run
    one by one instead. `blocks`: the blocks' sweep configs and folders, by config name."""

    def __init__(self, blocks: dict[str, tuple[sweep_config.SweepConfig, Path]]):
        self.blocks = blocks
        self.rows: dict[str, pd.DataFrame] | None = None
        self.episodes = 0

    def __call__(self, group, cfg: sweep_config.SweepConfig, on_batch_done) -> pd.DataFrame:
        if self.rows is None:
            self.rows = self._evaluate_all()
        rows = self.rows.pop(cfg.name)
        on_batch_done(rows)
        return rows

    def _evaluate_all(self) -> dict[str, pd.DataFrame]:

        flat = [(name, g) for name, (cfg, folder) in self.blocks.items()
                for g in sweep_groups.pending(cfg, folder) if g.episodes]
        self.episodes = sum(len(g.episodes) for _, g in flat)
        if len({g.shape for _, g in flat}) > 1:  # fields of other shapes: one by one
            parts: dict[str, list[pd.DataFrame]] = {name: [] for name in self.blocks}
            for name, g in flat:
                parts[name].append(
                    sweep_groups.evaluate_group(g, self.blocks[name][0], lambda r: None)
                )
            return {name: pd.concat(ps, ignore_index=True) if ps else pd.DataFrame()
                    for name, ps in parts.items()}
        runs = {(name, c.index): c.cfg for name, g in flat for c in g.cells}
        built = rollout_build.build(list(runs.values()), flat[0][1].shape)
        items = [(name, runs[(name, c)], c, e) for name, g in flat for c, e in g.episodes]
        size = built.padded(min(sum(cfg.batch_size for cfg, _ in self.blocks.values()),
                                len(items)))
        rows = sweep_groups.evaluate_episodes(built, [it[1:] for it in items], size)
        tags = pd.Series([it[0] for it in items])
        return {name: rows[(tags == name).to_numpy()].reset_index(drop=True)
                for name in self.blocks}


def run_table(presets: list[str], controllers: list[str], episodes: int, out: str | Path,
              image: int | None = None, batch_size: int = 256, seed: int = 0,
              smoke: bool = False, base: dict | None = None, evaluate=None,
              progress: bool = True, command: str = "", hard_stop: bool = False,
              share: bool = True) -> tuple[str, dict]:
    """Run (or resume) every (controller, preset) block into OUT/<controller>/<preset>/ and
    assemble the markdown page. `evaluate`: sweep.run's evaluator (None: the real one; tests
    inject a fake). With `share` (and the real evaluator) the blocks of a preset run in one
    program (`SharedBlocks`; the learned policy keeps its own). Returns (markdown, stats by
    (controller, preset))."""
    import jax


    watch, programs0 = stopwatch.Stopwatch(), rollout_build.program_count()
    out = Path(out)
    base = base if base is not None else load_base()
    devs = jax.devices()
    device = f"{len(devs)} × {devs[0].device_kind}"
    stats: dict[tuple[str, str], dict] = {}
    left_out, timings = [], []
    todo: list[tuple[str, str]] = []
    for p in presets:
        for c in controllers:
            if c == "segzeros_learned" and (why := checkpoint_missing(p)) is not None:
                msg = f"{CONTROLLERS[c][0]} on {p}: no segmenter checkpoint: {why}"
                left_out.append(msg)
                tqdm.write(f"skipped: {msg}", file=sys.stderr)
            else:
                todo.append((c, p))
    configs = {b: build_config(*b, episodes, image, base, batch_size, seed, smoke)
               for b in todo}
    shared: dict[tuple[str, str], SharedBlocks] = {}
    if share and evaluate is None:
        for p in presets:
            mine = [(c, q) for c, q in todo if q == p and mixable(c)]
            if len(mine) > 1:
                ev = SharedBlocks({configs[b].name: (configs[b], out / b[0] / b[1])
                                   for b in mine})
                shared.update({b: ev for b in mine})
    bar = tqdm(todo, desc="table3 blocks", unit="block", disable=not progress, position=0)
    cfg, done = None, []
    for c, p in bar:
        bar.set_postfix_str(f"{c} / {p}")
        cfg = configs[(c, p)]
        t0 = time.perf_counter()
        res = sweep_run.run(
            cfg,
            out / c / p,
            evaluate=shared.get((c, p), evaluate),
            progress=progress,
            command=command,
            hard_stop=hard_stop,
        )  # Ctrl-C: finished cells kept
        if runtime.writer():  # several processes: process 0 reads and writes
            stats[(c, p)] = block_stats(pd.read_csv(res["files"]["results"]))
            done.append(((c, p), res["groups"][0].hashes[0], res["ran"],
                         time.perf_counter() - t0))
    for b, cell_hash, ran, wall in done:  # blocks that shared a program: its time, once
        ev, note = shared.get(b), ""
        if ev is not None:
            mates = [x for x, e in shared.items() if e is ev]
            note = "one program with " + ", ".join(CONTROLLERS[x[0]][0] for x in mates)
            wall = sum(w for x, _, _, w in done if x in mates)
            ran = ev.episodes if ran else 0
        timings.append(f"{b[1]}, {CONTROLLERS[b[0]][0]}: " + block_timing(
            out / b[0] / b[1], cell_hash, ran, wall, device, note))
    bar.close()
    if runtime.writer():
        print(
            f"{len(todo)} blocks, {rollout_build.program_count() - programs0} closed-loop "
            f"programs; "
            f"{watch.line()}",
            file=sys.stderr,
        )
    for c in CONTROLLERS:
        if c not in controllers:
            missing = [p for p in presets if c == "segzeros_learned" and checkpoint_missing(p)]
            left_out.append(f"{CONTROLLERS[c][0]}: not run (not in --controllers)" + (
                f"; no segmenter checkpoint is shipped for {', '.join(missing)}" if missing
                else ""))
    ref = cfg or build_config(controllers[0], presets[0], episodes, image, base, batch_size,
                              seed, smoke)
    sz = build_config("segzeros_gt", presets[0], episodes, image, base, batch_size, seed, smoke)
    info = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
            "command": f"`{command}`" if command else "(API call)",
            "device": device,
            "episodes per block": ref.seeds,
            "episode": f"{ref.sim.path_length:g} m path, timeout {ref.episode.max_time:g} s, "
                       f"start offset std {ref.episode.start_offset_std:g} m, start heading std "
                       f"{ref.episode.start_yaw_std:g}°",
            "camera": f"{ref.camera.width} × {ref.camera.height} px, fovy "
                      f"{ref.camera.fovy:g}°, pitch {ref.robot.cam_pitch_deg:g}°, height "
                      f"{ref.robot.cam_height:g} m",
            "SegZeros": f"{sz.controller.variant} law, ω gain {sz.controller.omega_gain:g}, "
                        f"v max {sz.controller.v_max:g}; sky/lighting "
                        f"{sz.perception.condition}",
            "results": f"`{out}/<controller>/<preset>/results.csv`"}
    if smoke:
        info["smoke"] = "tiny check run (--smoke): not the paper's scenario"
    elif ref.seeds < 100:
        info["note"] = (f"{ref.seeds} episodes per block, fewer than the 100 of the full table "
                        "(`python experiments/table3_navigation.py`): wide intervals")
    md = document(stats, presets, controllers, info, left_out, timings)
    return md, stats


def main(argv: list[str] | None = None) -> int:
    p = cli.table3()
    args = p.parse_args(argv)
    args.presets = args.presets or list(crops.names())
    if args.episodes < 1 or (args.image is not None and args.image < 8):
        p.error("--episodes must be ≥ 1 and --image ≥ 8")
    out = Path(args.out + "_smoke" if args.smoke else args.out)
    command = "python experiments/table3_navigation.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    try:
        runtime.setup(args)
    except ValueError as e:
        p.error(str(e))
    try:
        base = load_base(args.base)
        md, stats = run_table(args.presets, args.controllers, args.episodes, out, args.image,
                              args.batch_size, args.seed, args.smoke, base,
                              progress=not args.no_progress, command=command.strip(),
                              hard_stop=True, share=not args.separate)
    except sweep_config.ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted: finished cells are kept in {out}; run the same command again to "
              "resume", file=sys.stderr)
        return 130
    if not runtime.writer():
        return 0
    out.mkdir(parents=True, exist_ok=True)
    (out / "table3.md").write_text(md)
    (out / "table3.json").write_text(json.dumps(
        {f"{c}/{p}": s for (c, p), s in stats.items()}, indent=1, default=float) + "\n")
    doc = args.doc  # docs/table3.md only when asked
    if doc:
        Path(doc).parent.mkdir(parents=True, exist_ok=True)
        Path(doc).write_text(md)
    print(md)
    print(f"written: {out / 'table3.md'}" + (f", {doc}" if doc else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
