"""The arm the product drives when none is named: the one place that chooses it."""

from robots.arms.arm import Arm
from robots.arms.rx60 import rx60_arm

DEFAULT_ARM: Arm = rx60_arm()
