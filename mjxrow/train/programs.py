"""The compiled pieces of a training run (`Trainer`): every crop's environment with the
trainer's wrappers (episode, vmap, auto-reset), its rollout's three programs (`PARTS`, run by
`rollout.Stepwise`; traced, or read back from those an earlier process kept beside the
compilation cache: `runtime.exported`; `start_tracing` traces every crop's in a process of
its own, side by side, while `compile` compiles each as it comes: `train.tracing`) and its
blank worlds, the network's value and `rollout.join`, the BC and PPO updates, and what a saved
training state must match. `train.loop` drives them.

There is no reset program: a run's first rollout starts from blank worlds
(`AutoResetWrapper.blank`, zeros made by a program of broadcasts) whose first step resets every
one in the rollout's own reset, and is not trained on. A reset program (a field, a plant table,
a frame) cost about as much XLA time as a rollout, one per crop.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import traverse_util

from mjxrow import env as mjxrow_env
from mjxrow import runtime
from mjxrow.policies import checkpoint as policies_checkpoint
from mjxrow.policies import networks as policies_networks
from mjxrow.train import bc as train_bc
from mjxrow.train import curriculum as train_curriculum
from mjxrow.train import ppo as train_ppo
from mjxrow.train import rollout
from mjxrow.train import tracing as train_tracing

if TYPE_CHECKING:
    from mjxrow.train.loop import TrainConfig


def make_envs(cfg: TrainConfig) -> tuple[list[mjxrow_env.Env], tuple]:
    """The raw environments and their training wrappers (episode, vmap, auto-reset)."""
    raw = [mjxrow_env.Env(cfg.run_config(p), cfg.env) for p in cfg.presets]
    specs = {e.spec for e in raw}
    if len(specs) > 1:
        raise ValueError(f"train.presets: the environments observe differently: {specs}")
    B = cfg.per_env
    k = cfg.max_resets or max(1, B // 16)
    wrapped = tuple(
        mjxrow_env.AutoResetWrapper(
            mjxrow_env.VmapWrapper(mjxrow_env.EpisodeWrapper(e, cfg.episode_length)), B, k
        )
        for e in raw
    )
    return raw, wrapped


class Trainer:
    """The compiled pieces of one training run (see `train`)."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.raw, self.envs = make_envs(cfg)
        self.spec = self.raw[0].spec
        for key, on in (("bc.mirror", cfg.bc.mirror), ("net.symmetric", cfg.net.symmetric)):
            if on and self.spec.kind == "features":
                raise ValueError(f"{key}: the segmenter's features of a mirrored image are not "
                                 "its features mirrored; mirror rgb or mask observations")
        self.net = policies_networks.PolicyNet(cfg.net)
        self.obs_example = self.raw[0].observation_structs()
        self.limits = tuple(float(x) for x in np.asarray(self.raw[0].limits))
        # each environment's (crop's) rollout step as three programs (`rollout.Stepwise`):
        # smaller programs, which XLA compiles side by side, in threads; each takes the worlds'
        # buffers for its own (`DONATE`: no copy of the arrays a part leaves as they are, a
        # few GB a crop, such as its field and plant tables)
        self.parts = tuple(
            {p: jax.jit(fn, donate_argnums=DONATE[p]) for p, fn in (
                ("advance", functools.partial(rollout.advance, self.net, e, length=cfg.unroll)),
                ("reset", e.step_reset), ("observe", e.step_observe))}
            for e in self.envs)
        self.value = jax.jit(functools.partial(rollout.value, self.net))  # every crop's
        self.join = jax.jit(rollout.join)
        self.blanks = tuple(jax.jit(e.blank) for e in self.envs)  # key → worlds to replace
        # what names each environment's traced programs kept beside the compilation cache
        # (`runtime.exported`; '' traces them every run)
        self.keys = tuple(_program_key(cfg, r, e) for r, e in zip(self.raw, self.envs,
                                                                   strict=True))
        self.bc_tx = train_ppo.optimizer(cfg.bc.learning_rate, cfg.bc.max_grad_norm)
        self.ppo_tx = train_ppo.optimizer(cfg.ppo.learning_rate, cfg.ppo.max_grad_norm)
        self.bc_update = jax.jit(functools.partial(self._update, "bc"))
        self.ppo_update = jax.jit(functools.partial(self._update, "ppo"))
        d = cfg.average  # the weights' moving average, one step an iteration
        self.average = jax.jit(lambda avg, p: jax.tree.map(lambda a, x: d * a + (1 - d) * x,
                                                           avg, p))
        # where `compile`'s time went (time.perf_counter values): 'traced' (every program
        # traced or read back), and each XLA compilation's (start, end) by program
        self.compile_times: dict[str, Any] = {}

    def kept(self, i: int, what: str, fn, args: tuple, out_tree: Any, donate: tuple = ()):
        """Environment i's jitted `fn`, or the same program for `args` traced by an earlier
        process and kept beside the compilation cache (`runtime.exported`: no tracing);
        `what` names the program among the environment's, `out_tree` its result's tree,
        `donate` the arguments it takes the buffers of (as `fn` does)."""
        if not self.keys[i]:
            return fn
        return runtime.exported(fn, args, f"{self.keys[i]}\n{what}", out_tree, donate) or fn

    def start_tracing(self, log=print, force: bool = False) -> train_tracing.Tracing | None:
        """Start tracing every environment's rollout programs in a process of its own, side
        by side, each kept beside the compilation cache (`runtime.exported`) and reported as
        soon as it is, so that `compile(tracing=...)` reads each back and starts XLA on it
        while the others are still being traced (Python traces one program at a time in a
        process). Only where the cache is on, several environments have kept programs, the
        curriculum is off, this set of programs was not traced so before (a marker in the
        cache's `exported/`), and the machine has two cores per environment or `force` (each
        process first spends seconds importing and tracing once: on a 2-core CPU three tiny
        crops took 39 s so, 29-41 s in one); None otherwise. The processes do not compile. A
        failed process is a one-line note, and what it did not keep is traced here."""
        marker = self._untraced_marker(force)
        if marker is None:
            return None
        log(f"tracing the {len(self.envs)} crops' programs in {len(self.envs)} processes")
        return train_tracing.start(_trace_one, self.cfg, len(self.envs),
                                   str(runtime.cache_dir()), marker)

    def _untraced_marker(self, force: bool):
        """The marker file left once processes have traced this run's programs
        (`start_tracing`), or None where they do not trace them (see there), or have."""
        root, cfg = runtime.cache_dir(), self.cfg
        if (root is None or len(self.envs) < 2 or not all(self.keys) or cfg.curriculum.on
                or jax.process_count() > 1
                or not (force or (os.cpu_count() or 1) >= 2 * len(self.envs))):
            return None
        h = hashlib.sha256(runtime.code_version().encode())
        for part in (*self.keys, str(cfg.net), str(cfg.unroll), str(cfg.seed),
                     jax.default_backend()):
            h.update(part.encode() + b"\0")
        marker = root / "exported" / f"{h.hexdigest()}.traced"
        return None if marker.is_file() else marker

    def rollout_programs(self, i: int, args: dict, parts: tuple[str, ...] | None = None
                         ) -> dict:
        """Environment i's rollout programs {part: program} (`parts`, kept in that order;
        default `PARTS`) for `args` (`rollout_args`'), each kept as `kept` keeps it."""
        worlds = args["observe"][0]
        trees = {"advance": rollout.advance_structure(worlds),
                 "reset": jax.tree.structure(worlds), "observe": jax.tree.structure(worlds)}
        about = {"advance": f"the rollout's advance, {self.cfg.unroll} steps, {self.cfg.net}",
                 "reset": "the training step's reset", "observe": "the training step's frame"}
        return {p: self.kept(i, about[p], self.parts[i][p], args[p], trees[p], DONATE[p])
                for p in parts or PARTS}

    def lower_blanks(self, key: jax.Array) -> list:
        """Every environment's blank worlds (`AutoResetWrapper.blank`), lowered for `key`
        (split over them): a lowered program's `out_info` is the shape of its worlds. Tracing
        one traces the environment's `reset_world` for its shapes (not its frame)."""
        keys = jax.random.split(key, len(self.envs))
        return [b.lower(k) for b, k in zip(self.blanks, keys, strict=True)]

    def compile(self, params, worlds, key, pools, opts: dict, blanks: list = (),
                replay=None, tracing: train_tracing.Tracing | None = None):
        """Every program the run needs, compiled side by side (one thread each: XLA compiles
        separate programs in parallel where the machine has the cores; the tracing before it
        is Python's, one at a time, and skipped for a program kept by `kept`): the lowered
        `blanks`, every environment's rollout programs (on worlds of the shapes `worlds`;
        `PARTS`, and the network's value and `rollout.join`, which all share), and the update
        of every phase in `opts` ({'bc' or 'ppo': its optimiser state}; BC's with the `replay`
        buffer, or None: `train.bc.replay_mix`). With `tracing` (`start_tracing`'s) each
        rollout program is lowered and compiled as its process reports it kept (the caller
        ends the processes: `Tracing.close`). Returns ([blank executables],
        [`rollout.Stepwise` of each environment], {phase: update executable}, join's
        executable); the times are in `compile_times`."""
        n = len(blanks) + len(PARTS) * len(self.parts) + 2 + len(opts)
        with ThreadPoolExecutor(n) as ex:
            futures = {("blank", i): ex.submit(_timed, low.compile)
                       for i, low in enumerate(blanks)}
            args = [rollout_args(params, st, key, i, pool)
                    for i, (st, pool) in enumerate(zip(worlds, pools, strict=True))]
            outs = {}
            for i, part in (tracing.ready() if tracing is not None else
                            ((i, p) for i in range(len(args)) for p in PARTS)):
                low = self.rollout_programs(i, args[i], (part,))[part].lower(*args[i][part])
                futures[(part, i)] = ex.submit(_timed, low.compile)
                if part == "advance":
                    outs[i] = low.out_info
            outs = [outs[i] for i in range(len(args))]
            low_v = self.value.lower(params, worlds[0].obs)
            futures[("value", None)] = ex.submit(_timed, low_v.compile)
            T = self.cfg.unroll
            low = self.join.lower([[o[1]] * T for o in outs], [low_v.out_info] * len(outs),
                                  [o[2] for o in outs])
            futures[("join", None)] = ex.submit(_timed, low.compile)
            traj, boot, _ = low.out_info
            for ph, opt in opts.items():
                if ph == "bc":
                    low = self.bc_update.lower(params, opt, traj, boot, key, replay,
                                               jnp.float32(1.0))
                else:
                    low = self.ppo_update.lower(params, opt, traj, boot, key)
                futures[("update", ph)] = ex.submit(_timed, low.compile)
            t_traced = time.perf_counter()
            done = {k: f.result() for k, f in futures.items()}
        jobs = {k: v[0] for k, v in done.items()}
        self.compile_times = {"traced": t_traced, **{self._name(k): v[1:]
                                                     for k, v in done.items()}}
        rollouts = [rollout.Stepwise(**{p: jobs[(p, i)] for p in PARTS},
                                     value=jobs[("value", None)], length=self.cfg.unroll)
                    for i in range(len(self.parts))]
        return ([jobs[("blank", i)] for i in range(len(blanks))], rollouts,
                {ph: jobs[("update", ph)] for ph in opts}, jobs[("join", None)])

    def _name(self, job: tuple) -> str:
        """A compile job's name in `compile_times`: its program, and its crop or phase."""
        what, which = job
        if which is None:
            return what
        return f"{what} {self.cfg.presets[which] if isinstance(which, int) else which}"

    def fresh_params(self, key: jax.Array) -> Any:
        """A fresh network's weights."""
        shapes = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), self.obs_example)
        return policies_networks.init(self.net, shapes, key)

    def init_params(self, key: jax.Array) -> Any:
        """A fresh network, or `cfg.init`'s weights (ValueError naming train.init when its
        observation or network is not this run's). A checkpoint without the auxiliary head
        starts a run with `net.aux` too: its weights, the head fresh."""
        params = self.fresh_params(key)
        if not self.cfg.init:
            return params
        ck = policies_checkpoint.load(self.cfg.init, dataclasses.asdict(self.spec),
                                      key="train.init")
        if ck.net.cfg not in (self.cfg.net, dataclasses.replace(self.cfg.net, aux=False)):
            raise ValueError(f"train.init: {ck.path} holds network {ck.net.cfg}; this run "
                             f"trains {self.cfg.net}")
        fresh = traverse_util.flatten_dict(params)
        stored = traverse_util.flatten_dict(ck.variables)
        return traverse_util.unflatten_dict({
            k: jnp.asarray(stored.get(k, ref), ref.dtype) for k, ref in fresh.items()})

    def replay_buffer(self):
        """BC's empty replay buffer for this run's rollouts (`train.bc.replay_buffer`), or None
        without `bc.replay` (or without a BC phase)."""
        cfg = self.cfg
        if not cfg.bc.replay or cfg.bc_fraction <= 0:
            return None
        n = cfg.unroll * cfg.num_envs
        shape = lambda x: jax.ShapeDtypeStruct((n, *x.shape), x.dtype)  # noqa: E731
        return train_bc.replay_buffer({
            "obs": jax.tree.map(shape, self.obs_example),
            "teacher": jax.ShapeDtypeStruct((n, 2), jnp.float32),
            "target": jax.ShapeDtypeStruct((n,), jnp.float32),
            "lane_error": jax.ShapeDtypeStruct((n, 2), jnp.float32)})

    def _update(self, phase, params, opt_state, traj, boot, key, replay=None, lr_scale=None):
        """One phase's update on a rollout: (params, opt_state, metrics), and for BC also its
        replay buffer after it (None without `bc.replay`); BC's steps are scaled by `lr_scale`
        (traced: `bc.lr_end`'s schedule)."""
        c = self.cfg.ppo
        adv, target = train_ppo.gae(traj, boot, c.discount, c.gae_lambda, c.reward_scale)
        data = train_ppo.batch(traj, adv, target)
        if phase == "bc":
            b = self.cfg.bc
            if replay is not None:
                key, k_mix = jax.random.split(key)
                data, replay = train_bc.replay_mix(replay, data, k_mix, b.replay)
            if b.mirror:
                key, k_mirror = jax.random.split(key)
                data = {**data, "mirror": train_bc.mirror_flags(k_mirror,
                                                                len(data["teacher"]))}
            out = train_ppo.sgd(
                params,
                opt_state,
                data,
                key,
                train_bc.loss(self.net, b.value_cost, b.aux_cost),
                self.bc_tx,
                b.epochs,
                b.minibatches,
                lr_scale,
            )
            return (*out, replay)
        return train_ppo.sgd(params, opt_state, data, key, train_ppo.loss(self.net, c), self.ppo_tx,
                             c.epochs, c.minibatches)

    def about(self) -> dict:
        """What a saved training state must match to be resumed."""
        return {"observation": self.spec.to_dict(), "network": self.cfg.net.to_dict(),
                "presets": list(self.cfg.presets), "num_envs": self.cfg.num_envs,
                "replay": self.cfg.bc.replay if self.cfg.bc_fraction > 0 else 0,
                "state_format": STATE_FORMAT}


