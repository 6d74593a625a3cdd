"""Camera and robot calibration from board (or marker) observations. Pure numeric.

boards        board geometry, detection in images, printable patterns
board_reasons why a board was not found in an image; a larger grid than given
pose_files    robot pose files of other systems -> X_WF
observations  one robot pose with its board detections; board pose by PnP
settings      thresholds of the calibration
intrinsics    one camera (calibrateCamera) and a stereo pair (stereoCalibrate)
hand_eye      AX = XB by OpenCV's methods, and whether the motions determine X_FC
refine        joint refinement of X_FC and X_WB on every board corner (the board is fixed)
eye_in_hand   the whole hand-eye calibration: seed, refine, reject outlier poses
eye_to_hand   a static stereo camera against the robot (blinking marker, rigid fit)
file          the calibration file that scan and reconstruct read
exchange      the calibration as OpenCV stereo_calib and ROS camera_info / tf files
              (exchange_opencv, exchange_ros, exchange_tf; camera_files: shared checks)
camera_quality  epipolar error and board coverage of a camera calibration
"""
