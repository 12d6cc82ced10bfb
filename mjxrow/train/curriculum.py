"""The adversarial curriculum: every `every` iterations the failure search (`mjxrow.search`)
runs against the CURRENT policy, and the fields it finds failing go into a pool that a fixed
`share` of every batch of resets of one environment draws from (`env.randomize.Pool`), so that
training goes where the policy breaks.

    cur = Curriculum(CurriculumConfig(search="searches/policy_variety.yaml", every=20),
                     presets, ranges_of_each_env)
    pools = cur.pools()                          # traced: one compiled rollout for every pool
    row = cur.round(policy_dir, out / "adversary", iteration)   # the search, the new pool

Round 0 runs before the first iteration (the starting policy's failure rate), round k after
iteration k · `every`. A round is one search folder `OUT/adversary/round_<k>/` (the search's
own outputs: candidates, failures, state), run with the search's YAML, its controller replaced
by `policy` on the checkpoint being trained, its budget `episodes` episodes (the same every
round, so that the failure rates compare), no baseline, seed k. Its summary row (failing
episodes per 1,000, failing candidates, distinct failures) goes to `OUT/adversary.jsonl`: the
failure rate the search finds against the policy over the training run, plotted in the
learning curve.

The pool holds the searched values of the box's keys for the environment of the search's
preset (its field keys, and `perception.sun_azimuth`: the sun turned there in whichever sky
the reset draws); every other value of a pooled reset is drawn as usual. The box must lie inside
that environment's randomisation ranges (checked when the curriculum is built), so a searched
field is a field the environment can hold.

With `mirror_sun` (default), a failing candidate with a sun azimuth a (degrees from the rows'
direction) enters the pool twice: as found, then with the sun at 360° − a, its mirror image
across the rows. The fields are drawn alike on the left and the right, so a policy that fails
with the sun on one side is trained with it on both sides too. Without the mirror, a search
that finds one side first pulls the policy towards that side only.
"""

from __future__ import annotations

import dataclasses
import json
import threading
from pathlib import Path
from typing import Any

import numpy as np

from mjxrow.env import randomize as env_randomize


@dataclasses.dataclass(frozen=True)
class CurriculumConfig:
    """Settings of the adversarial curriculum (`train.curriculum.<key>`); no `search`: off."""

    search: str = ""  # a search YAML (e.g. searches/policy_variety.yaml); '' for none
    every: int = 20  # iterations between searches (the first after `every` iterations)
    share: float = 0.25  # share of every batch of resets taken from the searched failures
    episodes: int = 512  # the search's budget per round, in episodes (equal every round)
    pool: int = 64  # rows in the pool: the failures of the latest rounds, newest first
    sets: tuple[str, ...] = ()  # `--set` overrides of the search config (KEY=VALUE)
    smoke: bool = False  # the search's --smoke settings (a CPU check of the training command)
    mirror_sun: bool = True  # a failing sun also pooled mirrored across the rows (module doc)

    def __post_init__(self):
        if self.every < 1:
            raise ValueError(f"train.curriculum.every: must be at least 1, got {self.every}")
        if not 0.0 <= self.share <= 1.0:
            raise ValueError(f"train.curriculum.share: must lie in [0, 1], got {self.share}")
        if not isinstance(self.mirror_sun, bool):
            raise ValueError(f"train.curriculum.mirror_sun: must be true or false, got "
                             f"{self.mirror_sun!r}")
        for name in ("episodes", "pool"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"train.curriculum.{name}: must be at least 1, got "
                                 f"{getattr(self, name)}")

    @property
    def on(self) -> bool:
        return bool(str(self.search).strip())


def search_config(cfg: CurriculumConfig, checkpoint: str | Path | None, seed: int = 0,
                  image: tuple[int, int] | None = None):
    """The SearchConfig of one round: the YAML's search against the `policy` controller on
    `checkpoint` (None: the shipped one, for checks before training), `cfg.episodes`
    episodes, no baseline, seed `seed`; `image` (height, width): the camera's size in pixels,
    the images the policy is trained on (None: the YAML's)."""
    from mjxrow.search import config as search_config

    sets = [*cfg.sets, "controller.name=policy",
            f"controller.checkpoint={checkpoint or 'shipped'}",
            f"budget.episodes={cfg.episodes}", "budget.minutes=null",
            "budget.failures=null", "baseline=none", f"seed={seed}"]
    if image is not None:
        sets += [f"camera.height={int(image[0])}", f"camera.width={int(image[1])}"]
    try:
        return search_config.load(cfg.search, sets, smoke=cfg.smoke)
    except (search_config.ConfigError, OSError) as e:
        raise ValueError(f"train.curriculum.search: {cfg.search}: {e}") from None


