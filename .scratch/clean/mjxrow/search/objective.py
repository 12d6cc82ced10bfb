"""The objective of a failure search: failure, the continuous margin, and distinct failures.

- **Failure**: an episode fails when it does not reach the goal (any other ending: collision,
  timeout, stuck, off the patch, missed goal, flipped, simulation error). A candidate fails when
  at least `fail_share` of its repeats fail.
- **Margin** (`lane`), per episode: 1 − (max lateral offset) / (half the free width of its lane),
  the free width being the lane's width across the rows (narrowed by the sinusoid's steepest
  angle) less the plants' nominal width and the robot's width: 1 on the centre line, 0 where the
  robot's side reaches the nominal plant line; clipped to [−1, 1]. A failed episode counts −1.
  A candidate's margin is the mean over its repeats; the search minimises it.
- **Distinct failures**: failing candidates nearer than `merge_radius` to each other in the
  normalised box (Euclidean) are one failure. Leader clustering, worst first: candidates sorted
  by (fail rate down, margin up, order found), each joins the first leader within the radius or
  leads a new failure. The leaders, in that order, are the ranked failures.
"""

from __future__ import annotations

import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.rollout import metrics as rollout_metrics

MIN_HALF = 0.01  # m, the half free width below which the margin stops growing finer


def half_free_width(lane_width: np.ndarray, params: dict[str, np.ndarray]) -> np.ndarray:
    """Half the free width [m] of each episode's lane [B]: (lane width across the rows ·
    cos(atan(2πA/λ)) − plant width · scale − robot width) / 2. lane_width [B] (the generated
    field's, metres); params: FieldParams values [B] (host)."""
    slope = 2.0 * np.pi * params["row_amplitude"] / np.maximum(params["row_wavelength"], 1e-9)
    free = (lane_width * np.cos(np.arctan(slope))
            - params["plant_width"] * params["scale"] - mjxrow_field.ROBOT_WIDTH)
    return 0.5 * free


def episode_margin(reason: np.ndarray, max_offset: np.ndarray, half_free: np.ndarray
                   ) -> np.ndarray:
    """Margin [B] of each episode (module doc): −1 for a failed episode."""
    m = 1.0 - np.nan_to_num(max_offset, nan=np.inf) / np.maximum(half_free, MIN_HALF)
    return np.where(reason == rollout_metrics.GOAL, np.clip(m, -1.0, 1.0), -1.0)


def failed(reason: np.ndarray) -> np.ndarray:
    """bool [B]: the episode did not reach the goal."""
    return np.asarray(reason) != rollout_metrics.GOAL


def cluster(U: np.ndarray, fail_rate: np.ndarray, margin: np.ndarray, radius: float
            ) -> tuple[np.ndarray, list[int]]:
    """Distinct failures among N failing candidates (module doc): (label [N], the 0-based
    index into U of each failure's leader, ranked). U [N, d] normalised coordinates."""
    order = np.lexsort((np.arange(len(U)), margin, -fail_rate))
    leaders: list[int] = []
    label = np.full(len(U), -1)
    centres = np.empty((len(U), U.shape[1] if U.ndim == 2 else 0))
    for i in order:
        dist = np.linalg.norm(centres[:len(leaders)] - U[i], axis=1)
        hit = np.flatnonzero(dist < radius)
        if hit.size:
            label[i] = hit[0]
        else:
            label[i] = len(leaders)
            centres[len(leaders)] = U[i]
            leaders.append(int(i))
    return label, leaders


def extend_distinct(seen: np.ndarray, U: np.ndarray, radius: float) -> np.ndarray:
    """`seen` [K, d] (the distinct failures so far, `count_distinct`'s order) with the new
    failures of U [N, d] (in the order found) that lie farther than `radius` from all."""
    for u in U:
        if not np.any(np.linalg.norm(seen - u, axis=1) < radius):
            seen = np.concatenate([seen, u[None]])
    return seen


def count_distinct(U: np.ndarray, radius: float) -> np.ndarray:
    """Distinct failures found so far after each of N failing candidates in the order found
    (int [N], greedy: a failure is new when no earlier new one lies within the radius)."""
    seen = np.empty((len(U), U.shape[1] if U.ndim == 2 else 0))
    k = 0
    out = np.zeros(len(U), int)
    for i, u in enumerate(U):
        if not np.any(np.linalg.norm(seen[:k] - u, axis=1) < radius):
            seen[k] = u
            k += 1
        out[i] = k
    return out


def near(U: np.ndarray, known: np.ndarray, radius: float) -> np.ndarray:
    """bool [N]: each point of U [N, d] lies within `radius` of one of `known` [K, d]."""
    if len(known) == 0 or len(U) == 0:
        return np.zeros(len(U), bool)
    dist = np.linalg.norm(U[:, None, :] - known[None, :, :], axis=-1)
    return np.any(dist < radius, axis=1)
