"""The reconstruction's configuration (`processing.reconstruction`): the filter, ICP, pose graph,
hand-eye correction, pass alignment and surfaces, and the named variants that switch the
registration stages (pose only, ICP, corrected) for comparisons on the same captures."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

from reconstruction.common.errors import ScannerError
from reconstruction.handeye.correction import HandEyeConfig
from reconstruction.hangings.alignment import AlignmentConfig
from reconstruction.registration.filtering import FilterConfig
from reconstruction.registration.pairwise import IcpConfig
from reconstruction.registration.posegraph import PoseGraphConfig
from reconstruction.surfaces.config import SurfaceConfig


@dataclass(frozen=True)
class ReconstructionConfig:
    filter: FilterConfig = field(default_factory=FilterConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    handeye: HandEyeConfig = field(default_factory=HandEyeConfig)
    surfaces: SurfaceConfig = field(default_factory=SurfaceConfig)
    # After the hand-eye correction, one more pose graph with the corrected kinematic poses as
    # priors and the same ICP edges, to absorb per-view errors (joint offsets) that no shared
    # X_FC can explain.
    final_pose_graph: bool = False
    min_views: int = 2
    # Putting the passes of a multi-hanging scan into one frame.
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)

    def __post_init__(self) -> None:
        if self.min_views < 1:
            raise ScannerError(f"reconstruction.min_views: must be >= 1, got {self.min_views}")


def _pose_only(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=False), handeye=replace(c.handeye, enabled=False))


def _icp_only(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=True), handeye=replace(c.handeye, enabled=False))


def _corrected(c: ReconstructionConfig) -> ReconstructionConfig:
    return replace(c, icp=replace(c.icp, enabled=True), handeye=replace(c.handeye, enabled=True))


VARIANTS: dict[str, Callable[[ReconstructionConfig], ReconstructionConfig]] = {
    "pose_only": _pose_only,
    "icp": _icp_only,
    "corrected": _corrected,
}


def variant_config(config: ReconstructionConfig, variant: str) -> ReconstructionConfig:
    """The configuration with the ICP / correction flags of a named variant."""
    if variant not in VARIANTS:
        raise ScannerError(f"unknown variant '{variant}'; valid: {', '.join(VARIANTS)}")
    return VARIANTS[variant](config)
