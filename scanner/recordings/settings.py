"""How an imported recording becomes a model (`scanner reconstruct --config` of a recording).

A recording is not one of this product's scans: one camera, its own scale and distance, a
volume nobody configured. So the settings that depend on scale default to the recording's own:
`auto` sizes (None here) follow the pixel footprint at the working distance, the working
volume comes from the masks or the cameras' common view, and the matcher searches what that
volume spans.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from reconstruction.common.checks import check_fields, positive
from reconstruction.common.errors import ScannerError
from reconstruction.pipeline import ReconstructionConfig
from reconstruction.stereo.params import StereoParams
from reconstruction.two_view.cloud import TwoViewConfig
from reconstruction.two_view.pairing import PairingConfig
from reconstruction.working_volume.table import TableConfig

# Which views' masks restrict the clouds: all of them, the even views only (the odd views' masks
# then score the model as views it did not use), or none (the working volume alone).
MASK_USES = ("all", "even", "none")


@dataclass(frozen=True)
class RecordingProcessing:
    stereo: StereoParams = field(default_factory=StereoParams)
    two_view: TwoViewConfig = field(default_factory=TwoViewConfig)
    pairing: PairingConfig = field(default_factory=PairingConfig)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    table: TableConfig = field(default_factory=TableConfig)
    masks: str = "all"
    # The working volume (a sphere in the recording's world, metres); None: from the masks
    # used, else from the cameras' common view.
    volume_centre_m: tuple[float, float, float] | None = None
    volume_radius_m: float | None = None
    # Grid sizes in units of the pixel footprint at the working distance (after downscaling):
    # the per-view filter's and the fused cloud's voxel, and the TSDF's. One footprint keeps
    # every measured point's detail; the product's own scans use 1 mm at 0.38 mm footprints.
    voxel_footprints: float = positive(1.0)
    # Split-half agreement: the common part is where the halves lie within this many voxels.
    split_half_common_voxels: float = positive(5.0)
    primary_surface: str = "poisson"
    mesh_formats: tuple[str, ...] = (".ply",)

    def __post_init__(self) -> None:
        check_fields("recording", self)
        if self.masks not in MASK_USES:
            raise ScannerError(
                f"recording.masks: expected one of {', '.join(MASK_USES)}, got {self.masks!r}"
            )
        if (self.volume_centre_m is None) != (self.volume_radius_m is None):
            raise ScannerError(
                "recording.volume_centre_m, volume_radius_m: give both (a sphere) or neither"
            )
        if self.volume_radius_m is not None and not self.volume_radius_m > 0:
            raise ScannerError(
                f"recording.volume_radius_m: expected a positive radius, got {self.volume_radius_m}"
            )
        if self.primary_surface not in self.reconstruction.surfaces.methods:
            raise ScannerError(
                f"recording.primary_surface: expected one of the surfaces built "
                f"({', '.join(self.reconstruction.surfaces.methods)}), got {self.primary_surface!r}"
            )
