"""Policies: what turns a camera or a field into a controller's input, and the learned policy.

`perception` puts render → segment in front of the mask controllers of `mjxrow.control`
(SegZeros, SegMin); `observe` is the learned policy's observation (image, mask or features,
odometry), shared by the training environment and the evaluator; `networks` the policy network;
`checkpoint` its folders on disk; `learned` the `policy` controller, registered here.
"""

from mjxrow.policies import learned, perception  # noqa: F401  (registers `policy`)
from mjxrow.policies.checkpoint import PolicyCheckpoint
from mjxrow.policies.learned import PolicyConfig
from mjxrow.policies.networks import NetConfig, PolicyNet
from mjxrow.policies.observe import KINDS, ObsSpec
from mjxrow.policies.perception import PerceptionConfig

__all__ = ["KINDS", "NetConfig", "ObsSpec", "PerceptionConfig", "PolicyCheckpoint",
           "PolicyConfig", "PolicyNet", "learned", "perception"]
