"""One camera moved by the arm (an imported recording, `scanner import-recording`): each
capture carries its own camera and pose, and a cloud needs a pair of captures
(`reconstruction/two_view/`, paired in `scanner/recordings/`)."""

from __future__ import annotations

from reconstruction.common.errors import ScannerError
from robots.sensors.sensor import Sensor


class MonoSensor(Sensor):
    kind = "mono"
    capture_format = "mono"
    model_words = "one camera per capture"
    device_words = "a single camera"
    pairs_of_captures = True
    scans = False
    hardware_kinds = ()

    def _not_scanned(self, what: str):
        raise ScannerError(
            f"sensor: mono ({what}) is an imported recording's camera; it is not scanned "
            "live (scanner import-recording writes its scan directory)"
        )

    def nominal_model(self, config):
        self._not_scanned("no nominal camera model")

    def nominal_X_FC(self, model):
        self._not_scanned("no camera tool")

    def calibrated_model(self, model, calibration, where: str):
        self._not_scanned("each capture holds its own camera")

    def model_to_dict(self, model) -> dict:
        self._not_scanned("each capture holds its own camera")

    def describe(self, model) -> str:
        return "one camera, pairs of views"

    def image_camera(self, model):
        return model

    def check_reach(self, model, standoff_m: float, radius_m: float) -> None:
        self._not_scanned("no standoff to check")

    def cloud(self, prepared, capture, X_WC, p_W_centre, radius_m, params, step_px=None):
        raise ScannerError(
            f"capture {capture.pose_index}: a mono capture alone gives no cloud; its views are "
            "paired first (scanner reconstruct of an imported recording)"
        )

    def true_device(self, config):
        self._not_scanned("no simulated device")

    def simulated_device(self, workcell, truth, true_joint_positions):
        self._not_scanned("no simulated device")
