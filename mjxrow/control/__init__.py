"""Controllers: the oracle, SegZeros and SegMin (`base`), and perception in the loop
(`perception`: render → segment → mask controller)."""

from mjxrow.control.base import *  # noqa: F403
from mjxrow.control.base import CONTROLLERS, Controller, Obs, Policy, as_policy, get  # noqa: F401
