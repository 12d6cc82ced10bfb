"""The candidate streams: CMA-ES (evosax), uniform random and scrambled Sobol sampling, each in
the normalised box [0, 1]^d, one generation of `population` candidates at a time.

Every stream is a pure function of (seed, generation) and its saved state, so that a resumed
search asks for exactly the candidates the uninterrupted one would have:

- `random`: generation g is `default_rng([seed, RANDOM, g]).random((P, d))`;
- `sobol`: points g·P … g·P + P − 1 of one scrambled Sobol sequence (seeded);
- `cma_es`: evosax's CMA-ES, its key `fold_in(fold_in(key(seed), restart), g)`, its state (mean,
  step size, covariance, paths) saved as numbers after every generation (`state` / `load`).
  The first run starts at the box's centre with step `sigma`; samples outside [0, 1]^d are
  evaluated at the nearest point of the box (clipped) and told with the squared distance to it
  added to their fitness. It restarts from a random point (`restart`) when `patience`
  generations passed without progress, or when its steps became smaller than a tenth of the
  merge radius (it has converged onto one failure).
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from evosax.algorithms import CMA_ES
from scipy.stats import qmc

RANDOM, SOBOL, RESTART = 11, 13, 17  # stream tags in the seeds of the host generators


@functools.lru_cache(maxsize=8)
def _es(population: int, d: int) -> CMA_ES:
    """One CMA_ES object per (population, dimension): evosax jits its methods per object."""
    return CMA_ES(population_size=population, solution=jnp.zeros(d, jnp.float32))


class Stream:
    """A method's candidates: `ask(g)` → (u [P, d] in [0, 1], raw samples [P, d]);
    `tell(g, raw, fitness)` (lower is better); `state()` / `load(state)` for resume."""

    name = ""

    def __init__(self, d: int, population: int, seed: int):
        self.d, self.population, self.seed = d, population, seed

    def ask(self, generation: int) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def tell(self, generation: int, raw: np.ndarray, fitness: np.ndarray) -> None:
        del generation, raw, fitness

    def state(self) -> dict[str, Any]:
        return {}

    def load(self, state: dict[str, Any]) -> None:
        del state

    def spread(self) -> float:
        """The stream's current step size in normalised coordinates (1 for samplers)."""
        return 1.0


class Random(Stream):
    name = "random"

    def ask(self, generation: int) -> tuple[np.ndarray, np.ndarray]:
        u = np.random.default_rng([self.seed, RANDOM, generation]).random(
            (self.population, self.d))
        return u, u


class Sobol(Stream):
    name = "sobol"

    def ask(self, generation: int) -> tuple[np.ndarray, np.ndarray]:
        eng = qmc.Sobol(self.d, scramble=True, seed=np.random.default_rng([self.seed, SOBOL]))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # not a power of two: still spread
            eng.fast_forward(generation * self.population)
            u = eng.random(self.population)
        return u, u


class CMAES(Stream):
    name = "cma_es"

    def __init__(self, d: int, population: int, seed: int, sigma: float = 0.3):
        super().__init__(d, population, seed)
        self.es = _es(population, d)
        self.params = self.es.default_params.replace(std_init=jnp.float32(sigma))
        self.restarts = 0
        self.es_state = self._init(np.full(d, 0.5))

    def _key(self, generation: int) -> jax.Array:
        return jax.random.fold_in(jax.random.fold_in(jax.random.key(self.seed), self.restarts),
                                  generation)

    def _init(self, mean: np.ndarray):
        return self.es.init(jax.random.key(self.seed), jnp.asarray(mean, jnp.float32),
                            self.params)

    def ask(self, generation: int) -> tuple[np.ndarray, np.ndarray]:
        x, asked = self.es.ask(self._key(generation), self.es_state, self.params)
        self._asked = (generation, self.restarts, asked)  # with C's eigenvectors, for tell
        raw = np.asarray(x, np.float64)
        return np.clip(raw, 0.0, 1.0), raw

    def tell(self, generation: int, raw: np.ndarray, fitness: np.ndarray) -> None:
        asked = getattr(self, "_asked", None)
        if asked is None or asked[:2] != (generation, self.restarts):
            self.ask(generation)
        state = self._asked[2]
        x = jnp.asarray(raw, jnp.float32)
        self.es_state, _ = self.es.tell(self._key(generation), x,
                                        jnp.asarray(fitness, jnp.float32), state, self.params)

    def restart(self) -> None:
        """Start again from a uniform random point of the box with the initial step size."""
        self.restarts += 1
        mean = np.random.default_rng([self.seed, RESTART, self.restarts]).random(self.d)
        self.es_state = self._init(mean)

    def spread(self) -> float:
        s = self.es_state
        return float(s.std) * float(np.sqrt(np.max(np.diag(np.asarray(s.C)))))

    def state(self) -> dict[str, Any]:
        leaves = jax.tree.leaves(self.es_state)
        return {"restarts": self.restarts,
                "es": [{"dtype": str(np.asarray(x).dtype), "shape": list(np.shape(x)),
                        "values": np.asarray(x).reshape(-1).tolist()} for x in leaves]}

    def load(self, state: dict[str, Any]) -> None:
        self.restarts = int(state["restarts"])
        template = self._init(np.full(self.d, 0.5))
        leaves, treedef = jax.tree.flatten(template)
        saved = state["es"]
        if len(saved) != len(leaves):
            raise ValueError("state.json: the CMA-ES state does not match this evosax version")
        out = []
        for t, s in zip(leaves, saved, strict=True):
            a = np.asarray(s["values"], dtype=s["dtype"]).reshape(s["shape"])
            if a.shape != np.shape(t):
                raise ValueError("state.json: the CMA-ES state has other shapes than this "
                                 "search's")
            out.append(jnp.asarray(a, dtype=jnp.asarray(t).dtype))
        self.es_state = jax.tree.unflatten(treedef, out)


def make(method: str, d: int, population: int, seed: int, sigma: float = 0.3) -> Stream:
    """The stream of `method` ('cma_es', 'random', 'sobol')."""
    if method == "cma_es":
        return CMAES(d, population, seed, sigma)
    return {"random": Random, "sobol": Sobol}[method](d, population, seed)