def pool_rows(failing: list[dict[str, Any]], ranges) -> np.ndarray:
    """Pool rows [n, k] (NaN: drawn) of failing candidates ({dotted key: value}), in the order
    of `env.randomize.pool_keys` of an environment's `ranges` ((name, lo, hi), ...)."""
    keys = env_randomize.pool_keys(ranges)
    rows = np.full((len(failing), len(keys)), np.nan, np.float32)
    for i, cand in enumerate(failing):
        for j, key in enumerate(keys):
            v = cand.get(key)
            if v is not None:
                rows[i, j] = float(v)
    return rows


def mirror_sun(rows: np.ndarray, ranges) -> np.ndarray:
    """Pool rows (`pool_rows`'s) each followed by its mirror image across the rows: the sun's
    azimuth a turned to 360° − a (mod 360). Rows without a sun, or with the sun along the
    rows (0° or 180°, their own mirror), stay single."""
    j = env_randomize.pool_keys(ranges).index("perception.sun_azimuth")
    out = []
    for r in rows:
        out.append(r)
        a = r[j]
        if not np.isnan(a) and not np.isclose(np.mod(a, 180.0), 0.0):
            m = r.copy()
            m[j] = np.mod(360.0 - a, 360.0)
            out.append(m)
    return np.stack(out) if out else rows


def check_box(box, ranges, preset: str) -> None:
    """ValueError naming the first box key that the environment of `preset` does not randomise,
    or whose searched range reaches outside the environment's (the sun's azimuth, an angle, is
    taken anywhere)."""
    have = {n: (lo, hi) for n, lo, hi in ranges}
    for d in box:
        section, _, name = d.key.partition(".")
        if d.key in env_randomize.POOL_EXTRA and not d.choices:
            continue
        if section != "field" or d.choices:
            raise ValueError(f"train.curriculum.search: box key {d.key}: only numeric field "
                             f"keys and {', '.join(env_randomize.POOL_EXTRA)} can seed "
                             "training resets")
        if name not in have:
            raise ValueError(f"train.curriculum.search: box key {d.key} is not randomised by "
                             f"the {preset} environment (env.randomize.ranges)")
        lo, hi = have[name]
        if d.low < lo - 1e-9 or d.high > hi + 1e-9:
            raise ValueError(f"train.curriculum.search: box key {d.key} [{d.low:g}, "
                             f"{d.high:g}] reaches outside the {preset} environment's range "
                             f"[{lo:g}, {hi:g}]")


