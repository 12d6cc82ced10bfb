"""A Brax / MuJoCo Playground-style environment for training navigation policies in row-crop
fields: `reset(rng) -> State`, `step(state, action) -> State` on ONE world (pure; jit and vmap
outside, batching in `env.wrappers`).

The environment is a client of the run builder: `Env(run, cfg)` takes the static pieces (the
MJX model, the episode settings, robot, camera intrinsics and render config) from
`rollout.build.build(run, shape=...)`, with the field shape fitted to the corners of the
randomisation ranges. Every reset draws a new world (`env.randomize`): FieldParams from the
ranges, a field, its lane, its MJX model arrays (`sim.world_model`), a start pose, a sky /
lighting condition, a camera-mount jitter; the renderer's plant table is computed once there
and kept in the state. Each step: action → (v, ω) → one control period of MJX physics → the
episode's end events (as `rollout.episode`) → reward terms → a new camera frame → observation.

The run's controller (`controller.name`, default oracle) is the TEACHER: its command for the
current observation, normalised to [-1, 1], is `state.info["teacher_action"]` (behaviour
cloning and DAgger label with it; a mask controller sees the renderer's ground-truth mask).

Navigation metrics: the state keeps the episode's `metrics.Log` ([T] per step, T the episode's
control steps), and the step that ends an episode reports `metrics.summarise` of it (success,
CHA, MAE, MSE, ω std, ...: every registered metric with Metric.env) in
`state.metrics["nav/<name>"]`: the sweep's numbers, by the sweep's function. `state.metrics`
also holds each reward term (`reward/<term>`) and the episode's return (`return`, valid where
`done`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow import control, render
from mjxrow import field as mjxrow_field
from mjxrow.control.oracle import OracleConfig
from mjxrow.env import randomize as env_randomize
from mjxrow.env import reward as env_reward
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import sim
from mjxrow.policies import observe as policies_observe
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import fingerprint as rollout_fingerprint
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.rollout import step as rollout_step
from mjxrow.rollout.config import ControllerChoice, RunConfig


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Environment settings beyond the run's (static, hashable)."""

    observation: str = "rgb"  # what the policy sees: 'rgb', 'chroma', 'mask', 'features'
    proprio: bool = True  # odometry (v, ω) and the previous action in the observation
    randomize: env_randomize.Randomize = env_randomize.Randomize()  # what every reset draws
    reward: env_reward.RewardConfig = env_reward.RewardConfig()  # reward weights

    def __post_init__(self):
        if self.observation not in policies_observe.KINDS:
            raise ValueError(f"env.observation: {self.observation!r} is not one of "
                             f"{', '.join(policies_observe.KINDS)}")


def lane_error(lane: field_lanes.Lane, pose: jax.Array) -> jax.Array:
    """float32 [2]: the lateral offset of `pose` (x, y, yaw) from the lane's centre line [m, +
    left] and its heading error to the line's direction [rad], as the metrics define them
    (`rollout.metrics.lateral_offset`, `heading_error`): what a policy's auxiliary head learns
    to see (`networks.NetConfig.aux`)."""
    p = pose[None]  # one step
    return jnp.concatenate([rollout_metrics.lateral_offset(p, lane),
                            rollout_metrics.heading_error(p, lane)]).astype(jnp.float32)


@struct.dataclass
class State:
    """One world's environment state (Playground's `mjx_env.State`): `data` the simulation
    and episode bookkeeping, `obs` the observation dict, `reward` float32 [], `done` float32 []
    (1.0 at the step that ended the episode), `metrics` dict of float32 [], `info` dict
    (teacher_action float32 [2], lane_error float32 [2]: the lateral offset from the lane's
    centre line [m, + left] and the heading error [rad] where the observation was taken,
    truncation float32 [], and what wrappers add)."""

    data: Any
    obs: dict
    reward: jax.Array
    done: jax.Array
    metrics: dict
    info: dict


