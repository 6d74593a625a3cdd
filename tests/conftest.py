"""Shared fixtures: the simulated world is built once per session (it is the slow part)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(relative: str) -> Path:
    """A file of ../shared/data, or skip the test when the shared folder is absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared data not available: {path}")
    return path


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Generated objects go to a per-session cache, never to the user's ~/.cache."""
    import os

    os.environ.setdefault("SCANNER_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="session")
def vase_sim():
    from robots.models.workcell import WorkcellConfig
    from robots.simulation.cell import create_simulation
    from robots.simulation.truth import ErrorModel

    return create_simulation(WorkcellConfig(), "vase", ErrorModel(seed=3))


@pytest.fixture(scope="session")
def view_q(vase_sim):
    """A reachable configuration looking at the object (from the preview's search)."""
    from scanner.scan.preview import first_reachable_view

    return first_reachable_view(vase_sim, 0.5)[1]
