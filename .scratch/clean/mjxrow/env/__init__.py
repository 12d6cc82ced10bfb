"""Training environments on the run builder, Brax / MuJoCo Playground style: `Env(run, cfg)`
with `reset(rng) -> State` and `step(state, action) -> State` on one world (`core`), domain
randomisation over the whole generator (`randomize`), reward terms and end events (`reward`),
the observation shared with the `policy` controller (`observe`), and the episode / vmap /
auto-reset wrappers (`wrappers`)."""

from mjxrow.env.core import Env, EnvConfig, EnvData, State, teacher_run
from mjxrow.env.randomize import RANGES, Pool, Randomize, default_ranges, make_pool
from mjxrow.env.reward import TERMS, RewardConfig
from mjxrow.env.wrappers import AutoResetWrapper, EpisodeWrapper, VmapWrapper, Wrapper
from mjxrow.policies.observe import KINDS, ObsSpec, Segmenter, odometry, scale_action

__all__ = ["KINDS", "RANGES", "TERMS", "AutoResetWrapper", "Env", "EnvConfig", "EnvData",
           "EpisodeWrapper", "ObsSpec", "Pool", "Randomize", "RewardConfig", "Segmenter", "State",
           "VmapWrapper", "Wrapper", "default_ranges", "make_pool", "odometry", "scale_action",
           "teacher_run"]
