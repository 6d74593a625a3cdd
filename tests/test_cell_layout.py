"""The cell laid out from the arm's reach: the object hangs where the arm reaches most of the
viewpoint sphere, unless the configuration says where (the RX60's default cell stays as it is),
and an object the arm sees from too few directions is refused before anything moves."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from planners.reach import ReachSettings, best_center, candidate_centers, sphere_share
from reconstruction.common.errors import ScannerError
from robots.arms.default import DEFAULT_ARM
from robots.models.camera_tool import nominal_X_FC
from robots.models.workcell import WorkcellConfig
from scanner.configs.scan import ScanConfig, scan_config_from_dict, with_overrides
from scanner.configs.views import ViewpointConfig
from scanner.scan.layout import cell_reach, laid_out
from scanner.scan.viewpoints import generate_viewpoints

ROOT = Path(__file__).resolve().parents[1]
UR5E_FILE = str(ROOT / "scanner" / "configs" / "arms" / "ur5e.yaml")
STEREO = ScanConfig().camera.stereo_camera()
X_FC = nominal_X_FC(STEREO.baseline_m)
# A coarse sphere and a 2 x 2 grid: the search's logic at a few dozen IK requests.
COARSE = ReachSettings(
    directions=12,
    rolls=2,
    distances_of_reach=(0.6, 0.75),
    elevations_rad=(math.radians(30.0), math.radians(60.0)),
)


def test_the_rx60s_measured_cell_is_kept_and_never_searched():
    config = ScanConfig()
    assert laid_out(config) is config
    assert config.cell.object_center_m == (0.40, 0.0, 1.00)
    assert scan_config_from_dict({}, "x").cell.object_center_m == (0.40, 0.0, 1.00)


def test_an_arm_files_scan_without_a_centre_is_laid_out_and_one_with_a_centre_keeps_it():
    assert scan_config_from_dict({"robot": UR5E_FILE}, "x").cell.object_center_m is None
    given = {"robot": UR5E_FILE, "cell": {"object_center_m": [0.45, 0.0, 0.45]}}
    assert scan_config_from_dict(given, "x").cell.object_center_m == (0.45, 0.0, 0.45)
    assert with_overrides(ScanConfig(), robot=UR5E_FILE).cell.object_center_m is None
    with pytest.raises(ValueError, match="not laid out"):
        WorkcellConfig(object_center_m=None).X_WO  # noqa: B018


def test_the_search_picks_the_candidate_whose_sphere_the_arm_reaches_most(tmp_path):
    """On the RX60 (closed-form IK: the search in a second): every candidate is scored, the
    best wins, and its score is the share sphere_share measures there."""
    cell = WorkcellConfig()
    reach = best_center(DEFAULT_ARM, cell, X_FC, STEREO.X_CR, 0.5, COARSE)
    centres = candidate_centers(DEFAULT_ARM, 0.5, COARSE)
    assert [c for c, _ in reach.candidates] == centres and len(centres) == 4
    assert reach.reach_share == max(s for _, s in reach.candidates) > 0
    placed = replace(cell, object_center_m=reach.object_center_m)
    assert sphere_share(DEFAULT_ARM, placed, X_FC, STEREO.X_CR, 0.5, COARSE) == reach.reach_share
    # In front of the arm (+x), above the table.
    assert reach.object_center_m[0] > 0 and reach.object_center_m[2] > 0.15


def test_the_search_is_cached_per_arm_and_radius(tmp_path, monkeypatch):
    monkeypatch.setenv("SCANNER_CACHE", str(tmp_path))
    config = replace(ScanConfig(), cell=replace(ScanConfig().cell, object_center_m=None))
    first = cell_reach(config, COARSE)
    assert len(list((tmp_path / "cell_reach").glob("rx60-*.json"))) == 1
    assert cell_reach(config, COARSE) == first
    other = replace(config, views=replace(config.views, radius_m=0.45))
    cell_reach(other, COARSE)
    assert len(list((tmp_path / "cell_reach").glob("rx60-*.json"))) == 2
    laid = laid_out(config, COARSE)
    assert laid.cell.object_center_m == first.object_center_m


def test_an_object_seen_from_too_few_directions_is_refused_in_one_line():
    """Reachable: a 20 deg cap under the object (3 % of the sphere, about 18 of 600
    directions); 24 views cannot be spread there."""
    axis = np.array([0.0, 0.0, -1.0])

    def reachable(viewpoint):
        d = np.subtract(viewpoint.p_WM, viewpoint.p_WT)
        return [np.zeros(6)] if d @ axis / np.linalg.norm(d) > math.cos(math.radians(20)) else []

    with pytest.raises(ScannerError) as e:
        generate_viewpoints(ViewpointConfig(count=24, roll_candidates=1), (0, 0, 1), reachable)
    message = str(e.value)
    assert message.startswith("views.count: 24 views asked, but only ") and "\n" not in message
    reached = int(message.split("only ")[1].split(" ")[0])
    assert 0 < reached < 24
    assert "cell.object_center_m" in message and "views.radius_m" in message
