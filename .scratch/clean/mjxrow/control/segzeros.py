"""SegZeros and SegMin: steering from a binary plant mask (the paper's controller and its
minimum-histogram variant), with the end-of-row behaviours.

Signs: ω > 0 turns left (counter-clockwise, yaw increasing). Image column 0 is the LEFT edge of
the image, so a free lane left of the image centre (x_c < w/2, d < 0) gives ω > 0.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow.control.base import Controller, Obs, register, wrap_angle

LAWS = ("linear", "quadratic")
METHODS = ("zeros", "min")
ON_END = ("straight", "lane", "stop", "hold")
VARIANTS = ("paper", "public")

@struct.dataclass
class SegParams:
    """Parameters of SegZeros (method "zeros") and SegMin (method "min")."""

    v_max: jax.Array  # v at d = 0 before clipping [m/s]
    omega_gain: jax.Array  # ω gain [rad/s]
    v_limit: jax.Array  # clip of |v| [m/s]
    omega_limit: jax.Array  # clip of |ω| [rad/s]
    min_run: jax.Array  # zero-column runs of ≤ min_run columns are dropped [columns]
    end_frac: jax.Array  # a run wider than end_frac·w means end of row [-]
    min_count: jax.Array  # a column with ≤ min_count plant pixels counts as free [pixels]
    ema_alpha: jax.Array  # EMA on commands: cmd = α·new + (1 − α)·previous (1 = off) [-]
    depth_max: jax.Array  # plant pixels farther than this (or depth 0) are ignored [m]
    heading_alpha: jax.Array  # EMA factor of the in-row heading that on_end "straight" holds [-]
    lane_alpha: jax.Array  # EMA factor of the in-row line's direction (on_end "lane") [-]
    lane_xy_alpha: jax.Array  # EMA factor of the in-row line's point (on_end "lane") [-]
    lane_k_yaw: jax.Array  # on_end "lane": ω per rad of heading error [rad/s / rad]
    lane_k_lat: jax.Array  # on_end "lane": ω per m of lateral offset from the line [rad/s / m]
    method: str = struct.field(pytree_node=False, default="zeros")  # "zeros" | "min"
    law: str = struct.field(pytree_node=False, default="linear")  # "linear" | "quadratic"
    n_frames: int = struct.field(pytree_node=False, default=1)  # masks OR'd (sliding window)
    smooth: int = struct.field(pytree_node=False, default=11)  # SegMin moving-average width
    on_end: str = struct.field(pytree_node=False, default="straight")  # see seg_params
    image_hw: tuple[int, int] | None = struct.field(pytree_node=False, default=None)


def seg_params(method: str = "zeros", variant: str = "paper", *, v_max: float = 1.0,
               omega_gain: float = 3.0, v_limit: float = 0.5, omega_limit: float = 1.0,
               min_run: int = 3, end_frac: float = 0.8, min_count: int = 0,
               ema_alpha: float | None = None, depth_max: float | None = None,
               n_frames: int | None = None, law: str | None = None, smooth: int = 11,
               on_end: str = "straight", heading_alpha: float = 0.005,
               lane_alpha: float = 0.005, lane_xy_alpha: float = 0.02, lane_k_yaw: float = 1.5,
               lane_k_lat: float = 1.0,
               image_hw: tuple[int, int] | None = None) -> SegParams:
    """SegParams for `method` ("zeros": SegZeros, "min": SegMin) and `variant`:

    - "paper": ω = −ω_gain·d/(w/2), no EMA, one mask, no depth cut;
    - "public" (the authors' public code): ω = −sign(d)·ω_gain·K with K = d²/(w/2)², EMA
      α = 0.5 on the commands, OR of the last 3 masks (a sliding window; `image_hw` needed),
      plant pixels with depth > 5 m ignored.

    Both: v = v_max·(1 − d²/(w/2)²), v_max = 1, ω_gain = 3, then clipped to v_limit = 0.5 m/s
    and ω_limit = 1.0 rad/s. Explicit keyword values override the variant's.

    on_end, at the end of a row (SegZeros: no zero-column run left after dropping runs of
    ≤ min_run columns, or the longest wider than end_frac·w; SegMin: no plant pixel at all):
    "straight" drives on at v_limit holding the heading the robot had inside the row (so that
    an episode can reach a goal at the row's end), "lane" drives on at v_limit following the
    line the robot drove inside the row (heading and lateral position), "stop" commands (0, 0)
    as the public code does, "hold" keeps the last command.

    Why the end-of-row behaviours are as they are, and what they measured on pear:
    docs/controller.md."""
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; expected one of {METHODS}")
    presets = {"paper": dict(law="linear", ema_alpha=1.0, n_frames=1, depth_max=float("inf")),
               "public": dict(law="quadratic", ema_alpha=0.5, n_frames=3, depth_max=5.0)}
    if variant not in presets:
        raise ValueError(f"variant: unknown {variant!r}; expected one of {tuple(presets)}")
    base = presets[variant]
    law = base["law"] if law is None else law
    ema_alpha = base["ema_alpha"] if ema_alpha is None else ema_alpha
    n_frames = base["n_frames"] if n_frames is None else n_frames
    depth_max = base["depth_max"] if depth_max is None else depth_max
    if law not in LAWS:
        raise ValueError(f"law: unknown {law!r}; expected one of {LAWS}")
    if on_end not in ON_END:
        raise ValueError(f"on_end: unknown {on_end!r}; expected one of {ON_END}")
    if not 0 < ema_alpha <= 1:
        raise ValueError(f"ema_alpha: must lie in (0, 1], got {ema_alpha}")
    if not 0 < heading_alpha <= 1:
        raise ValueError(f"heading_alpha: must lie in (0, 1], got {heading_alpha}")
    for name, a in (("lane_alpha", lane_alpha), ("lane_xy_alpha", lane_xy_alpha)):
        if not 0 < a <= 1:
            raise ValueError(f"{name}: must lie in (0, 1], got {a}")
    for name, gain in (("lane_k_yaw", lane_k_yaw), ("lane_k_lat", lane_k_lat)):
        if not gain >= 0:
            raise ValueError(f"{name}: must be non-negative, got {gain}")
    if int(n_frames) < 1:
        raise ValueError(f"n_frames: must be at least 1, got {n_frames}")
    if n_frames > 1 and image_hw is None:
        raise ValueError("image_hw: needed (height, width) to buffer masks when n_frames > 1")
    if smooth < 1 or smooth % 2 == 0:
        raise ValueError(f"smooth: must be a positive odd width, got {smooth}")
    f = lambda x: np.asarray(x, np.float32)  # noqa: E731 (host: stacked per batch on the host)
    return SegParams(v_max=f(v_max), omega_gain=f(omega_gain), v_limit=f(v_limit),
                     omega_limit=f(omega_limit), min_run=f(min_run), end_frac=f(end_frac),
                     min_count=f(min_count), ema_alpha=f(ema_alpha), depth_max=f(depth_max),
                     heading_alpha=f(heading_alpha), lane_alpha=f(lane_alpha),
                     lane_xy_alpha=f(lane_xy_alpha), lane_k_yaw=f(lane_k_yaw),
                     lane_k_lat=f(lane_k_lat), method=method, law=law,
                     n_frames=int(n_frames), smooth=int(smooth), on_end=on_end,
                     image_hw=None if image_hw is None else tuple(image_hw))


@struct.dataclass
class SegState:
    cmd: jax.Array  # float32 [2], last command (v, ω)
    masks: jax.Array  # bool [n_frames − 1, H, W], previous masks, newest first
    end_of_row: jax.Array  # bool [], the last step saw the end of the row
    yaw_ref: jax.Array  # float32 [], heading held at the end of the row (EMA of the yaw) [rad]
    has_ref: jax.Array  # bool [], yaw_ref (and the lane line) hold measured values
    lane_yaw: jax.Array  # float32 [], direction of the in-row line (EMA of the yaw) [rad]
    lane_xy: jax.Array  # float32 [2], a point of the in-row line (EMA of x, y) [m]


def seg_init(params: SegParams) -> SegState:
    h, w = params.image_hw or (0, 0)
    return SegState(cmd=jnp.zeros(2, jnp.float32),
                    masks=jnp.zeros((params.n_frames - 1, h, w), bool),
                    end_of_row=jnp.zeros((), bool), yaw_ref=jnp.zeros((), jnp.float32),
                    has_ref=jnp.zeros((), bool), lane_yaw=jnp.zeros((), jnp.float32),
                    lane_xy=jnp.zeros(2, jnp.float32))



def _yaw_ema(ref: jax.Array, has_ref: jax.Array, yaw: jax.Array, alpha: jax.Array,
             end: jax.Array) -> jax.Array:
    """EMA [rad] of the yaw with factor alpha on the wrapped difference (continuous across
    ±π); the first yaw when there is no reference yet; unchanged when `end`."""
    new = jnp.where(has_ref, ref + alpha * wrap_angle(yaw - ref), yaw)
    return jnp.where(end, ref, wrap_angle(new)).astype(jnp.float32)


def heading_reference(params: SegParams, state: SegState, yaw: jax.Array,
                      end: jax.Array) -> jax.Array:
    """The heading [rad] on_end "straight" holds, updated with this step's yaw [rad] unless the
    step sees the end of the row (`end`): the first yaw, then an EMA with factor
    heading_alpha (on the wrapped difference, so it is continuous across ±π)."""
    return _yaw_ema(state.yaw_ref, state.has_ref, yaw, params.heading_alpha, end)


def lane_reference(params: SegParams, state: SegState, pose: jax.Array,
                   end: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The line on_end "lane" follows, updated with this step's pose (x [m], y [m], yaw [rad])
    unless the step sees the end of the row (`end`): (direction [rad] [], point [m] [2]), the
    EMA with factor lane_alpha of the yaw (wrapped, as `heading_reference`) and the EMA with
    factor lane_xy_alpha of (x, y); the first pose when there is no reference yet."""
    yaw = _yaw_ema(state.lane_yaw, state.has_ref, pose[2], params.lane_alpha, end)
    xy = pose[:2]
    new = jnp.where(state.has_ref, state.lane_xy + params.lane_xy_alpha * (xy - state.lane_xy), xy)
    return yaw, jnp.where(end, state.lane_xy, new).astype(jnp.float32)


def lane_command(params: SegParams, pose: jax.Array, lane_yaw: jax.Array,
                 lane_xy: jax.Array) -> jax.Array:
    """ω [rad/s] [] that steers the pose (x [m], y [m], yaw [rad]) onto the line through
    lane_xy [m] [2] with direction lane_yaw [rad]: −lane_k_yaw·wrap(yaw − lane_yaw) −
    lane_k_lat·e_lat, clipped to ±omega_limit; e_lat [m] is the offset from the line,
    positive to the left of its direction (so a robot left of the line turns right, ω < 0)."""
    d = pose[:2] - lane_xy
    e_lat = -jnp.sin(lane_yaw) * d[0] + jnp.cos(lane_yaw) * d[1]
    omega = (-params.lane_k_yaw * wrap_angle(pose[2] - lane_yaw)
             - params.lane_k_lat * e_lat)
    return jnp.clip(omega, -params.omega_limit, params.omega_limit).astype(jnp.float32)


def free_runs(free: jax.Array) -> jax.Array:
    """Lengths of runs of True in `free` (bool [W]): at the last column of each run its
    length, 0 elsewhere. int32 [W]; no Python loop over columns (a cumulative max)."""
    idx = jnp.arange(free.shape[-1])
    last_blocked = jax.lax.cummax(jnp.where(free, -1, idx), axis=0)
    ends = free & ~jnp.concatenate([free[1:], jnp.zeros(1, bool)])
    return jnp.where(ends, idx - last_blocked, 0).astype(jnp.int32)


def segzeros_target(hist: jax.Array, params: SegParams) -> tuple[jax.Array, jax.Array]:
    """SegZeros on a column histogram hist [W] (plant pixels per column): the centre x_c of
    the longest run of free columns, in pixels from the image's left edge (column c spans
    [c, c + 1)), and the end-of-row flag. Runs of ≤ min_run columns are dropped; no run, or
    the longest wider than end_frac·W, is the end of the row."""
    W = hist.shape[-1]
    length = free_runs(hist <= params.min_count)
    length = jnp.where(length > params.min_run, length, 0)
    last = jnp.argmax(length)  # first of the longest runs
    L = length[last]
    x_c = last + 1.0 - 0.5 * L
    end = (L == 0) | (L > params.end_frac * W)
    return x_c.astype(jnp.float32), end


def segmin_target(hist: jax.Array, params: SegParams) -> tuple[jax.Array, jax.Array]:
    """SegMin on a column histogram hist [W]: normalise to its maximum, smooth with a moving
    average of `smooth` columns (edges padded with the first/last fully averaged value), take
    the mean position of the columns at the minimum; end of row when no plant pixel is seen.
    Returns (x_c [pixels from the left edge], end_of_row)."""
    W, k = hist.shape[-1], params.smooth
    h = hist.astype(jnp.float32)
    top = jnp.max(h)
    h = h / jnp.maximum(top, 1e-9)
    if k > 1:
        if W < k + 4:
            raise ValueError(f"smooth: window {k} too wide for an image {W} columns wide")
        h = jnp.convolve(h, jnp.ones(k, jnp.float32) / k, mode="same")
        idx = jnp.arange(W)
        h = jnp.where(idx <= k // 2, h[k // 2 + 1], h)
        h = jnp.where(idx >= W - k // 2 - 1, h[W - k // 2 - 2], h)
    at_min = h <= jnp.min(h) + 1e-6
    x_c = jnp.sum(jnp.where(at_min, jnp.arange(W) + 0.5, 0.0)) / jnp.sum(at_min)
    return x_c.astype(jnp.float32), top <= 0


def steering_law(x_c: jax.Array, width: int, params: SegParams) -> jax.Array:
    """(v, ω) [2] from the target column x_c [pixels] of an image `width` columns wide.

    d = x_c − w/2, K = d²/(w/2)², v = v_max·(1 − K); "linear": ω = −ω_gain·d/(w/2),
    "quadratic": ω = −sign(d)·ω_gain·K; then |v| ≤ v_limit, |ω| ≤ omega_limit."""
    half = 0.5 * width
    dn = (x_c - half) / half
    K = dn * dn
    if params.law == "linear":
        omega = -params.omega_gain * dn
    else:
        omega = -jnp.sign(dn) * params.omega_gain * K
    v = params.v_max * (1.0 - K)
    return jnp.stack([jnp.clip(v, -params.v_limit, params.v_limit),
                      jnp.clip(omega, -params.omega_limit, params.omega_limit)])


def seg_command(params: SegParams, mask: jax.Array, depth: jax.Array | None = None,
                prev_cmd: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """One SegZeros/SegMin decision, no memory: mask bool (or probability, > 0.5) [H, W],
    depth float32 [H, W] or None, prev_cmd [2] (used by on_end "hold"). Returns (cmd [2],
    end_of_row bool [])."""
    m = mask if mask.dtype == bool else mask > 0.5
    if depth is not None:
        m = m & (depth > 0) & (depth <= params.depth_max)
    hist = jnp.sum(m, axis=0)
    target = segzeros_target if params.method == "zeros" else segmin_target
    x_c, end = target(hist, params)
    cmd = steering_law(x_c, mask.shape[-1], params)
    if params.on_end in ("straight", "lane"):
        end_cmd = jnp.stack([params.v_limit, jnp.zeros_like(params.v_limit)])
    elif params.on_end == "stop":
        end_cmd = jnp.zeros(2, jnp.float32)
    else:
        end_cmd = jnp.zeros(2, jnp.float32) if prev_cmd is None else prev_cmd
    return jnp.where(end, end_cmd, cmd).astype(jnp.float32), end


def seg_act(params: SegParams, state: SegState, obs: Obs) -> tuple[SegState, jax.Array]:
    """SegZeros / SegMin step: OR the mask with the buffered ones, decide (at the end of the
    row with on_end "straight": hold the in-row heading; "lane": follow the in-row line; see
    `seg_params`), smooth with the EMA. Needs obs.mask (bool [H, W]) and obs.pose (x, y, yaw);
    obs.depth is used when present. Inside the row the command does not depend on on_end."""
    if obs.mask is None:
        raise ValueError("mask: the seg controllers need obs.mask (use with_perception)")
    mask = obs.mask if obs.mask.dtype == bool else obs.mask > 0.5
    if params.n_frames > 1:
        if state.masks.shape[1:] != mask.shape:
            raise ValueError(f"image_hw: params say {state.masks.shape[1:]}, the mask is "
                             f"{mask.shape}")
        used = mask | jnp.any(state.masks, axis=0)
        masks = jnp.concatenate([mask[None], state.masks[:-1]], 0)
    else:
        used, masks = mask, state.masks
    new, end = seg_command(params, used, obs.depth, state.cmd)
    yaw = obs.pose[2]
    yaw_ref = heading_reference(params, state, yaw, end)
    lane_yaw, lane_xy = lane_reference(params, state, obs.pose, end)
    has_ref = state.has_ref | ~end
    if params.on_end in ("straight", "lane"):
        if params.on_end == "straight":
            hold = jnp.clip(-params.omega_gain * wrap_angle(yaw - yaw_ref),
                            -params.omega_limit, params.omega_limit)
        else:
            hold = lane_command(params, obs.pose, lane_yaw, lane_xy)
        new = jnp.where(end & has_ref, new.at[1].set(hold), new).astype(jnp.float32)
    cmd = params.ema_alpha * new + (1.0 - params.ema_alpha) * state.cmd
    return SegState(cmd=cmd, masks=masks, end_of_row=end, yaw_ref=yaw_ref, has_ref=has_ref,
                    lane_yaw=lane_yaw, lane_xy=lane_xy), cmd



@dataclasses.dataclass(frozen=True)
class SegConfig:
    """SegZeros / SegMin settings (YAML section `controller` with `name: segzeros` or
    `segmin`): the keyword arguments of `seg_params` under the same names. None takes the
    variant's value. Numbers are traced except the structural ones (`STATIC`)."""

    variant: str = "paper"  # law preset: the paper's (linear ω) or the authors' public code's
    # (quadratic ω, EMA 0.5, 3-frame mask OR, 5 m depth cut)
    v_max: float = 1.0  # m/s, v = v_max·(1 − d²) at the free run's offset d, before the v_limit
    # clip
    omega_gain: float = 3.0  # rad/s, ω = −omega_gain·d with d the free run's centre offset
    # normalised by w/2
    v_limit: float = 0.5  # m/s, clip of |v|
    omega_limit: float = 1.0  # rad/s, clip of |ω|
    min_run: int = 3  # px, free-column runs of at most this many columns are dropped
    end_frac: float = 0.8  # -, a free run wider than this fraction of the image width means end of
    # row
    min_count: int = 0  # px, a column with at most this many plant pixels counts as free
    ema_alpha: float | None = None  # -, EMA factor on the commands (1 = off); None: the variant's
    # (paper 1, public 0.5)
    depth_max: float | None = None  # m, mask pixels farther than this are ignored; None: the
    # variant's (paper none, public 5)
    n_frames: int | None = None  # count, masks OR'd over the last n frames; None: the variant's
    # (paper 1, public 3)
    law: str | None = None  # steering law, linear or quadratic; None: the variant's
    smooth: int = 11  # px, segmin: moving-average width of the column histogram (odd)
    on_end: str = "straight"  # at the end of a row: hold the in-row heading (straight), follow the
    # in-row line from odometry (lane), stop, or hold the last command
    heading_alpha: float = 0.005  # -, on_end straight: EMA factor per control step of the in-row
    # heading it holds (0.005 at 15 Hz: about 13 s)
    lane_alpha: float = 0.005  # -, on_end lane: EMA factor of the in-row line's direction
    lane_xy_alpha: float = 0.02  # -, on_end lane: EMA factor of a point of the in-row line
    lane_k_yaw: float = 1.5  # rad/s per rad, on_end lane: ω per rad of heading error
    lane_k_lat: float = 1.0  # rad/s per m, on_end lane: ω per m of lateral offset from the line

    STATIC: ClassVar[tuple[str, ...]] = ("variant", "n_frames", "law", "smooth", "on_end")
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"variant": VARIANTS, "law": LAWS,
                                                     "on_end": ON_END}


def _seg_maker(method: str):
    def make(cfg: SegConfig, image_hw: tuple[int, int] | None = None) -> SegParams:
        """Traced params of a SegConfig for an image of image_hw = (height, width) pixels."""
        kw = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}
        variant = kw.pop("variant")
        try:
            return seg_params(method, variant, image_hw=image_hw, **kw)
        except ValueError as e:
            msg = str(e)
            raise ValueError(msg if msg.startswith("controller.") else f"controller.{msg}") \
                from None

    return make


SEGZEROS = register(Controller("segzeros", SegConfig, _seg_maker("zeros"), seg_init, seg_act,
                               needs_mask=True))
SEGMIN = register(Controller("segmin", SegConfig, _seg_maker("min"), seg_init, seg_act,
                             needs_mask=True))
