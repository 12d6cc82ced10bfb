"""The learning curve of a training run: `read_log` reads its `train_log.jsonl` (one line per
iteration, as `loop.train` writes it), `plot_curve` draws it as a PNG."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def read_log(path: str | Path) -> list[dict]:
    p = Path(path)
    if not p.is_file():
        return []
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def _smooth(ax, x, y, *style, **kw):
    """A centred moving mean of `y` (over the finite points; at the ends, over the points
    there are)."""
    ok = np.isfinite(y)
    if ok.sum() > 4:
        w = max(1, ok.sum() // 20)
        kernel = np.ones(w)
        mean = np.convolve(y[ok], kernel, mode="same") / np.convolve(
            np.ones(ok.sum()), kernel, mode="same")
        ax.plot(x[ok], mean, *style, **kw)


def plot_curve(log_path: str | Path, png: str | Path) -> Path:
    """Learning curve from a train_log.jsonl: episode return, success rate (and each preset's,
    where several trained together), episode length
    (seconds to the goal, of the episodes that reach it) and env-steps/s over env steps, the
    BC → PPO switch marked where both phases ran (matplotlib, Agg backend). The curriculum's
    rounds have their own figure (`curriculum.plot_rounds`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_log(log_path)
    png = Path(png)
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.6))
    x = np.array([r["env_steps"] for r in rows], float) / 1e6
    series = (("return", "episode return"), ("nav/success", "success rate"),
              ("nav/time", "episode length [s] (to the goal)"))
    for ax, (k, title) in zip(axes[:3], series, strict=True):
        y = np.array([r.get(k, np.nan) for r in rows], float)
        ax.plot(x, y, ".", ms=3, alpha=0.4)
        _smooth(ax, x, y, "-", lw=1.5, label="all" if k == "nav/success" else None)
        ax.set_title(title)
    presets = [k for k in (rows[-1] if rows else {}) if k.startswith("success/")]
    for k in presets:  # each preset's success (thin lines), where several trained together
        _smooth(axes[1], x, np.array([r.get(k, np.nan) for r in rows], float), "-", lw=0.8,
                label=k.split("/", 1)[1])
    if presets:
        axes[1].legend(fontsize=7)
    axes[3].plot(x, [r["rollout_steps_per_s"] for r in rows], label="rollout")
    axes[3].plot(x, [r["steps_per_s"] for r in rows], label="with updates")
    axes[3].set_title("env-steps/s")
    axes[3].legend()
    phases = [r["phase"] for r in rows]  # the BC → PPO switch, where both phases ran
    switch = next((r["env_steps"] / 1e6 for i, r in enumerate(rows)
                   if r["phase"] == "ppo" and "bc" in phases[:i]), None)
    for ax in axes:
        ax.set_xlabel("env steps [M]")
        if switch is not None:
            ax.axvline(switch, color="grey", ls="--", lw=0.8)
    fig.suptitle("policy training" + (" (dashed: BC/DAgger → PPO)" if switch is not None
                                      else f" ({phases[0] if phases else 'no'} iterations)"))
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