class Curriculum:
    """The pools of a training run's environments and the rounds that fill them (module doc).
    `presets` and `ranges` are the training environments', in order; `checkpoint` a policy of
    the run's observation and network (None: the shipped one) to check the search against;
    `image` (height, width) the run's camera size, which the searches take."""

    def __init__(self, cfg: CurriculumConfig, presets, ranges,
                 checkpoint: str | Path | None = None, image: tuple[int, int] | None = None):
        self.cfg = cfg
        self.image = image
        self.ranges = tuple(ranges)
        self.rows = [np.zeros((0, len(env_randomize.pool_keys(r))), np.float32)
                     for r in self.ranges]
        self.target = None
        if cfg.on:  # the search's config checked against a checkpoint of this run's network
            # the search and its dependencies (evosax) imported now, not after the compilation
            from mjxrow.search import run as search_run

            self._search = search_run
            scfg = search_config(cfg, checkpoint, image=image)
            preset = scfg.scenario.preset
            if preset not in presets:
                raise ValueError(f"train.curriculum.search: the search's preset {preset!r} is "
                                 f"not trained (train.presets: {', '.join(presets)})")
            self.target = list(presets).index(preset)
            check_box(scfg.box, self.ranges[self.target], preset)

    def pools(self) -> tuple[env_randomize.Pool, ...]:
        """One pool per environment (empty where no search feeds it)."""
        return tuple(env_randomize.make_pool(r, self.cfg.pool, self.cfg.share)
                     for r in self.rows)

    def load(self, pools) -> None:
        """Take the rows of saved pools (a resumed run's)."""
        for i, pool in enumerate(pools):
            self.rows[i] = np.asarray(pool.values, np.float32)[:int(pool.count)]

    def due(self, iteration: int) -> bool:
        return self.target is not None and iteration > 0 and iteration % self.cfg.every == 0

    def add(self, failing: list[dict[str, Any]]) -> int:
        """Put failing candidates (with their mirrored suns: `mirror_sun`) first in their
        environment's pool (the oldest drop out of its `pool` rows); returns the pool's
        size."""
        i = self.target
        new = pool_rows(failing, self.ranges[i])
        if self.cfg.mirror_sun:
            new = mirror_sun(new, self.ranges[i])
        self.rows[i] = np.concatenate([new, self.rows[i]], 0)[:self.cfg.pool]
        return len(self.rows[i])

    def prepare(self, checkpoint: str | Path) -> float:
        """Compile the rounds' search program ahead (`search.run.prepare`) against the policy
        at `checkpoint` (any weights of the run's network); returns the seconds it took."""
        return self._search.prepare(search_config(self.cfg, checkpoint, image=self.image))

    def prepare_ahead(self, checkpoint: str | Path) -> Ahead:
        """`prepare` in a thread of its own (e.g. beside the training's compilation); the
        returned `Ahead`'s `wait` joins it."""
        return Ahead(self.prepare, checkpoint)

    def round(self, checkpoint: str | Path, folder: str | Path, iteration: int,
              log_path: str | Path | None = None) -> dict[str, Any]:
        """Search against the policy at `checkpoint`, refill the pool, append the summary to
        `log_path` (JSON lines). Returns the summary row."""
        k = iteration // self.cfg.every
        scfg = search_config(self.cfg, checkpoint, seed=k, image=self.image)
        res = self._search.run(scfg, Path(folder) / f"round_{k:03d}", progress=False,
                             figures=False)
        cands = res["candidates"]
        fails = cands[cands["outcome"] == "fail"] if len(cands) else cands
        keys = [d.key for d in scfg.box]
        failing = [{key: r[key] for key in keys} for _, r in fails.iterrows()]
        size = self.add(failing)
        s = res["summary"].iloc[0]
        row = {"iteration": iteration, "round": k, "episodes": int(s["episodes"]),
               "failing_episodes": int(s["failing_episodes"]),
               "failing_per_1000": float(s["failing_per_1000"]),
               "failing_candidates": int(s["failing_candidates"]),
               "distinct_failures": int(s["distinct_failures"]), "pool": size,
               "search_s": round(float(res["wall_s"]), 1)}
        if log_path is not None:
            with Path(log_path).open("a") as f:
                f.write(json.dumps(row) + "\n")
        return row


class Ahead:
    """`fn(*args)` (the search's compilation ahead of need: `Curriculum.prepare_ahead`) in a
    thread of its own; `wait` joins it once and reports it. A failure is only reported: the
    work it would have saved is done again where it is needed, and fails there with its own
    error."""

    def __init__(self, fn, *args):
        self.result: Any = None
        self.error: BaseException | None = None
        self.thread: threading.Thread | None = threading.Thread(
            target=self._run, args=(fn, *args), daemon=True)
        self.thread.start()

    def _run(self, fn, *args) -> None:
        try:
            self.result = fn(*args)
        except Exception as e:  # noqa: BLE001 -- reported by wait(), redone where needed
            self.error = e

    def wait(self, log=print) -> None:
        if self.thread is None:
            return
        self.thread.join()
        self.thread = None
        if self.error is not None:
            log(f"the curriculum's search program was not compiled ahead "
                f"({type(self.error).__name__}: {self.error}); its first round compiles it")
        else:
            log(f"the curriculum's search program compiled ahead, beside the training's, in "
                f"{self.result:.1f} s")


def plot_rounds(log_path: str | Path, png: str | Path) -> Path | None:
    """The failure rate each round's search found against the policy (failing episodes per
    1,000 with its 95 % Wilson interval) over the training iterations, from the rounds' log
    (`OUT/adversary.jsonl`); None when there is no round (matplotlib, Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mjxrow.rollout import aggregate as rollout_aggregate

    p = Path(log_path)
    rows = [json.loads(x) for x in p.read_text().splitlines() if x.strip()] if p.is_file() \
        else []
    if not rows:
        return None
    it = np.array([r["iteration"] for r in rows])
    mid, err = [], []
    for r in rows:
        fails = np.zeros(r["episodes"], bool)
        fails[:r["failing_episodes"]] = True
        a = rollout_aggregate.aggregate({"fail": fails})["fail"]
        mid.append(1000 * a["mean"])
        err.append((1000 * (a["mean"] - a["lo"]), 1000 * (a["hi"] - a["mean"])))
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.errorbar(it, mid, yerr=np.array(err).T, fmt="o-", capsize=3)
    ax.set_xlabel("training iteration (round 0: the starting policy)")
    ax.set_ylabel("failing episodes per 1,000")
    ax.set_ylim(bottom=0)
    ax.set_title(f"the failure search against the policy ({rows[0]['episodes']} episodes a "
                 "round, 95 % intervals)", fontsize=10)
    fig.tight_layout()
    png = Path(png)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
