"""Training navigation policies in the batched environments (`mjxrow.env`): the policy network
(`networks`), batched rollouts shared by every algorithm (`rollout`), PPO (`ppo`), behaviour
cloning and DAgger from a teacher controller (`bc`), policy checkpoints and resumable training
states (`checkpoint`), the compiled programs of a run (`programs`), the loop with its
budget, progress bar and log (`loop`), and the learning curve (`curve`).
`experiments/train_policy.py` is the command."""

from mjxrow.policies.checkpoint import PolicyCheckpoint
from mjxrow.policies.networks import TINY, NetConfig, PolicyNet
from mjxrow.train.bc import BCConfig
from mjxrow.train.curve import plot_curve
from mjxrow.train.loop import TrainConfig, train
from mjxrow.train.ppo import PPOConfig
from mjxrow.train.programs import Trainer

__all__ = ["TINY", "BCConfig", "NetConfig", "PPOConfig", "PolicyCheckpoint", "PolicyNet",
           "TrainConfig", "Trainer", "plot_curve", "train"]
