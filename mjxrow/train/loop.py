"""The training loop: behaviour cloning / DAgger from the teacher, then PPO, in batched
auto-resetting environments (one per crop), within a wall-time budget, resumable.

    result = train(TrainConfig(...), out="runs/policy")

writes into `out`: `state/` (orbax training state, resumed by the next call with the same
`out`), `train_log.jsonl` (one line per iteration: phase, env steps, losses, episode metrics,
each preset's success rate, steps/s), `learning_curve.png` (return, success, steps/s over env
steps; with the adversarial curriculum also `adversary.png`, the failure rate its searches
find) and `policy/` (the policy checkpoint the `policy` controller loads: the last weights, or
with `average` their moving average over the iterations, the last then in `policy_last/`). The
budget counts the iterations' wall time (compilation and the curriculum's searches excluded)
over every call with the same `out`; the first `bc_fraction` of it is BC / DAgger, the rest
PPO; `iterations` caps the iterations as well, and the schedule then also runs its course
within them (`train.schedule.clock`). A `deadline` that leaves less than the budget
cuts it to what it leaves once everything is compiled (`train.schedule`), and the schedule
follows the wall clock where it runs ahead of the budget's, so the split falls inside the call;
once PPO has run it stays PPO. A progress bar shows the budget spent and its ETA.

The training state holds everything the next iteration depends on: the network, both
optimisers, the PRNG key, the counters, the worlds being driven (every environment's batched
state), the curriculum's pools, the weights' moving average and BC's replay buffer
(`bc.replay`), so a run resumed from a state saved at iteration k computes the same iteration
k + 1 as the run that went on.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from mjxrow import env as mjxrow_env
from mjxrow import runtime
from mjxrow.policies import checkpoint as policies_checkpoint
from mjxrow.policies import networks as policies_networks
from mjxrow.rollout.config import build_run
from mjxrow.train import bc as train_bc
from mjxrow.train import curriculum as train_curriculum
from mjxrow.train import ppo as train_ppo
from mjxrow.train import programs as train_programs
from mjxrow.train import rollout
from mjxrow.train import schedule as train_schedule
from mjxrow.train import state as train_state
from mjxrow.train.curve import plot_curve


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run (static)."""

    presets: tuple[str, ...] = ("zucchini", "vineyard", "pear", "lettuce", "chard")  # crops
    # trained together, one environment (and its rollout programs) each
    num_envs: int = 15360  # worlds stepped together, split evenly over the presets (3,072 a
    # crop: a GPU runs a batch of 512 barely faster than one of 2,048, and 3,072 faster still)
    unroll: int = 32  # control steps per rollout (one iteration)
    budget_minutes: float = 5.0  # training wall time over all resumed calls (compile excluded)
    bc_fraction: float = 0.5  # share of the budget for BC / DAgger before PPO (1: no PPO)
    max_resets: int | None = None  # worlds per pass of the reset loop (None: B / 16)
    episode_length: int | None = None  # training time limit [steps] (None: the episode's)
    seed: int = 0  # PRNG seed of the network, the worlds and the rollouts
    save_every: int = 25  # iterations between training-state checkpoints
    average: float = 0.8  # per-iteration decay of the moving average of the weights that
    # `policy/` holds (about the last five iterations; 0: the last weights alone)
    iterations: int | None = None  # stop after this many iterations in all (None: budget only)
    init: str = ""  # a policy checkpoint ('shipped' or a folder) whose network the run starts
    # from (its observation and network must be this run's); '' for a fresh network
    run: tuple[tuple[str, Any], ...] = ()  # RunConfig keys of every preset's environment
    env: mjxrow_env.EnvConfig = mjxrow_env.EnvConfig()
    net: policies_networks.NetConfig = policies_networks.NetConfig()
    ppo: train_ppo.PPOConfig = train_ppo.PPOConfig()
    bc: train_bc.BCConfig = train_bc.BCConfig()
    curriculum: train_curriculum.CurriculumConfig = train_curriculum.CurriculumConfig()

    def __post_init__(self):
        if not self.presets:
            raise ValueError("train.presets: at least one preset")
        if self.num_envs < len(self.presets) or self.num_envs % len(self.presets):
            raise ValueError(f"train.num_envs: {self.num_envs} does not split evenly over "
                             f"{len(self.presets)} presets")
        if not 0.0 <= self.bc_fraction <= 1.0:
            raise ValueError(f"train.bc_fraction: must lie in [0, 1], got {self.bc_fraction}")
        if not self.budget_minutes > 0:
            raise ValueError(f"train.budget_minutes: must be positive, got "
                             f"{self.budget_minutes}")
        if self.unroll < 1:
            raise ValueError(f"train.unroll: must be at least 1, got {self.unroll}")
        if not 0.0 <= self.average < 1.0:
            raise ValueError(f"train.average: must lie in [0, 1), got {self.average}")
        if self.iterations is not None and self.iterations < 1:
            raise ValueError(f"train.iterations: must be at least 1, got {self.iterations}")

    @property
    def per_env(self) -> int:
        return self.num_envs // len(self.presets)

    def run_config(self, preset: str):
        """The RunConfig of one preset's environment (the controller is the teacher)."""
        return build_run({"preset": preset, **dict(self.run)}, seed=self.seed)