@struct.dataclass
class EnvData:
    """The world and its episode (one world)."""

    sim: sim.SimState
    world: dict  # the world's model arrays (sim.WORLD_FIELDS), written by sim.world_model
    field: mjxrow_field.Field
    table: tuple  # the arrays of the field's render.PlantTable (Env rebuilds the table)
    lane: jax.Array  # int32 [], the driven lane
    lane_line: field_lanes.Lane  # the driven lane's centre line; its end is the goal
    cond: Any  # render.Conditions of the episode
    jitter: jax.Array  # float32 [3], camera (height [m], pitch [rad], roll [rad]) offsets
    key: jax.Array  # PRNG key of the episode's sensor noise
    prev_action: jax.Array  # float32 [2], in [-1, 1]
    vel: jax.Array  # float32 [2], odometry (v [m/s], ω [rad/s]) over the last control period
    anchor: jax.Array  # float32 [2], position at the last stuck check [m]
    t: jax.Array  # int32 [], control steps since reset
    ret: jax.Array  # float32 [], return so far
    teacher: Any  # the teacher controller's state
    log: rollout_metrics.Log  # the episode so far ([T] per step)


def teacher_run(run: RunConfig) -> RunConfig:
    """The run with its controller replaced by the oracle (for the builder: no segmenter or
    policy checkpoint is loaded)."""

    return dataclasses.replace(run, controller=ControllerChoice("oracle", OracleConfig()))


