"""The calibration in the files OpenCV and ROS users already have: pure functions between a
StereoCamera (or X_FC) and those files.

OpenCV (the layout of OpenCV's `samples/cpp/stereo_calib.cpp`, written through cv2.FileStorage):

    intrinsics.yml  M1 D1 M2 D2 (3x3 K and 1x5 k1 k2 p1 p2 k3 of the left and right camera),
                    image_width image_height (as OpenCV's single-camera calibration sample names
                    them; stereo_calib writes no image size)
    extrinsics.yml  R T (cv2.stereoCalibrate: x_right = R x_left + T, i.e. X_RC; our
                    StereoCamera.R and .T as they are), R1 R2 P1 P2 Q (cv2.stereoRectify),
                    length_unit

  stereo_calib's T (and P2, Q) are in units of its square size (`-s`, default 1: board squares);
  ours are in metres and say so (`length_unit: m`). Reading takes the unit from that key, else
  from the caller, else assumes metres.

ROS (`sensor_msgs/CameraInfo` as camera_calibration_parsers writes it, one file per camera):

    left.yaml, right.yaml  image_width image_height camera_name camera_matrix
                           distortion_model (plumb_bob) distortion_coefficients
                           rectification_matrix projection_matrix  ({rows, cols, data})

  The right camera's projection matrix carries Tx = -fx' * baseline (metres, REP 104 and the
  CameraInfo message). Reading rebuilds R, T from the rectification: both rectified frames share
  one orientation (R_rect_C = R1, R_rect_R = R2) and the right one sits at (Tx / fx', Ty / fy', 0)
  in the left one, so R = R2^T R1 and T = R2^T (Tx / fx', Ty / fy', 0).

Hand-eye as a ROS static transform (hand_eye_tf.yaml): X_FC is the pose of the child frame (the
left optical frame C: z forward, x right, y down, what REP 103 suffixes `_optical`) in the parent
frame (the flange F, ROS-Industrial's `tool0`); translation in metres and the unit quaternion
(qx, qy, qz, qw) with qw >= 0, plus the `static_transform_publisher` command lines. Reading also
takes easy_handeye's files (`transformation: {x, y, z, qx, qy, qz, qw}`) and easy_handeye2's
(`transform: {translation: {x, y, z}, rotation: {x, y, z, w}}`).

Every reader raises ScannerError naming the file and the key.
"""

from reconstruction.calibration.exchange_opencv import (
    LENGTH_UNITS_M,
    OPENCV_EXTRINSICS,
    OPENCV_FILES,
    OPENCV_INTRINSICS,
    opencv_stereo_texts,
    parse_length_unit,
    read_opencv_stereo,
    write_opencv_stereo,
)
from reconstruction.calibration.exchange_ros import (
    ROS_DISTORTION_MODELS,
    ROS_FILES,
    ROS_LEFT,
    ROS_RIGHT,
    camera_info_dicts,
    read_ros_camera_info,
    write_ros_camera_info,
)
from reconstruction.calibration.exchange_tf import (
    HAND_EYE_TF,
    QUATERNION_NORM_TOLERANCE,
    ROS_FRAME_PATTERN,
    StaticTransform,
    read_hand_eye,
    require_ros_frame,
    static_transform,
    static_transform_text,
    write_static_transform,
)

__all__ = [
    "HAND_EYE_TF",
    "LENGTH_UNITS_M",
    "OPENCV_EXTRINSICS",
    "OPENCV_FILES",
    "OPENCV_INTRINSICS",
    "QUATERNION_NORM_TOLERANCE",
    "ROS_DISTORTION_MODELS",
    "ROS_FILES",
    "ROS_FRAME_PATTERN",
    "ROS_LEFT",
    "ROS_RIGHT",
    "StaticTransform",
    "camera_info_dicts",
    "opencv_stereo_texts",
    "parse_length_unit",
    "read_hand_eye",
    "read_opencv_stereo",
    "read_ros_camera_info",
    "require_ros_frame",
    "static_transform",
    "static_transform_text",
    "write_opencv_stereo",
    "write_ros_camera_info",
    "write_static_transform",
]
