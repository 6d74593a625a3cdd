"""reconstruction/ is pure numeric code: importing all of it must not pull in Drake."""

import subprocess
import sys

CHECK = """
import importlib, pkgutil, sys
import reconstruction
names = [m.name for m in pkgutil.walk_packages(reconstruction.__path__, "reconstruction.")]
for name in names:
    importlib.import_module(name)
assert "reconstruction.stereo" in names, names
upper = ("pydrake", "robots", "planners", "scanner")
leaked = sorted(m for m in sys.modules if m.split(".")[0] in upper)
print(len(names), leaked)
"""


def test_reconstruction_imports_no_drake_and_no_upper_layer():
    result = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    count, leaked = result.stdout.split(maxsplit=1)
    assert int(count) >= 6  # camera_model, errors, rectification, stereo, ... were all imported
    assert leaked.strip() == "[]"


def test_opencv_is_a_4x_release_with_hand_eye_calibration():
    """opencv-python-headless 5.0's bindings lack calibrateHandEye, which calibration needs."""
    import cv2

    major, minor = (int(part) for part in cv2.__version__.split(".")[:2])
    assert major == 4 and minor >= 10
    assert hasattr(cv2, "calibrateHandEye")
    assert hasattr(cv2, "STEREO_SGBM_MODE_SGBM_3WAY")
