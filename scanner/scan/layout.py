"""The scan's cell laid out for its arm: where the object hangs when the configuration does not
say (an arm file's scan without `cell.object_center_m`), chosen by planners/reach.py from the
arm's reach at the views' radius and cached per arm and radius (robots/cache.py); and where it
stands when a table or turntable presents it (`presented`).

The RX60's default cell is its own measured layout and is never searched again, so its scans
stay as they were.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import replace

import numpy as np

from planners.reach import CellReach, ReachSettings, best_center
from reconstruction.common.errors import ScannerError
from robots.arms.default import arm_of
from robots.cache import cache_dir
from scanner.configs.scan import ScanConfig
from scanner.scan.world import software_camera

log = logging.getLogger(__name__)
SCHEMA = "scanner.cell_reach/1"


def reach_settings(config: ScanConfig) -> ReachSettings:
    """The coarse sphere in the scan's own elevation band."""
    views = config.views
    return ReachSettings(
        elevation_min_rad=views.elevation_min_rad, elevation_max_rad=views.elevation_max_rad
    )


# A support's top hides what lies below its plane: views from under it see the carrier.
SUPPORT_MIN_ELEVATION_RAD = 0.0


def presented(config: ScanConfig) -> ScanConfig:
    """`config` with the object where its presentation holds it: a hanging where the cell
    hangs it; on a table or turntable on the support (`cell.support_top_m`, seen from above
    and around), its views in the elevation band above the support's top."""
    cell = config.cell
    centre = cell.presented_center_m(config.presentation)
    if centre == cell.object_center_m:
        return config
    views = config.views
    low = max(views.elevation_min_rad, SUPPORT_MIN_ELEVATION_RAD)
    if low >= views.elevation_max_rad:
        raise ScannerError(
            f"views.elevation_max_rad: a {config.presentation} is seen from above its top "
            f"(elevation > 0), got a band up to {views.elevation_max_rad!r} rad"
        )
    return replace(
        config,
        cell=replace(cell, object_center_m=centre),
        views=replace(views, elevation_min_rad=low),
    )


def laid_out(config: ScanConfig, settings: ReachSettings | None = None) -> ScanConfig:
    """`config` with its object centre: where its presentation holds it (`presented`), the
    configured one, else the best of the arm's reach (`cell_reach`)."""
    config = presented(config)
    if config.cell.object_center_m is not None:
        return config
    reach = cell_reach(config, settings or reach_settings(config))
    log.info(
        "object centre %s: the arm reaches %.0f %% of the %.3f m viewpoint sphere there",
        reach.object_center_m,
        100 * reach.reach_share,
        config.views.radius_m,
    )
    return replace(config, cell=replace(config.cell, object_center_m=reach.object_center_m))


def cell_reach(config: ScanConfig, settings: ReachSettings) -> CellReach:
    """The search of planners/reach.py for this scan's arm, camera, cell and radius; read from
    the cache when it was done before with the same inputs."""
    arm = arm_of(config.robot)
    model, X_FC = software_camera(config)
    key = hashlib.sha256(
        "\n".join(
            [
                SCHEMA,
                arm.model_text,
                arm.identity,
                repr(replace(config.cell, object_center_m=None)),
                repr(config.views.radius_m),
                repr(settings),
                np.round(X_FC, 9).tobytes().hex(),
                np.round(model.X_CR, 9).tobytes().hex(),
            ]
        ).encode()
    ).hexdigest()[:24]
    path = cache_dir() / "cell_reach" / f"{arm.name}-{key}.json"
    if path.is_file():
        d = json.loads(path.read_text())
        candidates = tuple((tuple(c["object_center_m"]), c["reach_share"]) for c in d["candidates"])
        return CellReach(tuple(d["object_center_m"]), d["reach_share"], candidates)
    reach = best_center(arm, config.cell, X_FC, model.X_CR, config.views.radius_m, settings)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"schema": SCHEMA, **reach.as_dict()}, indent=2) + "\n")
    tmp.replace(path)
    return reach
