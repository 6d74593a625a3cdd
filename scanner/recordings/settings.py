"""How an imported recording becomes a model (`scanner reconstruct --config` of a recording).

A recording is not one of this product's scans: one camera, its own scale and distance, a
volume nobody configured. So the settings that depend on scale default to the recording's own:
`auto` sizes (None here) follow the pixel footprint at the working distance, the working
volume comes from the masks or the cameras' common view, and the matcher searches what that
volume spans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from reconstruction.common.checks import check_fields, positive
from reconstruction.common.errors import ScannerError
from reconstruction.config import ReconstructionConfig
from reconstruction.stereo.params import StereoParams
from reconstruction.surfaces.export import MeshExportConfig
from reconstruction.surfaces.meshes import MESH_SUFFIXES
from reconstruction.two_view.cloud import TwoViewConfig
from reconstruction.two_view.pairing import PairingConfig
from reconstruction.working_volume.table import TableConfig

# Which views' masks restrict the clouds: all of them, the even views only (the odd views' masks
# then score the model as views it did not use), or none (the working volume alone).
MASK_USES = ("all", "even", "none")


@dataclass(frozen=True)
class RecordingProcessing:
    # A 5 px block (the product's scans use 3, tuned on the simulator's sharp, noise-free
    # views): real views' sensor noise and soft texture make the 3 px block's matches scatter.
    # Measured on DTU's scan 24 at half resolution, views 10-25, split-half median / p90
    # 0.278 / 0.556 -> 0.268 / 0.540 mm, 3 % more points (scripts/splithalf_experiments.py);
    # all 49 views 0.211 / 0.411 -> 0.205 / 0.398 mm at the same time.
    stereo: StereoParams = field(default_factory=lambda: StereoParams(block_size_px=5))
    # Half resolution: DTU's 1600 x 1200 views matched at 800 x 600 give the model's outline
    # as well as at a quarter (silhouette IoU 0.977 / 0.974) with half its split-half scatter
    # (0.27 / 0.56 mm), at twice the time (scripts/bench_recordings.py).
    two_view: TwoViewConfig = field(default_factory=lambda: TwoViewConfig(downscale=2.0))
    # Each view the reference of TWO pairs (its two nearest usable partners): twice the
    # samples of the surface. Measured on DTU's scan 24, all 49 views at half resolution:
    # split-half median / p90 0.205 / 0.398 -> 0.166 / 0.297 mm, common share 0.971 -> 0.984,
    # IoU 0.974 -> 0.979, for 1.44x the wall time (pairs and filter: 353 -> 509 s, both on a
    # machine loaded by other work). Not a calibration error that the second partner averages:
    # on views 10-25 each pair's median signed distance to the other pairs' points along their
    # normals varies by 7 um (standard deviation) from pair to pair; the split-half median
    # there is mostly the halves' samples lying beside each other (0.15 mm in the plane, 0.09
    # mm along the normal, of 0.198 mm).
    pairing: PairingConfig = field(default_factory=lambda: PairingConfig(pairs_per_view=2))
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    table: TableConfig = field(default_factory=TableConfig)
    masks: str = "all"
    # Register the pair clouds (ICP and pose graph) also when the recording gave calibrated
    # camera poses (flange poses with X_FC are registered as a scan's are). Measured on DTU's
    # scan 24 at a quarter resolution: 9 % less split-half scatter for twice the time.
    register_given_poses: bool = False
    # The working volume (a sphere in the recording's world, metres), or a box (its corners:
    # x, y, z min then x, y, z max, metres, axis-aligned in that world: an object standing on a
    # table is boxed more tightly than sphered); neither: from the masks used, else from the
    # cameras' common view.
    volume_centre_m: tuple[float, float, float] | None = None
    volume_radius_m: float | None = None
    volume_box_m: tuple[float, float, float, float, float, float] | None = None
    # Grid sizes in units of the pixel footprint at the working distance (after downscaling):
    # the per-view filter's and the fused cloud's voxel, and the TSDF's. One footprint keeps
    # every measured point's detail; the product's own scans use 1 mm at 0.38 mm footprints.
    voxel_footprints: float = positive(1.0)
    # The fused cloud (and so the surfaces' input) is coarser: twice the footprint averages the
    # views' overlapping points; the split-half agreement compares the halves at voxel_footprints.
    fused_footprints: float = positive(2.0)
    # Poisson's surface is kept this many footprints from the data: it bridges the gaps stereo
    # leaves on dark or shiny patches (windows, glazed tiles) that the views around them close.
    # Measured on DTU's scan 24 at half resolution, held-out masks: 8 footprints (3.7 mm) IoU
    # 0.978, covered 0.989; 12: 0.974, 0.994; 16: 0.969, 0.996.
    poisson_trim_footprints: float = positive(12.0)
    # Split-half agreement, in footprints of the SOURCE images (not the matching scale: a measure
    # must not move with the method's settings): the halves merged on a grid of one footprint
    # (0.22 mm on DTU's 1600 x 1200 views at 0.65 m, its peer's 0.2 mm merge), their common part
    # within four (about 1 mm there, what the peer counts as common at full resolution).
    split_half_voxel_footprints: float = positive(1.0)
    split_half_common_footprints: float = positive(4.0)
    primary_surface: str = "poisson"
    mesh_formats: tuple[str, ...] = (".ply",)
    mesh_export: MeshExportConfig = field(default_factory=MeshExportConfig)

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
        centre = self.volume_centre_m
        if centre is not None and (
            len(centre) != 3 or not all(math.isfinite(float(c)) for c in centre)
        ):
            raise ScannerError(
                f"recording.volume_centre_m: expected three finite numbers, got {centre}"
            )
        if self.volume_radius_m is not None and not (
            math.isfinite(self.volume_radius_m) and self.volume_radius_m > 0
        ):
            raise ScannerError(
                f"recording.volume_radius_m: expected a positive radius, got {self.volume_radius_m}"
            )
        box = self.volume_box_m
        if box is not None:
            if centre is not None:
                raise ScannerError(
                    "recording.volume_box_m: give a box or a sphere (volume_centre_m, "
                    "volume_radius_m), not both"
                )
            if len(box) != 6 or not all(math.isfinite(float(c)) for c in box):
                raise ScannerError(
                    f"recording.volume_box_m: expected six finite numbers (x, y, z min, then "
                    f"max), got {box}"
                )
            if not all(float(box[i + 3]) > float(box[i]) for i in range(3)):
                raise ScannerError(
                    f"recording.volume_box_m: each maximum must exceed its minimum, got {box}"
                )
        bad = [f for f in self.mesh_formats if f not in MESH_SUFFIXES]
        if bad:
            raise ScannerError(
                f"recording.mesh_formats: {', '.join(map(repr, bad))} not known; expected "
                f"suffixes from {', '.join(MESH_SUFFIXES)}"
            )
        if self.primary_surface not in self.reconstruction.surfaces.methods:
            raise ScannerError(
                f"recording.primary_surface: expected one of the surfaces built "
                f"({', '.join(self.reconstruction.surfaces.methods)}), got {self.primary_surface!r}"
            )