def train(cfg: TrainConfig, out: str | Path, progress: bool = True,
          deadline: float | None = None, log=print, on_compiled=None,
          background_save: bool = False) -> dict[str, Any]:
    """Train (or resume training) into `out`; stop when the budget or `cfg.iterations` is spent
    or at the `deadline` (a `time.time()` value, e.g. to leave room for an evaluation).
    `on_compiled()`, if given, is called once the run's programs are compiled (to start other
    compilations then, e.g. an evaluation's, rather than compete with these). Returns
    the summary: paths, iterations, env steps, elapsed, compile time, seconds spent saving
    the training state, steps/s, the memory peak (`runtime.memory_peak`), last metrics, the
    curriculum's rounds. With `background_save` the last training state is still being
    written when it returns: its `train.state.PendingSave` is the summary's `saving` (call its
    `wait()` before the process ends, e.g. after an evaluation)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    tr = train_programs.Trainer(cfg)
    key = jax.random.key(cfg.seed)
    k_init, key = jax.random.split(key)
    params = tr.init_params(k_init)
    live = None  # the policy the curriculum's searches drive (written before each round)
    if cfg.curriculum.on:
        live = Path(policies_checkpoint.save(out / "adversary" / "policy", params, tr.spec,
                                             cfg.net, tr.limits)).resolve()
    cur = train_curriculum.Curriculum(cfg.curriculum, cfg.presets, [e.ranges for e in tr.raw],
                                      live, (tr.spec.height, tr.spec.width))
    pools = cur.pools()
    # the rounds' search program compiled in a thread beside the training's: with the
    # compilation cache on, the first round then compiles nothing
    ahead = cur.prepare_ahead(live) if cur.target is not None else None
    k_reset, key_after = jax.random.split(key)
    # compile everything once, before the clock of the budget runs (from the first tracing)
    t0 = time.perf_counter()
    # every crop's rollout programs traced in processes side by side, where they are, each
    # compiled here as it comes (`train.tracing`); the processes end however this goes
    tracing = tr.start_tracing(log=log)
    try:
        lowered = tr.lower_blanks(k_reset)  # the blank worlds' programs (their shapes are the
        # rollouts' arguments), traced here while the processes trace the rollouts
        worlds = tuple(low.out_info for low in lowered)
        state = {"params": params, "bc_opt": tr.bc_tx.init(params),
                 "ppo_opt": tr.ppo_tx.init(params), "counters": _counters(0, 0, 0.0),
                 "key": jax.random.key_data(key),
                 "worlds": jax.eval_shape(train_state.storable, worlds), "pools": pools,
                 "average": params}
        replay = tr.replay_buffer()  # BC's earlier rollouts (bc.replay), or None
        if replay is not None:
            state["replay"] = replay
        restored = train_state.restore_state(out / "state", state, tr.about())
        if restored is not None:
            state = restored[1]
            log(f"resumed from {out / 'state'}: iteration {int(state['counters']['iteration'])}, "
                f"{float(state['counters']['elapsed']) / 60:.1f} of {cfg.budget_minutes:g} min")
        params, bc_opt, ppo_opt = state["params"], state["bc_opt"], state["ppo_opt"]
        average = state["average"]
        replay = None if "replay" not in state else jax.tree.map(jnp.asarray, state["replay"])
        it = int(state["counters"]["iteration"])
        env_steps = int(state["counters"]["env_steps"])
        elapsed = float(state["counters"]["elapsed"])
        key = jax.random.wrap_key_data(jnp.asarray(state["key"]))
        pools = jax.tree.map(jnp.asarray, state["pools"])
        cur.load(pools)

        ppo_started = train_schedule.ppo_started(ppo_opt)
        phases = train_schedule.reachable(cfg, elapsed, ppo_started)
        blanks, unrolls, updates, join = tr.compile(
            params, worlds, key, pools,
            {p: bc_opt if p == "bc" else ppo_opt for p in phases},
            lowered if restored is None else [], replay=replay, tracing=tracing)
    finally:
        if tracing is not None:
            tracing.close()
    compile_s = time.perf_counter() - t0
    if on_compiled is not None:
        on_compiled()

    def unroll(params, envs, key, beta, noise, ppo, pools):
        return rollout.side_by_side(unrolls, join, params, envs, key, beta, noise, ppo, pools)

    t1 = time.perf_counter()
    if restored is None:
        # the first rollout resets every blank world at its first step (a new field each, as
        # the rollout's own resets draw them) and is not trained on
        k_first, key = jax.random.split(key_after)
        blank = tuple(b(k) for b, k in zip(blanks, jax.random.split(k_reset, len(blanks)),
                                           strict=True))
        envs = unroll(params, blank, k_first, jnp.float32(1.0), jnp.float32(0.0),
                      jnp.bool_(False), pools)[0]
    else:
        envs = train_state.restored(state["worlds"], worlds)
    jax.block_until_ready(envs)
    first_s = time.perf_counter() - t1
    parts = compile_parts(tr.compile_times, t0)
    log(f"compiled {len(unrolls)} rollout{'s' * (len(unrolls) > 1)} and the "
        f"{' and '.join(p.upper() for p in phases)} update{'s' * (len(phases) > 1)} in "
        f"{compile_s:.1f} s ({cfg.num_envs} worlds, {cfg.unroll} steps per rollout, "
        f"{tr.spec.describe()}): tracing {parts['trace_s']:.1f} s, then XLA "
        f"{parts['xla_after_trace_s']:.1f} s; each program's XLA compilation "
        + ", ".join(f"{k} {v:.1f} s" for k, v in parts["xla_s"].items())
        + ("" if restored is not None else
           f"; the first worlds (a rollout from blank ones, not trained on) {first_s:.1f} s")
        + "; memory peak so far " + runtime.peak_text(runtime.memory_peak()))

    # with a deadline, the budget is what it leaves (`train.schedule`): PPO's share comes in time
    budget = train_schedule.call_budget(cfg, elapsed,
                                        None if deadline is None else deadline - time.time())
    if budget < cfg.budget_minutes * 60.0:
        log(f"the deadline leaves {(budget - elapsed) / 60:.1f} min of training: this call "
            f"schedules over {budget / 60:.2f} of the {cfg.budget_minutes:g}-min budget "
            f"(BC / DAgger up to {cfg.bc_fraction * budget / 60:.2f} min, then PPO)")
    log_path = out / "train_log.jsonl"
    bar = tqdm(total=round(budget), initial=min(round(elapsed), round(budget)), unit="s",
               desc="training", disable=not progress, dynamic_ncols=True,
               mininterval=1.0 if sys.stderr.isatty() else 30.0,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s "
                          "[{elapsed}<{remaining}{postfix}]")
    last: dict[str, Any] = {}
    rates, rounds = [], []
    search_s = save_s = 0.0
    window: collections.deque = collections.deque(maxlen=20)  # recent iterations' episodes

    def shipped():
        """The weights the run ships: the moving average where `train.average` > 0."""
        return average if cfg.average > 0 else params

    def adversary_round():
        """A search against the policy the run would ship now (the weights' moving average
        where `train.average` > 0), its failures into the pool (the curriculum)."""
        nonlocal pools, search_s
        t0 = time.perf_counter()
        ahead.wait(bar.write)
        policies_checkpoint.save(live, shipped(), tr.spec, cfg.net, tr.limits,
                                 meta=_meta(cfg, tr, it, env_steps, elapsed))
        rnd = cur.round(live, out / "adversary", it, out / "adversary.jsonl")
        pools = cur.pools()
        rounds.append(rnd)
        search_s += time.perf_counter() - t0
        bar.write(f"adversary round {rnd['round']} at iteration {it}: "
                  f"{rnd['failing_per_1000']:.0f} failing episodes per 1,000, "
                  f"{rnd['failing_candidates']} failing fields, pool {rnd['pool']}")

    writing = train_state.PendingSave()  # a periodic save orbax may still be writing

    def save(wait=True):
        """Save the training state (after the one still being written, if any: one save at a
        time into the folder); with `wait=False` orbax writes it while training goes on."""
        nonlocal save_s
        t0 = time.perf_counter()
        writing.wait()
        pending = train_state.save_state(out / "state", it, {
            "params": params, "bc_opt": bc_opt, "ppo_opt": ppo_opt,
            "counters": _counters(it, env_steps, elapsed), "key": jax.random.key_data(key),
            "worlds": train_state.storable(envs), "pools": pools, "average": average,
            **({} if replay is None else {"replay": replay})}, tr.about(), wait=wait)
        save_s += time.perf_counter() - t0
        return pending

    t_train, elapsed0 = time.perf_counter(), elapsed
    with bar, log_path.open("a") as logf:
        if cur.target is not None and it == 0:  # round 0: the starting policy's failure rate
            adversary_round()
        while elapsed < budget and (deadline is None or time.time() < deadline) and (
                cfg.iterations is None or it < cfg.iterations):
            # the schedule's clock: the budget's, or with a deadline the wall time of this
            # call's training (saves, logging and searches included) where that ran ahead, or
            # the iterations' share of the budget where `cfg.iterations` ends the run first
            clock = train_schedule.clock(cfg, elapsed, budget, it, None if deadline is None
                                         else elapsed0 + time.perf_counter() - t_train)
            phase, beta, noise, ppo, lr = train_schedule.phase(cfg, clock, budget, ppo_started)
            if ppo and not ppo_started and cfg.ppo.start_log_std is not None:
                params = train_schedule.with_log_std(params, cfg.ppo.start_log_std)
            key, k_roll, k_upd = jax.random.split(key, 3)
            t0 = time.perf_counter()
            envs, traj, boot, sums, per_env = unroll(params, envs, k_roll, jnp.float32(beta),
                                                     jnp.float32(noise), jnp.bool_(ppo),
                                                     pools=pools)
            jax.block_until_ready(traj.reward)
            t1 = time.perf_counter()
            if phase == "bc":
                params, bc_opt, m, replay = updates["bc"](params, bc_opt, traj, boot, k_upd,
                                                          replay, jnp.float32(lr))
                m = {**m, "lr_scale": lr}
            else:
                params, ppo_opt, m = updates["ppo"](params, ppo_opt, traj, boot, k_upd)
                ppo_started = True
            if cfg.average > 0:
                average = tr.average(average, params)
            m = jax.device_get(m)
            t2 = time.perf_counter()
            it += 1
            n = cfg.unroll * cfg.num_envs
            env_steps += n
            elapsed += t2 - t0
            row = {"iteration": it, "phase": phase, "beta": beta, "env_steps": env_steps,
                   "elapsed_s": elapsed, "rollout_s": t1 - t0, "update_s": t2 - t1,
                   "rollout_steps_per_s": n / (t1 - t0), "steps_per_s": n / (t2 - t0),
                   **{k: float(v) for k, v in m.items()},
                   **rollout.summarise_stats(jax.device_get(sums)),
                   **rollout.per_preset_success(cfg.presets, jax.device_get(per_env))}
            logf.write(json.dumps(row) + "\n")
            logf.flush()
            rates.append((row["rollout_steps_per_s"], row["steps_per_s"]))
            last = row
            window.append(jax.device_get(sums))
            recent = rollout.summarise_stats(jax.tree.map(lambda *x: sum(x), *window))
            bar.set_postfix_str(f"{phase} return {recent['return']:.2f} success "
                                f"{recent['nav/success']:.2f} {row['steps_per_s']:,.0f} "
                                f"env-steps/s", refresh=False)
            bar.update(min(round(elapsed), round(budget)) - bar.n)
            if cur.due(it):
                adversary_round()
            if it % cfg.save_every == 0:
                writing = save(wait=False)
    saving = save(wait=not background_save)
    if ahead is not None:
        ahead.wait(log)  # no thread left compiling when this returns
    meta = _meta(cfg, tr, it, env_steps, elapsed)
    policy_dir = policies_checkpoint.save(out / "policy", shipped(), tr.spec, cfg.net, tr.limits,
                                          meta={**meta, "average": cfg.average})
    last_dir = policies_checkpoint.save(out / "policy_last", params, tr.spec, cfg.net, tr.limits,
                                        meta=meta) if cfg.average > 0 else None
    curve = plot_curve(log_path, out / "learning_curve.png")
    train_curriculum.plot_rounds(out / "adversary.jsonl", out / "adversary.png")
    steady = rates[1:] or rates
    return {"out": str(out), "policy": str(policy_dir),
            **({"policy_last": str(last_dir)} if last_dir else {}), "curve": str(curve),
            "iterations": it, "env_steps": env_steps, "elapsed_s": elapsed,
            "compile_s": compile_s, "compile_parts": parts, "first_s": first_s,
            "wall_s": time.perf_counter() - t_start,
            "search_s": search_s, "save_s": save_s, "rounds": rounds,
            "rollout_steps_per_s": float(np.median([r[0] for r in steady])) if steady
            else math.nan,
            "steps_per_s": float(np.median([r[1] for r in steady])) if steady else math.nan,
            "memory_peak_gib": runtime.memory_peak(),
            "last": last, **({"saving": saving} if background_save else {})}


def compile_parts(times: dict, t0: float) -> dict:
    """Where a compilation's time went, from `Trainer.compile_times` and its start `t0`:
    `trace_s` (until every program was traced or read back: Python, one program at a time),
    `xla_after_trace_s` (the XLA compilations still running after that), `xla_s` (each
    program's XLA compilation, side by side with the others and the tracing) and
    `xla_from_s` (when each began, from `t0`: a rollout program's as soon as it was traced or
    read back)."""
    jobs = {k: v for k, v in times.items() if k != "traced"}
    traced = times.get("traced", t0)
    end = max((e for _, e in jobs.values()), default=traced)
    return {"trace_s": traced - t0, "xla_after_trace_s": max(0.0, end - traced),
            "xla_s": {k: e - s for k, (s, e) in jobs.items()},
            "xla_from_s": {k: s - t0 for k, (s, _) in jobs.items()}}


def _counters(it: int, env_steps: int, elapsed: float) -> dict:
    # 0-d arrays: orbax's standard handler takes arrays, not numpy scalars
    return {"iteration": np.asarray(it, np.int64), "env_steps": np.asarray(env_steps, np.int64),
            "elapsed": np.asarray(elapsed, np.float64)}


def _meta(cfg: TrainConfig, tr: train_programs.Trainer, it: int, env_steps: int,
          elapsed: float) -> dict:
    return {"presets": list(cfg.presets), "iterations": it, "env_steps": env_steps,
            "train_minutes": elapsed / 60.0, "num_envs": cfg.num_envs,
            "bc_fraction": cfg.bc_fraction, "teacher": tr.raw[0].run.controller.name,
            "init": cfg.init or None,
            "image_shape": list(tr.obs_example["image"].shape),
            "device": jax.devices()[0].device_kind}


def initial_policy(cfg: TrainConfig, path: str | Path) -> Path | None:
    """An untrained policy checkpoint of `cfg`'s architecture and observation at `path` (for
    compiling the evaluation before the trained weights exist); None for "features" (its
    shape needs the segmenter)."""
    if cfg.env.observation == "features":
        return None
    run = cfg.run_config(cfg.presets[0])
    spec = mjxrow_env.ObsSpec(
        cfg.env.observation, run.camera.height, run.camera.width, cfg.env.proprio
    )
    obs = policies_checkpoint.example_obs(spec)
    robot = run.robot_config()
    params = policies_networks.init(
        policies_networks.PolicyNet(cfg.net), obs, jax.random.key(cfg.seed)
    )
    return policies_checkpoint.save(path, params, spec, cfg.net, (robot.v_max, robot.omega_max),
                                    meta={"untrained": True})