PARTS = ("advance", "reset", "observe")  # a rollout step's programs (`rollout.Stepwise`)
DONATE = {"advance": (1,), "reset": (0,), "observe": (0,)}  # each one's worlds argument


def rollout_args(params, worlds, key: jax.Array, i: int, pool) -> dict:
    """{part: the arguments} environment i's rollout programs (`PARTS`) are compiled for
    (the step, β, noise and the PPO switch are data; these only fix their dtypes)."""
    return {"advance": (params, worlds, jax.random.fold_in(key, i), np.int32(0),
                        jnp.float32(1.0), jnp.float32(0.1), jnp.bool_(False),
                        rollout.sums0(worlds)),
            "reset": (worlds, pool), "observe": (worlds,)}


def _trace_one(cfg: TrainConfig, i: int, cache: str) -> None:
    """In a process of its own: trace environment i's rollout of the run `cfg` as
    `Trainer.compile` would (the same keys and argument shapes), keeping it beside the
    compilation cache `cache` (`Trainer.start_tracing`), reporting each part as it is kept,
    the one XLA takes longest over first (`train.tracing.ORDER`)."""
    runtime.enable_cache(cache)
    one = dataclasses.replace(cfg, presets=(cfg.presets[i],), num_envs=cfg.per_env)
    tr = Trainer(one)
    key = jax.random.key(cfg.seed)
    # the shapes and device of `train`'s weights (their values are not traced): no network is
    # initialised here, which would compile its programs first
    dev = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    params = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, sharding=dev),
                          jax.eval_shape(tr.fresh_params, key))
    # pools of `train`'s shapes (an empty one: this crop need not be the search's)
    off = dataclasses.replace(one.curriculum, search="")
    pools = train_curriculum.Curriculum(off, one.presets, [e.ranges for e in tr.raw]).pools()
    worlds = jax.eval_shape(tr.blanks[0], key)
    args = rollout_args(params, worlds, key, i, pools[0])
    for part in train_tracing.ORDER:
        tr.rollout_programs(0, args, (part,))
        train_tracing.report(i, part)


def _timed(fn):
    """(fn(), start, end): perf_counter values around the call."""
    t = time.perf_counter()
    return fn(), t, time.perf_counter()


STATE_FORMAT = 3  # what a training state holds (2: with the worlds and the pools; 3: and the
# weights' moving average)


def _program_key(cfg: TrainConfig, raw: mjxrow_env.Env, env: Any) -> str:
    """Everything static in one environment's training programs besides the network's and
    the rollout's (their callers add those), as text; '' where the environment has none."""
    key = raw.program_key()
    return key and (f"{key}\ntraining worlds {env.batch_size}, {env.max_resets} resets a "
                    f"pass, time limit {cfg.episode_length}")
