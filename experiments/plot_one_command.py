"""The one-command policies side by side: pear's success at its default geometry for every
command from a fresh network (100 episodes, 95 % Wilson interval; the last weights and, where
kept, their moving average) and pear's success in the sampled training rollouts as the teacher's
share β falls.

    python experiments/plot_one_command.py [--runs docs/data/one_command_runs.csv]
        [--rollouts docs/data/one_command_pear_rollouts.csv] [--out docs/one_command_pear.png]

The CSVs hold the measured commands (docs/training.md, fifth round). An existing --out is
replaced only when this script wrote it (the PNG's `Software` entry names it); anything else
there is an error (exit 2), left as it is.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
GOAL = 0.97  # the pear goal (within 2 points of SegZeros' 0.99-1.00)
TAG = "mjxrow experiments/plot_one_command.py"  # the PNG's Software entry
SEED_STYLES = ("-", ":", "--", "-.")  # a training seed's line style


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", default=str(ROOT / "docs/data/one_command_runs.csv"))
    p.add_argument("--rollouts", default=str(ROOT / "docs/data/one_command_pear_rollouts.csv"))
    p.add_argument("--out", default=str(ROOT / "docs/one_command_pear.png"))
    p.add_argument("--episodes", type=int, default=100, help="episodes per evaluation")
    return p


def _read(path: str, key: str) -> list[dict]:
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        raise ValueError(f"{key}: cannot read {path} ({e.strerror})") from None
    if not rows:
        raise ValueError(f"{key}: {path} has no rows")
    return rows


def interval(p: float, n: int) -> tuple[float, float]:
    """The 95 % Wilson interval of a success rate p over n episodes."""
    from mjxrow.rollout import aggregate

    k = round(p * n)
    a = aggregate.aggregate({"success": np.arange(n) < k})["success"]
    return a["lo"], a["hi"]


def plot(runs: list[dict], rollouts: list[dict], out: Path, n: int) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recipes = list(dict.fromkeys(r["recipe"] for r in runs))
    palette = plt.cm.tab20.colors  # more recipes than tab10 has colours
    colors = {r: palette[i % len(palette)] for i, r in enumerate(recipes)}
    commands = list(dict.fromkeys((r["date"], r["device"], r["recipe"], r["seed"],
                                   r["iterations"]) for r in runs))
    # the commands above (as wide as they need), the training rollouts below
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(max(12.0, 0.5 * len(commands) + 3), 9.5),
                                 gridspec_kw={"height_ratios": [1.1, 1]})
    for x, c in enumerate(commands):
        mine = {r["weights"]: float(r["pear"]) for r in runs
                if (r["date"], r["device"], r["recipe"], r["seed"], r["iterations"]) == c}
        col = colors[c[2]]
        for w, marker, dx in (("last", "o", -0.12), ("average", "s", 0.12)):
            if w not in mine:
                continue
            lo, hi = interval(mine[w], n)
            ax.errorbar(x + dx, mine[w], yerr=[[mine[w] - lo], [hi - mine[w]]], fmt=marker,
                        color=col, mfc=col if w == "average" else "white", capsize=3)
        if len(mine) == 2:
            ax.plot([x - 0.12, x + 0.12], [mine["last"], mine["average"]], color=col, lw=0.8)
    ax.axhline(GOAL, color="k", ls="--", lw=0.8)
    ax.text(len(commands) - 0.5, GOAL + 0.01, f"goal {GOAL}", ha="right", va="bottom", fontsize=8)
    ax.set_xticks(range(len(commands)))
    ax.set_xticklabels([f"{'H100' if 'H100' in c[1] else 'H200'}\nseed {c[3]}\n{c[4] or '?'} it"
                        for c in commands], fontsize=7)
    ax.set_ylabel("pear success, default geometry (95 % CI)")
    ax.set_ylim(0, 1.05)
    handles = [plt.Line2D([], [], color=colors[r], marker="o", ls="", label=r) for r in recipes]
    handles += [plt.Line2D([], [], color="gray", marker="o", mfc="white", ls="", label="last "
                           "weights"), plt.Line2D([], [], color="gray", marker="s", ls="",
                                                  label="moving average (0.8)")]
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("one command from a fresh network: pear at its default geometry", fontsize=9)

    for (recipe, seed), group in _groups(rollouts).items():
        it = [int(r["iteration"]) for r in group if r["pear_rollout_success"]]
        s = [float(r["pear_rollout_success"]) for r in group if r["pear_rollout_success"]]
        bx.plot(it, s, color=colors.get(recipe, "k"), ls=SEED_STYLES[int(seed) % 4],
                label=f"{recipe}, seed {seed}")
        b = [(int(r["iteration"]), float(r["beta"])) for r in group]
        bx.plot(*zip(*b, strict=True), color=colors.get(recipe, "k"), lw=0.6, alpha=0.5)
    bx.set_xlabel("iteration")
    bx.set_ylabel("pear success in the sampled rollouts (thick); β (thin)")
    bx.set_ylim(0, 1.05)
    bx.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    bx.set_title("training rollouts (action noise, field variety)", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": TAG})
    plt.close(fig)
    return out


def written_by(path: Path, tag: str = TAG) -> bool:
    """Whether `path` is a PNG whose `Software` entry is `tag` (this script's by default)."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return im.info.get("Software") == tag
    except (OSError, ValueError):
        return False


def _groups(rows: list[dict]) -> dict:
    out: dict = {}
    for r in rows:
        out.setdefault((r["recipe"], r["seed"]), []).append(r)
    return out


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    out = Path(args.out)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes: must be ≥ 1, got {args.episodes}")
        if out.exists() and not written_by(out):
            raise ValueError(f"--out: {out} exists and was not written by this script; "
                             "choose another path")
        runs, rollouts = _read(args.runs, "--runs"), _read(args.rollouts, "--rollouts")
        for key, rows, cols in (("--runs", runs, ("recipe", "seed", "weights", "pear")),
                                ("--rollouts", rollouts, ("recipe", "seed", "iteration", "beta",
                                                          "pear_rollout_success"))):
            missing = [c for c in cols if c not in rows[0]]
            if missing:
                raise ValueError(f"{key}: missing column {missing[0]!r}")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(plot(runs, rollouts, out, args.episodes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