class Env:
    """The environment of one RunConfig (preset, sim, robot, camera, render, episode,
    perception; the controller is the teacher) and an EnvConfig. Holds only static values
    and the MJX model; `reset` and `step` are pure functions of their arguments."""

    def __init__(self, run: RunConfig, cfg: EnvConfig = EnvConfig(), device=None):
        self.run, self.cfg = run, cfg
        rz = cfg.randomize
        self.ranges = rz.resolved(run.preset)
        self.base = run.field_params()
        shape = mjxrow_field.fit_shape(
            env_randomize.corner_params(self.base, self.ranges), run.preset
        )
        env_randomize.check_ranges(self.base, self.ranges, shape)
        built = rollout_build.build(teacher_run(run), shape=shape,
                                    devices=[device or jax.devices()[0]])
        self.shape, self.mx, self.episode = built.shape, built.mx, built.episode
        self._built_key = built.key
        self.intr, self.render_cfg = run.camera, run.render
        robot = run.robot_config()
        self.limits = jnp.asarray([robot.v_max, robot.omega_max], jnp.float32)
        rn = sim.robot_numbers(self.mx)
        self.half = (0.5 * rn["length"], 0.5 * rn["width"])
        self.spec = policies_observe.ObsSpec(cfg.observation, run.camera.height, run.camera.width,
                                             cfg.proprio)
        self.seg = policies_observe.segmenter_for(run, self.spec)
        tc = control.get(run.controller.name)
        if getattr(tc, "make_policy", None) is not None:
            raise ValueError(f"controller.name: {tc.name!r} cannot be the teacher (it needs a "
                             f"trained policy); use oracle or segzeros")
        self.teacher = tc
        self.teacher_params = run.controller_params()
        # the plant table's tree structure (with its static part: numpy primitive kinds) stays
        # here; the state holds its leaves, so states of different resets share one structure
        tree = []

        def table(k):
            t = render.plant_table(mjxrow_field.generate(self.base, self.shape, k), self.shape)
            tree.append(jax.tree.structure(t))
            return ()

        jax.eval_shape(table, jax.random.key(0))
        self._table_tree = tree[0]
        h, w = run.camera.height, run.camera.width
        frame = render.Frame(rgb=jnp.zeros((h, w, 3), jnp.uint8), depth=jnp.zeros((h, w)),
                             mask=jnp.zeros((h, w), bool), classes=jnp.zeros((h, w), jnp.uint8))
        self._obs_shapes = jax.eval_shape(lambda f: policies_observe.observe(
            self.spec, f, self.seg, jnp.zeros(2), jnp.zeros(2), self.limits), frame)

    # -- static facts ---------------------------------------------------------------------

    def program_key(self) -> str:
        """Everything static this environment's programs close over, as text (names their
        traced programs kept by `runtime.exported`): the teacher run's closed-loop key (the
        MJX model, field shape, episode, crop), every value of the run and of the EnvConfig,
        the teacher and its params. '' where that text is not the same in every process: code
        from outside the mjxrow package, or a segmenter's weights in the observation."""
        if not self._built_key or self.seg is not None:
            return ""
        try:
            return "\n".join((self._built_key, rollout_fingerprint.stable_text(self.run),
                              rollout_fingerprint.stable_text(self.cfg),
                              rollout_fingerprint.stable_text(self.teacher),
                              rollout_fingerprint.stable_text(self.teacher_params)))
        except rollout_fingerprint.Foreign:
            return ""

    @property
    def dt(self) -> float:
        """s, one control period."""
        return self.episode.control_dt

    @property
    def action_size(self) -> int:
        return 2

    @property
    def n_steps(self) -> int:
        """Control steps before the episode's timeout."""
        return self.episode.n_steps

    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        return {k: tuple(v.shape) for k, v in self._obs_shapes.items()}

    def observation_structs(self) -> dict[str, jax.ShapeDtypeStruct]:
        """One world's observation: shapes and dtypes (nothing traced)."""
        return dict(self._obs_shapes)

    # -- pieces -----------------------------------------------------------------------------

    def model(self, world: dict):
        """The MJX model of one world from its arrays (EnvData.world)."""
        return self.mx.tree_replace(world)

    def frame(self, d: EnvData, s: sim.SimState, key: jax.Array | None):
        cam_pos, cam_rot = policies_observe.camera_jitter(*sim.camera_pose(s), d.jitter)
        table = jax.tree.unflatten(self._table_tree, d.table)
        return render.render(d.field, self.shape, cam_pos, cam_rot, self.intr, d.cond, key,
                             self.render_cfg, table=table)

    def _teach(self, d: EnvData, s: sim.SimState, frame, tstate):
        cam_pos, cam_rot = sim.camera_pose(s)
        obs = control.Obs(pose=sim.pose(s), lane=d.lane_line,
                          goal=field_lanes.goal(d.lane_line), cam_pos=cam_pos, cam_rot=cam_rot,
                          field=d.field,
                          mask=frame.mask, depth=frame.depth)
        tstate, cmd = self.teacher.act(self.teacher_params, tstate, obs)
        return tstate, policies_observe.normalise_command(
            jnp.asarray(cmd, jnp.float32), self.limits
        )

    def _sensor_key(self, d: EnvData, t):
        return jax.random.fold_in(d.key, t) if self.cfg.randomize.sensor_noise else None

    def _empty_log(self, p0, lane_line) -> rollout_metrics.Log:
        T = self.n_steps
        return rollout_metrics.Log(
            pose=jnp.full((T, 3), jnp.nan),
            cmd=jnp.zeros((T, 2)),
            alive=jnp.zeros(T, bool),
            event=jnp.zeros(T, jnp.int32),
            start=p0,
            goal=field_lanes.goal(lane_line),
            lane=lane_line,
            reason=jnp.int32(rollout_metrics.RUNNING),
            steps=jnp.int32(0),
            vel=jnp.full((T, 2), jnp.nan),
        )

    def _metrics(self, parts, log, ret):
        out = {f"reward/{k}": v.astype(jnp.float32) for k, v in parts.items()}
        nav = rollout_metrics.summarise(log, self.dt)
        out.update({f"nav/{m.name}": jnp.asarray(nav[m.name], jnp.float32)
                    for m in rollout_metrics.METRICS.values() if m.env})
        out["return"] = ret
        return out

    # -- the environment --------------------------------------------------------------------
    #
    # reset = observe ∘ reset_world and step = observe ∘ advance: the auto-reset wrapper calls
    # the parts, so that a batch renders its frames once per step, after the worlds that
    # ended were replaced (a reset then costs no frame of its own).

    def reset(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        """A new world and episode from PRNG key `rng`, observed (one world; pure); `given`
        as in `reset_world`."""
        return self.observe(self.reset_world(rng, given))

    def step(self, state: State, action: jax.Array) -> State:
        """One control step under `action` float [2] in [-1, 1] (clipped), observed. A state
        whose episode is done stays as it is (auto-reset wrappers replace it)."""
        new = self.observe(self.advance(state, action))
        return jax.tree.map(lambda x, y: jnp.where(state.done > 0, x, y),
                            state.replace(reward=jnp.zeros_like(state.reward)), new)

    def reset_world(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        """A new world and episode, not yet observed (`obs` and the teacher's action are
        zeros until `observe`). `given` float32 [len(pool_keys(self.ranges))]: ranged field
        values, then the sun's azimuth, to take instead of the draw where not NaN
        (`env.randomize.sample_params`, `sample_condition`)."""
        rz, scfg = self.cfg.randomize, self.episode.sim
        ks = jax.random.split(rng, 8)
        n = len(self.ranges)
        params = env_randomize.sample_params(self.base, self.ranges, ks[0],
                                             None if given is None else given[:n])
        sun = None if given is None else given[n]  # the sun's azimuth [deg] (NaN: drawn)
        field = mjxrow_field.generate(params, self.shape, ks[1])
        lane = mjxrow_field.robot_lane(field)
        m = sim.world_model(self.mx, field, lane, scfg)
        ahead = rz.start_progress * scfg.path_length * jax.random.uniform(ks[2])
        start = field.replace(row_x=field.row_x.at[1].add(ahead))  # start `ahead` m closer
        noise = sim.pose_noise(rz.start_offset_std, math.radians(rz.start_yaw_std_deg))
        s0 = sim.reset(m, start, lane, ks[3], scfg, noise)
        lane_line = field_lanes.lane(field, lane)
        p0 = sim.pose(s0)
        d = EnvData(
            sim=s0,
            world={k: getattr(m, k) for k in sim.WORLD_FIELDS},
            field=field,
            table=tuple(jax.tree.leaves(render.plant_table(field, self.shape))),
            lane=lane,
            lane_line=lane_line,
            cond=env_randomize.sample_condition(rz, ks[4], sun),
            jitter=env_randomize.sample_jitter(rz, ks[5]),
            key=ks[6],
            prev_action=jnp.zeros(2),
            vel=jnp.zeros(2),
            anchor=p0[:2],
            t=jnp.int32(0),
            ret=jnp.float32(0.0),
            teacher=self.teacher.init(self.teacher_params),
            log=self._empty_log(p0, lane_line),
        )
        zero = jnp.float32(0.0)
        parts = {k: zero for k in env_reward.TERMS}
        obs = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), self._obs_shapes)
        return State(data=d, obs=obs, reward=zero, done=zero,
                     metrics=self._metrics(parts, d.log, zero),
                     info={"teacher_action": jnp.zeros(2), "lane_error": jnp.zeros(2),
                           "truncation": zero})

    def expired(self, state: State) -> State:
        """`state` (one world or a batch) with its episode clock at the time limit: the next
        `advance` ends each episode (a timeout at least), whatever the world holds (the
        auto-reset wrapper's `blank`)."""
        d = state.data
        return state.replace(data=d.replace(t=jnp.full(d.t.shape, self.n_steps, d.t.dtype)))

    def observe(self, state: State) -> State:
        """The camera frame of the state's world → `obs`, and the teacher's action on it."""
        d = state.data
        frame = self.frame(d, d.sim, self._sensor_key(d, d.t))
        tstate, teacher = self._teach(d, d.sim, frame, d.teacher)
        obs = policies_observe.observe(
            self.spec, frame, self.seg, d.vel, d.prev_action, self.limits
        )
        return state.replace(data=d.replace(teacher=tstate), obs=obs,
                             info={**state.info, "teacher_action": teacher,
                                   "lane_error": lane_error(d.lane_line, sim.pose(d.sim))})

    def advance(self, state: State, action: jax.Array) -> State:
        """The physics, events and reward of one control step (obs left as it was: call
        `observe`). A done state stays as it is."""
        d = state.data
        a = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        cmd = policies_observe.scale_action(a, self.limits)
        m = self.model(d.world)
        carry = rollout_step.Carry(sim=d.sim, done=state.done > 0, anchor=d.anchor)
        nxt, row, reason = rollout_step.step(m, d.field, d.lane_line, self.half, carry, cmd, d.t,
                                             self.episode)
        p_old, p = sim.pose(d.sim), row.pose
        log = rollout_step.record(d.log, jnp.minimum(d.t, self.n_steps - 1), row, reason)
        parts = env_reward.terms(p_old, p, d.lane_line, reason, self.dt)
        r = env_reward.total(self.cfg.reward, parts)
        d_new = d.replace(sim=nxt.sim, prev_action=a, t=d.t + 1, ret=d.ret + r, log=log,
                          vel=policies_observe.odometry(p_old, sim.pose(nxt.sim), self.dt),
                          anchor=nxt.anchor)
        new = State(data=d_new, obs=state.obs, reward=r,
                    done=(reason != rollout_metrics.RUNNING).astype(jnp.float32),
                    metrics=self._metrics(parts, log, d_new.ret),
                    info={**state.info,
                          "truncation": (reason == rollout_metrics.TIMEOUT).astype(jnp.float32)})
        was_done = state.done > 0
        return jax.tree.map(lambda x, y: jnp.where(was_done, x, y),
                            state.replace(reward=jnp.zeros_like(state.reward)), new)
