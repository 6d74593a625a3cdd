"""Open3D imported by the reconstruction package leaves its notebook viewer (Dash, Plotly,
IPython) unimported, and the viewer still works when called."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from reconstruction.common import open3d_loading

FRESH = """
import sys
import numpy as np
import reconstruction, open3d as o3d
heavy = ("dash", "plotly", "IPython")
print([m for m in heavy if m in sys.modules])
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))
print(type(o3d.visualization.get_plotly_fig([cloud])).__name__, "dash" in sys.modules)
"""


def test_open3d_comes_without_its_viewer_until_the_viewer_is_called():
    # A fresh interpreter: this one may have imported Open3D before the package.
    r = subprocess.run([sys.executable, "-c", FRESH], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["[]", "Figure True"]
    # Here: a deferred function answers from the real viewer, whichever module is in place.
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))
    figure = open3d_loading._deferred("get_plotly_fig")([cloud])
    np.testing.assert_array_equal(figure.data[0].x, [1.0, 0.0, 0.0])
